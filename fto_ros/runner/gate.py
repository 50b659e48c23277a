"""Plausibility limits and the outlier gate: what the runner refuses before a sample can
reach the observer.  ROS-free, no observer knowledge.

**Limits.**  A measurement or input whose absolute value exceeds its per-channel limit
(``limits.measurement``, ``limits.input``: one value for every channel, or one per
channel) is rejected as ``measurement_implausible`` / ``input_implausible``: a finite
1e300 from a glitching driver never reaches an integrator.

**Outlier gate.**  Each measurement is compared with the linear extrapolation of the last
two accepted ones (variable step): the innovation ``e = y - y_pred`` of a model-free
predictor, available for every observer before its update, so a rejected sample never
touches the observer's state.  Its recent scale ``sigma`` is the RMS of e over the last
``outlier.window`` accepted samples (an exponentially weighted mean square), floored at
``outlier.min_scale``.  Once the observer has converged (the runner says when) and the
scale has a quarter window of history, a sample with ``|e_i| > threshold * sigma_i`` on
any channel is rejected as ``outlier``.  On the committed bags the largest ratio
|e| / sigma is 4.5 (noisy DC motor, cubic escape); the default threshold is 20.

A real change (a collision, a step of the signal) also starts as "outliers"; what tells it
from a glitch is that it persists: the rejected samples are extrapolated among
themselves, and ``outlier.confirm`` consecutive ones that agree with each other (their
own innovations within the threshold) are accepted as the new signal: the gate re-bases
on them (counted under ``outlier_rebase``).  Random junk never agrees with itself; after
``outlier.max_consecutive`` rejections in a row the gate re-bases anyway, so it can never
lock the observer out of a signal whose character changed (e.g. much noisier).  Each
re-base also restarts the scale estimate.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError


def channel_limits(values: Sequence[float], n: int, parameter: str) -> np.ndarray:
    """Per-channel limits from one value (all channels) or n values; ConfigError otherwise."""
    if len(values) == 1:
        return np.full(n, float(values[0]))
    if len(values) != n:
        raise ConfigError(parameter, f"expected 1 value (every channel) or {n}, got {len(values)}")
    return np.asarray(values, dtype=float)


def exceeds(v, limits: np.ndarray) -> bool:
    """Whether any |v_i| > limits_i (v: a checked sequence of finite numbers)."""
    for x, lim in zip(v, limits):
        if abs(x) > lim:
            return True
    return False


class OutlierGate:
    """The model-free innovation gate of the module docstring, for p channels."""

    #: no gating when one of the last two steps is this many times longer than the other (a
    #: line through samples either side of a pause says nothing about the next one)
    MAX_STEP_RATIO = 4.0

    def __init__(self, settings: Mapping[str, Any], p: int):
        self.threshold = settings["outlier.threshold"]
        self.alpha = 1.0 / settings["outlier.window"]
        self.min_history = max(2, settings["outlier.window"] // 4)
        self.confirm = settings["outlier.confirm"]
        self.max_consecutive = settings["outlier.max_consecutive"]
        self.floor = channel_limits(settings["outlier.min_scale"], p, "outlier.min_scale")
        self.p = p
        self.clear()

    @property
    def enabled(self) -> bool:
        return self.threshold > 0

    def clear(self) -> None:
        """Forget the history (a restart of the observer, a re-base)."""
        self._prev: list[tuple[float, np.ndarray]] = []     # last two accepted (t, y)
        self._ms = np.zeros(self.p)                         # mean square of e
        self._n = 0                                         # innovations in _ms
        self._held: list[tuple[float, np.ndarray]] = []     # last rejected (t, y), in a row
        self._run = 0                                       # rejections in a row

    def _innovation(self, a, b, t: float, y: np.ndarray, streak: bool = False) -> np.ndarray | None:
        """y minus the line through the samples a and b (None: no usable line).  After a
        pause (one of the two steps much longer than the other) there is none, unless the
        pause is a streak of samples this gate rejected (``streak``): then the line of the
        last accepted samples is what they are measured against."""
        (t1, y1), (t2, y2) = a, b
        if not t2 > t1 or not t > t2 or t2 - t1 > self.MAX_STEP_RATIO * (t - t2) \
                or (t - t2 > self.MAX_STEP_RATIO * (t2 - t1) and not streak):
            return None
        return y - (y2 + (y2 - y1) * ((t - t2) / (t2 - t1)))

    def check(self, t: float, y: np.ndarray, active: bool) -> str | None:
        """'outlier' to reject y at t, 'rebase' to accept it as a confirmed change (the
        caller counts it), None to accept it.  Call ``accepted`` for every sample the
        observer then takes."""
        if not self.enabled or not active or self._n < self.min_history:
            return None
        e = self._innovation(*self._prev, t, y, streak=self._run > 0)
        if e is None:
            return None
        limit = self.threshold * np.maximum(np.sqrt(self._ms), self.floor)
        if np.all(np.abs(e) <= limit):
            self._held.clear()
            self._run = 0
            return None
        held = self._held
        held.append((t, y.copy()))
        del held[:-self.confirm]
        self._run += 1
        # the last `confirm` rejected samples continue each other: a persisting change
        persisting = len(held) == self.confirm and all(
            (e_h := self._innovation(held[i - 2], held[i - 1], *held[i])) is not None
            and np.all(np.abs(e_h) <= limit) for i in range(2, len(held)))
        if persisting or self._run >= self.max_consecutive:
            base = held[-2:-1]
            self.clear()
            self._prev = base
            return "rebase"
        return "outlier"

    def accepted(self, t: float, y: np.ndarray) -> None:
        """Record a sample the observer took."""
        if len(self._prev) == 2:
            e = self._innovation(*self._prev, t, y)
            if e is not None:
                if self._n == 0:
                    self._ms = e * e
                else:
                    self._ms = self._ms + self.alpha * (e * e - self._ms)
                self._n += 1
        self._prev = (self._prev + [(t, y)])[-2:]

    def scale(self) -> np.ndarray:
        """The current sigma per channel (before the floor)."""
        return np.sqrt(self._ms)

    def summary(self) -> str:
        if not self.enabled:
            return "off"
        if self._n < self.min_history:
            return f"learning ({self._n} of {self.min_history} samples)"
        return "sigma " + ", ".join(f"{v:.3g}" for v in self.scale())
