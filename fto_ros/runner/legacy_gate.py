"""Plausibility limits and the outlier gate: what the runner refuses before a sample can
reach the observer.  ROS-free, no observer knowledge.

**Limits.**  A measurement or input whose absolute value exceeds its per-channel limit
(``limits.measurement``, ``limits.input``: one value for every channel, or one per
channel) is rejected as ``measurement_implausible`` / ``input_implausible``: a finite
1e300 from a glitching driver never reaches an integrator.

**Outlier gate.**  Each measurement is compared with the linear extrapolation of the last
two accepted ones (variable step): the innovation ``e = y - y_pred`` of a model-free
predictor, available for every observer before its update, so a rejected sample never
touches the observer's state; it is expressed in units of the innovation of equal steps of
the typical length (``_innovation``), so dropped samples do not look like glitches.  Its
recent scale ``sigma`` is the RMS of e over the last
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

import math
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
        self.floor = channel_limits(settings["outlier.min_scale"], p, "outlier.min_scale").tolist()
        self.p = p
        self.clear()

    @property
    def enabled(self) -> bool:
        return self.threshold > 0

    def clear(self) -> None:
        """Forget the history (a restart of the observer, a re-base)."""
        self._prev: list[tuple[float, np.ndarray]] = []     # last two accepted (t, y)
        self._ms = [0.0] * self.p                           # mean square of e
        self._n = 0                                         # innovations in _ms
        self._held: list[tuple[float, np.ndarray]] = []     # last rejected (t, y), in a row
        self._run = 0                                       # rejections in a row
        self._h = 0.0                                       # typical step (mean, s)

    def _innovation(self, a, b, t: float, y, streak: bool = False) -> list[float] | None:
        """y minus the line through the samples a and b, in units of the innovation of equal
        steps of the typical length (None: no usable line).

        Irregular steps (samples dropped on a loaded machine) make the raw innovation larger
        for a reason that is not a glitch: with r = (t - t2)/(t2 - t1) its noise part grows
        by sqrt((1 + r^2 + (1 + r)^2) / 6) and the extrapolation error of a smooth signal by
        (t - t2)(t - t1) / (2 h^2) (h: the typical step); the larger divides it.  In a streak
        of rejected samples only the noise part does (the line of the last accepted samples
        is what they are measured against: junk must not get through by lasting).  After a
        pause in the accepted history (one step much longer than the other) there is no line.
        Plain floats: p is small, and numpy's per-call cost would be most of the work.
        """
        (t1, y1), (t2, y2) = a, b
        h1, d = t2 - t1, t - t2
        if not h1 > 0 or not d > 0 or h1 > self.MAX_STEP_RATIO * d \
                or (d > self.MAX_STEP_RATIO * h1 and not streak):
            return None
        r = d / h1
        f = math.sqrt((1.0 + r * r + (1.0 + r) ** 2) / 6.0)
        if not streak and self._h > 0:
            f = max(f, d * (d + h1) / (2.0 * self._h * self._h))
        return [(yi - (bi + (bi - ai) * r)) / f for yi, ai, bi in zip(y, y1, y2)]

    def _within(self, e: list[float]) -> bool:
        return all(abs(v) <= lim for v, lim in zip(e, self._limit))

    def check(self, t: float, y, active: bool) -> str | None:
        """'outlier' to reject y at t, 'rebase' to accept it as a confirmed change (the
        caller counts it), None to accept it.  Call ``accepted`` for every sample the
        observer then takes."""
        if not self.enabled or not active or self._n < self.min_history:
            return None
        e = self._innovation(*self._prev, t, y, streak=self._run > 0)
        if e is None:
            return None
        self._limit = [self.threshold * max(math.sqrt(ms), fl) for ms, fl in zip(self._ms, self.floor)]
        if self._within(e):
            if self._run:
                self._held.clear()
                self._run = 0
            return None
        held = self._held
        held.append((t, list(y)))
        del held[:-self.confirm]
        self._run += 1
        # the last `confirm` rejected samples continue each other: a persisting change
        persisting = len(held) == self.confirm and all(
            (e_h := self._innovation(held[i - 2], held[i - 1], *held[i])) is not None
            and self._within(e_h) for i in range(2, len(held)))
        if persisting or self._run >= self.max_consecutive:
            base = held[-2:-1]
            self.clear()
            self._prev = base
            return "rebase"
        return "outlier"

    def accepted(self, t: float, y) -> None:
        """Record a sample the observer took."""
        prev = self._prev
        if prev:
            step = t - prev[-1][0]
            if step > 0:
                self._h = step if self._h == 0 else self._h + self.alpha * (step - self._h)
        if len(prev) == 2:
            e = self._innovation(prev[0], prev[1], t, y)
            if e is not None:
                a = self.alpha if self._n else 1.0
                self._ms = [ms + a * (v * v - ms) for ms, v in zip(self._ms, e)]
                self._n += 1
            self._prev = [prev[1], (t, y)]
        else:
            self._prev = prev + [(t, y)]

    def scale(self) -> list[float]:
        """The current sigma per channel (before the floor)."""
        return [math.sqrt(ms) for ms in self._ms]

    def summary(self) -> str:
        if not self.enabled:
            return "off"
        if self._n < self.min_history:
            return f"learning ({self._n} of {self.min_history} samples)"
        return "sigma " + ", ".join(f"{v:.3g}" for v in self.scale())
