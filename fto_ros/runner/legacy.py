"""The runner of the observer families that have no compiled kernel yet (the per-sample
work in Python); runner/runner.py hands them to it.  What follows is its original docstring.

The one adapter between (t, y, u) samples and an observer, for node AND replay.

The live node and the replay harness both call ``set_input`` / ``process`` /
``status`` here, so replaying a bag in CI exercises exactly what the node does
on live topics.  The runner is the one owner of time and validity:

- it checks every sample once (a sequence of the right length of finite numbers,
  within the plausibility limits; a stamp that is finite and representable as a ROS
  time, 0 <= t < 2^31 s; an input present and fresh);
- it classifies every interval (timeline.py): a step the observer bridges, a
  rejected stamp, or a discontinuity confirmed by the next sample before the
  observer is restarted once;
- it gates outliers before the observer sees them (gate.py);
- it restarts the observer on a failure (an exception, a non-finite or implausible
  estimate) and never lets a non-finite value out;
- it counts everything with its reason and builds the outputs and the diagnostics,
  whose level describes the recent past (health.py).

ROS-free.
"""
from __future__ import annotations

import math
import time
from collections import Counter, deque
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError
from ..core.params import check_vector
from ..observers.base import Observer, SampleRejected
from . import settings as S
from .build import changed_names, design_guard
from .legacy_gate import OutlierGate, channel_limits, exceeds
from .health import FAILURES, HealthWindow
from .legacy_timeline import CONFIRM, HOLD, REJECT, STEP, Held, classify

from .runner import (CONVERGENCE_FIELDS, ERROR, HELD, LEVEL_NAMES, MAX_HELD_INPUTS, MAX_STAMP,
                     OK, WARN, Output, Status, convergence_fields)


