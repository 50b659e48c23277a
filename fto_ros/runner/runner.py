"""The one adapter between (t, y, u) samples and an observer, for node AND replay.

The live node and the replay harness both call ``set_input`` / ``process`` /
``status`` here, so replaying a bag in CI exercises exactly what the node does
on live topics.  The runner validates each sample (finite, right length,
stamps increasing, input present and fresh), restarts the observer on time
jumps and long gaps, never lets a non-finite value out, counts everything
with its reason and builds the outputs and the diagnostics.  ROS-free.
"""
from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..core.errors import ConfigError
from ..observers.base import Observer, SampleRejected
from . import settings as S

OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}

#: order of the values on the ``convergence`` topic
CONVERGENCE_FIELDS = ("time_since_start", "output_residual", "converged", "guaranteed_time", "health")


@dataclass
class Output:
    """What one accepted sample produces (all finite)."""
    t: float
    estimate: np.ndarray
    unknown_input: np.ndarray | None
    convergence: np.ndarray          # CONVERGENCE_FIELDS; guaranteed_time may be inf (no guarantee)
    joint_state: tuple | None        # (names, position, velocity, effort) lists, or None


@dataclass
class Status:
    """One /diagnostics status: level, a one-line message, key-values a person can read."""
    level: int
    message: str
    values: list[tuple[str, str]]