class LegacyRunner:
    """Validates samples, drives one observer, builds outputs and diagnostics."""

    #: no per-joint mode (Runner refuses ``joints`` for the families that land here)
    joints: list = []

    def __init__(self, flat_params: Mapping[str, Any], changed: Sequence[str] | None = None):
        """ConfigError for unusable parameters, whatever fails (build.py): blamed on the
        ``changed`` names when given (a run-time change), else on the observer's section."""
        with design_guard(flat_params, changed):
            self.settings, self.observer_class, self.observer_config = S.split(flat_params)
            self.observer: Observer = self.observer_class(self.observer_config)
            obs = self.observer
            S.check_settings(self.settings, obs.n_states, obs.n_outputs, obs.n_inputs)
        self._flat = dict(flat_params)
        self.accepted = 0
        self.rejected: Counter[str] = Counter()
        self.resets: Counter[str] = Counter()
        self.rebases = 0
        self._update_us: deque[float] = deque(maxlen=2000)
        self._health = HealthWindow(self.settings["diagnostics.window"])
        self._window_start: float | None = None
        self._window_accepted = 0
        self._u: np.ndarray | None = self._no_input()
        self._t_input: float | None = None
        self._t_last: float | None = None
        self._t0: float | None = None
        self._held: Held | None = None
        self._pending: deque = deque(maxlen=MAX_HELD_INPUTS)   # inputs to advance to (set_input)
        self._start_from: np.ndarray | None = None     # ~/set_state: the next start's estimate
        self._last_output: Output | None = None
        self.last_rejection: str | None = None
        self.last_error: str | None = None
        self._configure()

    def _configure(self) -> None:
        """Everything derived from the settings and the observer's dimensions."""
        s, obs = self.settings, self.observer
        self._y_limits = channel_limits(s["limits.measurement"], obs.n_outputs, "limits.measurement")
        self._u_limits = channel_limits(s["limits.input"], obs.n_inputs, "limits.input") \
            if obs.n_inputs else np.zeros(0)
        self._gate = OutlierGate(s, obs.n_outputs)
        self._js = self._joint_state_mapping()
        self._health.window = s["diagnostics.window"]

    # -- configuration ------------------------------------------------------
    @property
    def observer_type(self) -> str:
        return self.observer_class.TYPE

    @property
    def convergence_fields(self) -> tuple[str, ...]:
        """The labels of the ``convergence`` values: the common ones, then the observer's."""
        return convergence_fields(self.observer)

    #: one observer: no joints axis
    joints: list = []
    n_joints = 1

    def statuses(self, now: float | None = None) -> list[Status]:
        """[the status] (``Runner.statuses`` of one observer)."""
        return [self.status(now)]

    @property
    def joint_state_map(self):
        """(names, per JointState field the state indices or None) of estimated_joint_states."""
        return self._js

    def process_block(self, kind, t, values, refused=None):
        """``Runner.process_block`` for this runner: the events one by one through
        ``set_input`` / ``process`` / ``reject`` (an unknown input it has not: NaN)."""
        from ..core.reasons import CODE, REJECTIONS
        from . import loop as L
        from .runner import Block
        obs = self.observer
        count, n, m, p = len(t), obs.n_states, obs.n_inputs, obs.n_outputs
        r = len(getattr(obs, "unknown_input_names", None) or range(p)) if obs.has_unknown_input else 0
        values = np.asarray(values, dtype=float).reshape(count, -1)
        pre = np.zeros(count, np.int16) if refused is None else np.asarray(refused).reshape(count)
        b = Block(np.zeros((count, 1), np.int16), np.zeros((count, 1, n)),
                  np.full((count, 1, r), np.nan), np.zeros((count, 1, len(self.convergence_fields))))
        input_refused = False
        for k in range(count):
            if pre[k] < 0 or (kind[k] == L.PAIRED and input_refused):
                b.status[k] = L.SKIPPED
            elif kind[k] == L.REFUSED or pre[k] != 0:
                self.reject(REJECTIONS[pre[k]])
                b.status[k] = pre[k]
            elif kind[k] == L.INPUT:
                why = self.set_input(float(t[k]), values[k, :m].tolist())
                input_refused = why is not None
                b.status[k] = L.INPUT_TAKEN if why is None else CODE[why]
            else:
                out = self.process(float(t[k]), values[k, :p].tolist())
                if out.__class__ is str:
                    b.status[k] = L.HELD if out == HELD else CODE[out]
                    continue
                b.estimate[k, 0], b.convergence[k, 0] = out.estimate, out.convergence
                if out.unknown_input is not None:
                    b.unknown_input[k, 0] = out.unknown_input
        return b

    def reconfigure(self, flat_params: Mapping[str, Any]) -> None:
        """Apply changed parameters: validate everything, then swap in a new observer.

        Raises ConfigError and keeps running the old configuration when the
        new one is unusable.  The observer restarts (counted as 'reconfigure').
        """
        new = type(self)(flat_params, changed_names(self._flat, flat_params))
        if new.observer_type != self.observer_type:
            raise ConfigError("observer.type", "cannot be changed at run time; restart the node")
        n_inputs = self.observer.n_inputs
        self.settings, self.observer_config, self.observer = new.settings, new.observer_config, new.observer
        self._flat = new._flat
        if self.observer.n_inputs != n_inputs:     # the old input does not fit the new observer
            self._u, self._t_input = self._no_input(), None
        self._configure()
        self.reset("reconfigure")

    # -- inputs -------------------------------------------------------------
    def set_input(self, t: float, u) -> str | None:
        """Store the known input u valid from time t on.  Returns a rejection reason or None."""
        obs = self.observer
        reason = check_vector(u, obs.n_inputs, "input")
        if reason is None and exceeds(u, self._u_limits):
            reason = "input_implausible"
        if reason is None and not (0.0 <= t < MAX_STAMP):
            reason = "input_bad_stamp"
        if reason is not None:
            self._reject(reason)
            return reason
        if obs.n_inputs == 0:
            # nothing to store: an empty input must not start the stale_input clock (it made
            # every later sample stale) nor advance a predictor; it leaves no trace
            return None
        self._u = np.array(u, dtype=float)
        self._t_input = t
        if self._held is not None and len(self._held.inputs) < MAX_HELD_INPUTS:
            self._held.inputs.append((t, self._u))
        # observers that predict between sparse measurements (single_delay, sampled form)
        # integrate up to each input instant, so a fast input is applied when it changes;
        # the runner does it when a measurement reaches the input's stamp (_advance_to), so
        # an input stamped ahead cannot move the prediction past measurements still to come
        if self._t0 is not None and getattr(obs, "advance", None) is not None:
            self._pending.append((t, self._u))
        return None

    def _advance_to(self, t: float) -> None:
        """Apply the pending inputs stamped up to t, in stamp order, to a predicting
        observer, each only within a step it can bridge from the last measurement (a longer
        silence is a gap: restart later).  A refused one is counted, as set_input does."""
        due = sorted((p for p in self._pending if p[0] <= t), key=lambda p: p[0])
        self._pending = deque((p for p in self._pending if p[0] > t), maxlen=MAX_HELD_INPUTS)
        for t_in, u in due:
            if 0.0 <= t_in - self._t_last <= self._step_limit():
                try:
                    self.observer.advance(t_in, u)
                except SampleRejected as exc:
                    self._reject(exc.reason)

    # -- measurements ------------------------------------------------------------
    def _step_limit(self) -> float:
        return min(self.settings["time.max_gap"], self.observer.max_step)

    def process(self, t: float, y) -> Output | str:
        """Feed the measurement y taken at t.  Returns the Output, or why there is none:
        a rejection reason (counted), or ``HELD`` (held at a time discontinuity until the
        next sample confirms it)."""
        obs = self.observer
        reason = check_vector(y, obs.n_outputs, "measurement")
        if reason is None and exceeds(y, self._y_limits):
            reason = "measurement_implausible"
        if reason is None and not (0.0 <= t < MAX_STAMP):
            reason = "bad_stamp"
        if reason is not None:
            self._reject(reason)
            return reason
        s = self.settings
        verdict, detail = classify(t, self._t_last, self._held, self._step_limit(),
                                   s["time.jump_threshold"], s["time.reset_on_jump"])
        if verdict == REJECT:
            self._reject(detail)
            return detail
        if verdict == HOLD:
            if self._held is not None:
                self._reject("stamp_jump_unconfirmed")
            self._held = Held(t, list(y), self._u, self._t_input, detail)
            return HELD
        if verdict == CONFIRM:
            held, self._held = self._held, None
            self.reset(held.kind)
            # the held sample starts the new run with the input that was current then, unless
            # that input was stamped after it (the old timeline's, before a jump back); the
            # inputs that came while it was held follow, as they would have
            fresh = held.t_input is not None and held.t_input <= held.t
            self._u, self._t_input = (held.u, held.t_input) if fresh else (self._no_input(), None)
            self._sample(held.t, np.array(held.y, dtype=float))
            for t_in, u_in in held.inputs:
                if held.t <= t_in <= t:
                    self.set_input(t_in, u_in)
        elif self._held is not None:                 # the old timeline goes on: it was junk
            self._held = None
            self._reject("stamp_jump_unconfirmed")
        if verdict == STEP:
            outcome = self._gate.check(t, y, self.state_name() == "converged")
            if outcome == "outlier":
                self._reject("outlier")
                return "outlier"
            if outcome == "rebase":
                self.rebases += 1
                self._health.count("rebase")
        return self._sample(t, np.array(y, dtype=float))

    def _sample(self, t: float, y: np.ndarray) -> Output | str:
        """Hand a classified sample to the observer; the Output or a rejection reason."""
        obs = self.observer
        if self._u is None:
            reason = "missing_input"
        elif self._t_input is not None and t - self._t_input > self.settings["input.timeout"]:
            reason = "stale_input"
        else:
            reason = None
        if reason is not None:
            self._reject(reason)
            return reason
        start = time.perf_counter()
        first = self._t0 is None
        try:
            if first:
                x0 = self._start_from if self._start_from is not None else \
                    (self.settings["observer.initial_estimate"] or None)
                obs.reset(t, None if x0 is None else np.array(x0))
            elif self._pending:
                self._advance_to(t)
            obs.update_checked(t, y, self._u)
        except SampleRejected as exc:
            self._reject(exc.reason)
            return exc.reason
        except Exception as exc:  # noqa: BLE001  last line of defence: never a traceback
            # an observer bug: its state cannot be trusted any more, so restart it
            return self._fail("observer_error", "observer_error", exc)
        self._update_us.append((time.perf_counter() - start) * 1e6)
        if first:
            self._t0 = t
        self._t_last = t
        out, problem = self._build_output(t)
        if problem is not None:  # never publish a non-finite or absurd estimate
            return self._fail(*problem)
        self._gate.accepted(t, y.tolist())
        self.accepted += 1
        self._window_accepted += 1
        self._health.count("accepted")
        self._last_output = out
        return out

    @property
    def last_sample_time(self) -> float | None:
        """Time of the last accepted measurement since the last restart (None right after one)."""
        return self._t_last

    def time_jump(self, t: float) -> None:
        """Time went back to t (bag loop, sim time reset, told by the node's clock): restart
        at once, and forget an input stamped after t, which belongs to the old timeline."""
        self._held = None
        self.reset("time_jump")
        if self._t_input is not None and self._t_input > t:
            self._u, self._t_input = self._no_input(), None

    def _no_input(self) -> np.ndarray | None:
        """The input before any arrived: none needed (empty) or missing (None)."""
        return np.zeros(0) if self.observer.n_inputs == 0 else None

    def set_state(self, x) -> str | None:
        """Restart the observer from the estimate x (plant coordinates) at the next sample:
        the node's ``~/set_state``.  None when taken, else why not (length, non-finite,
        beyond ``limits.estimate``); counted as the restart ``set_state``."""
        n = self.observer.n_states
        reason = check_vector(x, n, "state")
        if reason is None and any(abs(v) > self.settings["limits.estimate"] for v in x):
            reason = "state_implausible"
        if reason is not None:
            return reason
        self._start_from = np.array(x, dtype=float)
        self.reset("set_state")
        return None

    def reset(self, reason: str = "service") -> None:
        """Restart the observer at the next sample (counted under ``reason``).  A reset
        requested by a person (``service``, ``enable``, ``reconfigure``, ``set_state``) also
        clears the health window: the diagnostics level starts afresh."""
        self.resets[reason] += 1
        self._t0 = None
        self._t_last = None
        self._pending.clear()
        self._gate.clear()
        if reason != "set_state":
            self._start_from = None
        if reason in ("service", "enable", "reconfigure", "set_state"):
            self._health.clear()
            self.last_error = None
        else:
            self._health.count(reason)

    def _fail(self, restart: str, rejection: str, exc: BaseException | None = None) -> str:
        """The observer failed on a sample: restart it, count the sample; the rejection."""
        self.reset(restart)
        if exc is not None:
            self.last_error = f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
        self._reject(rejection)
        return rejection

    # -- outputs ------------------------------------------------------------
    def _build_output(self, t: float) -> tuple[Output | None, tuple[str, str] | None]:
        """(Output, None), or (None, (restart reason, rejection reason)) when the estimate
        is not finite or beyond ``limits.estimate``."""
        obs = self.observer
        x = np.array(obs.estimate, dtype=float)
        ui = obs.unknown_input
        ui = None if ui is None else np.array(ui, dtype=float)
        # the largest |value|: NaN anywhere makes it NaN, Inf makes it Inf (one pass each)
        big = max(map(abs, x.tolist()), default=0.0) if x.size else 0.0
        if ui is not None and ui.size:
            big = max(big, max(map(abs, ui.tolist())))
        if not math.isfinite(big) or math.isnan(x.sum()) or (ui is not None and math.isnan(ui.sum())):
            return None, ("non_finite_state", "non_finite_estimate")
        if big > self.settings["limits.estimate"]:
            return None, ("estimate_implausible", "estimate_implausible")
        since = t - self._t0
        gt = obs.guaranteed_time
        res = obs.output_residual
        thr = self.settings["convergence.residual_threshold"]
        converged = obs.converged
        if converged is None:
            # without a guarantee (asymptotic observers) only the residual can say it
            converged = since >= gt - 1e-9 if math.isfinite(gt) else \
                (math.isfinite(res) and res <= thr)
        health = obs.health
        conv = np.array([since, res if math.isfinite(res) else -1.0, float(converged), gt,
                         health if math.isfinite(health) else 0.0, *obs.convergence_extra()])
        js = None
        if self._js is not None:
            names, idx = self._js
            js = (names,) + tuple([float(x[i]) for i in ix] if ix is not None else [] for ix in idx)
        return Output(t, x, ui, conv, js), None

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
        """The diagnostics status; the level from the last ``diagnostics.window`` seconds
        of ``now`` (the caller's clock: node ROS time, replay sample time), see health.py."""
        obs, s = self.observer, self.settings
        state = self.state_name()
        out = self._last_output
        recent = self._health.close(now)
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
        values.append(("outlier gate", self._gate.summary()
                       + (f"; re-based {self.rebases} time(s)" if self.rebases else "")))
        if obs.n_inputs:
            age = (now - self._t_input) if (now is not None and self._t_input is not None) else None
            values.append(("input age (s)", "never received" if self._t_input is None else
                           (f"{age:.4f}" if age is not None else "n/a")))
        p50, p99 = self.update_time_us()
        values.append(("update time p50/p99 (us)", f"{p50:.1f} / {p99:.1f}"))
        if now is not None and self._window_start is not None and now > self._window_start:
            rate = self._window_accepted / (now - self._window_start)
            values.append(("measurement rate (Hz)", f"{rate:.1f}"))
            exp = s["diagnostics.expected_rate"]
            if exp > 0:
                values.append(("expected rate (Hz)", f"{exp:.1f}"))
                if rate < 0.8 * exp:
                    level = WARN
                    problems.append(f"rate {rate:.0f} Hz below expected {exp:.0f} Hz")
        values += [(k, str(v)) for k, v in obs.diagnostics().items()]
        window = f"last {s['diagnostics.window']:g} s"
        values.append((f"rejected ({window})", str(recent.get("rejected", 0))))
        failures = sum(recent.get(r, 0) for r in FAILURES)
        values.append((f"observer failures ({window})", str(failures)))
        if recent.get("rejected"):
            level = WARN
            problems.append(f"{recent['rejected']} sample(s) rejected in the {window} "
                            f"(last: {self.last_rejection})")
        if recent.get("rebase"):
            level = WARN
            problems.append("the outlier gate accepted a persisting change of the signal")
        if state == "diverging":
            level = WARN
            problems.append("output residual above convergence.residual_threshold after the guaranteed time")
        if state == "waiting":
            level = WARN
            problems.append("no accepted measurement yet" if self.accepted == 0 else "restarted, waiting for a sample")
        idle = self._health.idle_for(now)
        if self.accepted and idle > s["diagnostics.stale_after"]:
            level = WARN
            problems.append(f"no measurement accepted for {idle:.1f} s")
        if self.last_error:
            values.append(("last observer error", self.last_error))
        if failures:
            level = ERROR
            problems.append(f"the observer failed (non-finite or implausible values, or an internal "
                            f"error) and was restarted in the {window}")
        self._window_start = now
        self._window_accepted = 0
        message = state if not problems else f"{state}: " + "; ".join(problems)
        return Status(level, message, values)

    # -- helpers ------------------------------------------------------------
    def reject(self, reason: str) -> None:
        """Count a sample the caller refused before it reached the runner (e.g. a
        JointState without the configured joint, a future stamp)."""
        self._reject(reason)

    def _reject(self, reason: str) -> None:
        self.rejected[reason] += 1
        self._health.count("rejected")
        self.last_rejection = reason