class Runner:
    """Validates samples, drives one observer, builds outputs and diagnostics."""

    def __init__(self, flat_params: Mapping[str, Any]):
        self.settings, self.observer_class, self.observer_config = S.split(flat_params)
        self.observer: Observer = self.observer_class(self.observer_config)
        obs = self.observer
        S.check_settings(self.settings, obs.n_states, obs.n_outputs, obs.n_inputs)
        self.accepted = 0
        self.rejected: Counter[str] = Counter()
        self.resets: Counter[str] = Counter()
        self._update_us: deque[float] = deque(maxlen=2000)
        self._window_accepted = 0
        self._window_rejected = 0
        self._window_start: float | None = None
        self._u: np.ndarray | None = np.zeros(0) if obs.n_inputs == 0 else None
        self._t_input: float | None = None
        self._t_last: float | None = None
        self._t0: float | None = None
        self._last_output: Output | None = None
        self.last_rejection: str | None = None
        self.last_error: str | None = None
        self._js = self._joint_state_mapping()

    # -- configuration ------------------------------------------------------
    @property
    def observer_type(self) -> str:
        return self.observer_class.TYPE

    def reconfigure(self, flat_params: Mapping[str, Any]) -> None:
        """Apply changed parameters: validate everything, then swap in a new observer.

        Raises ConfigError and keeps running the old configuration when the
        new one is unusable.  The observer restarts (counted as 'reconfigure').
        """
        new = Runner(flat_params)
        if new.observer_type != self.observer_type:
            raise ConfigError("observer.type", "cannot be changed at run time; restart the node")
        self.settings, self.observer_config, self.observer = new.settings, new.observer_config, new.observer
        self._js = new._js
        self.reset("reconfigure")

    # -- inputs -------------------------------------------------------------
    def set_input(self, t: float, u) -> str | None:
        """Store the known input u valid from time t on.  Returns a rejection reason or None."""
        reason = self._check_vector(u, self.observer.n_inputs, "input")
        if reason is None and not math.isfinite(t):
            reason = "input_bad_stamp"
        if reason is not None:
            self._reject(reason)
            return reason
        self._u = np.array(u, dtype=float)
        self._t_input = t
        # observers that predict between sparse measurements (single_delay, sampled form)
        # integrate up to each input change, so a fast input is applied when it changes
        advance = getattr(self.observer, "advance", None)
        if advance is not None and self._t0 is not None and self._t_last is not None and t >= self._t_last:
            try:
                advance(t, self._u)
            except SampleRejected as exc:
                self._reject(exc.reason)
                return exc.reason
            except Exception as exc:  # noqa: BLE001  as in process(): restart, never a traceback
                self.reset("observer_error")
                self.last_error = f"{type(exc).__name__}: {exc}"
                self._reject("observer_error")
                return "observer_error"
        return None

    def process(self, t: float, y) -> Output | str:
        """Feed the measurement y taken at t.  Returns the Output, or the rejection reason."""
        obs = self.observer
        reason = self._check_vector(y, obs.n_outputs, "measurement")
        if reason is None and not math.isfinite(t):
            reason = "bad_stamp"
        if reason is None and self._u is None:
            reason = "missing_input"
        if reason is None and self._t_input is not None and t - self._t_input > self.settings["input.timeout"]:
            reason = "stale_input"
        if reason is None and self._t_last is not None:
            dt = t - self._t_last
            if dt == 0.0:
                reason = "repeated_stamp"
            elif dt < 0.0:
                if self.settings["time.reset_on_jump"] and -dt > self.settings["time.jump_threshold"]:
                    self.time_jump(t)
                    if self._u is None:
                        reason = "missing_input"
                else:
                    reason = "stamp_backwards"
            elif dt > self.settings["time.max_gap"]:
                self.reset("gap")
        if reason is not None:
            self._reject(reason)
            return reason

        y = np.array(y, dtype=float)
        start = time.perf_counter()
        first = self._t0 is None
        try:
            if first:
                x0 = self.settings["observer.initial_estimate"] or None
                obs.reset(t, None if x0 is None else np.array(x0))
            obs.update(t, y, self._u)
        except SampleRejected as exc:
            if first:
                self._t0 = None
            self._reject(exc.reason)
            return exc.reason
        except Exception as exc:  # noqa: BLE001  last line of defence: never a traceback
            # an observer bug: its state cannot be trusted any more, so restart it
            self.reset("observer_error")
            self.last_error = f"{type(exc).__name__}: {exc}"
            self._reject("observer_error")
            return "observer_error"
        self._update_us.append((time.perf_counter() - start) * 1e6)
        if first:
            self._t0 = t
        self._t_last = t

        out = self._build_output(t)
        if out is None:  # the observer let a non-finite value through: never publish it
            self.reset("non_finite_state")
            self._reject("non_finite_estimate")
            return "non_finite_estimate"
        self.accepted += 1
        self._window_accepted += 1
        self._last_output = out
        return out

    @property
    def last_sample_time(self) -> float | None:
        """Time of the last accepted measurement since the last restart (None right after one)."""
        return self._t_last

    def time_jump(self, t: float) -> None:
        """Time went back to t (bag loop, sim time reset): restart, and forget an input
        stamped after t, which belongs to the old timeline."""
        self.reset("time_jump")
        if self.observer.n_inputs and self._t_input is not None and self._t_input > t:
            self._u = self._t_input = None

    def reset(self, reason: str = "service") -> None:
        """Restart the observer at the next sample (counted under ``reason``)."""
        self.resets[reason] += 1
        self._t0 = None
        self._t_last = None


    # -- outputs ------------------------------------------------------------
    def _build_output(self, t: float) -> Output | None:
        obs = self.observer
        x = np.array(obs.estimate, dtype=float)
        ui = obs.unknown_input
        ui = None if ui is None else np.array(ui, dtype=float)
        # one sum per vector: a NaN or Inf anywhere makes it non-finite
        if not math.isfinite(x.sum()) or (ui is not None and not math.isfinite(ui.sum())):
            return None
        since = t - self._t0
        gt = obs.guaranteed_time
        res = obs.output_residual
        thr = self.settings["convergence.residual_threshold"]
        # without a guarantee (asymptotic observers) only the residual can say it
        converged = since >= gt - 1e-9 if math.isfinite(gt) else (math.isfinite(res) and res <= thr)
        health = obs.health
        conv = np.array([since, res if math.isfinite(res) else -1.0, float(converged), gt,
                         health if math.isfinite(health) else 0.0])
        js = None
        if self._js is not None:
            names, idx = self._js
            js = (names,) + tuple([float(x[i]) for i in ix] if ix is not None else [] for ix in idx)
        return Output(t, x, ui, conv, js)

    def _joint_state_mapping(self):
        names = self.settings["estimated_joint_states.joint_names"]
        if not names:
            return None
        idx = []
        for field in S.FIELDS:
            ix = self.settings[f"estimated_joint_states.{field}_states"]
            if not ix or all(i < 0 for i in ix):
                idx.append(None)
            elif any(i < 0 for i in ix):
                raise ConfigError(f"estimated_joint_states.{field}_states",
                                  "give an index for every joint or for none (JointState fields "
                                  "are all-or-nothing)")
            else:
                idx.append(ix)
        return names, idx

    # -- diagnostics --------------------------------------------------------
    def state_name(self) -> str:
        """'waiting', 'converging', 'converged' or 'diverging'."""
        out = self._last_output
        if out is None or self._t0 is None:
            return "waiting"
        res, converged = out.convergence[1], out.convergence[2]
        if not converged:
            return "converging"
        if res > self.settings["convergence.residual_threshold"]:
            return "diverging"
        return "converged"

    def update_time_us(self) -> tuple[float, float]:
        """(p50, p99) of the recent update times in microseconds (nan before any)."""
        if not self._update_us:
            return float("nan"), float("nan")
        a = np.fromiter(self._update_us, float)
        return float(np.percentile(a, 50)), float(np.percentile(a, 99))

    def status(self, now: float | None = None) -> Status:
        """The diagnostics status, rates over the window since the previous call.

        ``now`` is the caller's clock (node: ROS time; replay: sample time).
        """
        obs = self.observer
        state = self.state_name()
        out = self._last_output
        values: list[tuple[str, str]] = [("observer", obs.TYPE), ("state", state)]
        level, problems = OK, []
        if out is not None:
            values += [("time since start (s)", f"{out.convergence[0]:.4f}"),
                       ("guaranteed convergence time (s)",
                        "none" if math.isinf(out.convergence[3]) else f"{out.convergence[3]:.4g}"),
                       ("output residual", f"{out.convergence[1]:.4g}")]
        values += [("samples accepted", str(self.accepted)),
                   ("samples rejected", str(sum(self.rejected.values())))]
        values += [(f"rejected: {k}", str(v)) for k, v in sorted(self.rejected.items())]
        values += [(f"restarts: {k}", str(v)) for k, v in sorted(self.resets.items())]
        if obs.n_inputs:
            age = (now - self._t_input) if (now is not None and self._t_input is not None) else None
            values.append(("input age (s)", "never received" if self._t_input is None else
                           (f"{age:.4f}" if age is not None else "n/a")))
        p50, p99 = self.update_time_us()
        values.append(("update time p50/p99 (us)", f"{p50:.1f} / {p99:.1f}"))
        if now is not None and self._window_start is not None and now > self._window_start:
            rate = self._window_accepted / (now - self._window_start)
            values.append(("measurement rate (Hz)", f"{rate:.1f}"))
            exp = self.settings["diagnostics.expected_rate"]
            if exp > 0:
                values.append(("expected rate (Hz)", f"{exp:.1f}"))
                if rate < 0.8 * exp:
                    level, problems = WARN, problems + [f"rate {rate:.0f} Hz below expected {exp:.0f} Hz"]
        values += [(k, str(v)) for k, v in obs.diagnostics().items()]
        if self._window_rejected:
            level = WARN
            problems.append(f"{self._window_rejected} sample(s) rejected (last: {self.last_rejection})")
        if state == "diverging":
            level = WARN
            problems.append("output residual above convergence.residual_threshold after the guaranteed time")
        if state == "waiting":
            level = max(level, WARN)
            problems.append("no accepted measurement yet" if self.accepted == 0 else "restarted, waiting for a sample")
        if self.last_error:
            values.append(("last observer error", self.last_error))
        if self.resets.get("non_finite_state") or self.resets.get("observer_error"):
            level = ERROR
            problems.append("the observer failed (non-finite values or an internal error) and was restarted")
        self._window_start = now
        self._window_accepted = self._window_rejected = 0
        message = state if not problems else f"{state}: " + "; ".join(problems)
        return Status(level, message, values)

    # -- helpers ------------------------------------------------------------
    def _check_vector(self, v, n: int, what: str) -> str | None:
        try:
            length = len(v)
        except TypeError:
            return f"{what}_not_an_array"
        if length != n:
            return f"{what}_wrong_length"
        try:
            for x in v:
                if not math.isfinite(x):
                    return f"{what}_non_finite"
        except TypeError:
            return f"{what}_not_numeric"
        return None

    def reject(self, reason: str) -> None:
        """Count a sample the caller refused before it reached the runner (e.g. a
        JointState without the configured joint, a future stamp)."""
        self._reject(reason)

    def _reject(self, reason: str) -> None:
        self.rejected[reason] += 1
        self._window_rejected += 1
        self.last_rejection = reason
