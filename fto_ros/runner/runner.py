"""The one adapter between (t, y, u) samples and an observer, for node AND replay.

The live node and the replay harness both call ``set_input`` / ``process`` (one sample)
or ``process_block`` (many) and ``status`` here, so replaying a bag in CI exercises
exactly what the node does on live topics.  The runner is the one owner of time and
validity:

- it checks every sample once (a sequence of the right length of finite numbers,
  within the plausibility limits; a stamp that is finite and representable as a ROS
  time, 0 <= t < 2^31 s; an input present and fresh);
- it classifies every interval (timeline.py): a step the observer bridges, a
  rejected stamp, or a discontinuity confirmed by the next sample before the
  observer is restarted once;
- it gates outliers before the observer sees them (gate.py);
- it restarts the observer on a failure (a non-finite or implausible estimate) and never
  lets a non-finite value out;
- it counts everything with its reason and builds the outputs and the diagnostics,
  whose level describes the recent past (health.py).

The per-sample work is compiled (loop.py: the checks, the timeline, the gate, the
observer's kernel, the counters, in one call per block); this class is the Python side:
message values to arrays, the Output of one sample, counters by name, /diagnostics.

ROS-free.
"""
from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..core.errors import ConfigError
from ..core.reasons import CODE, REJECTIONS, RESTART_CODE, RESTARTS, REQUESTED
from ..observers.base import KernelObserver, Observer, check_vector
from . import gate as G
from . import loop as L
from . import settings as S
from .health import FAILURES, HealthWindow

OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}

#: order of the values on the ``convergence`` topic
CONVERGENCE_FIELDS = ("time_since_start", "output_residual", "converged", "guaranteed_time", "health")


def convergence_fields(obs: Observer) -> tuple[str, ...]:
    """The labels of ``obs``'s ``convergence`` values: the common ones, then its own."""
    return CONVERGENCE_FIELDS + tuple(obs.CONVERGENCE_EXTRA)


#: stamps must fit a builtin_interfaces/Time (int32 seconds) and not be negative
MAX_STAMP = L.MAX_STAMP
#: what ``process`` returns for a sample held at a time discontinuity (not a rejection:
#: it is used once the next sample confirms the jump)
HELD = "held_at_time_jump"
MAX_HELD_INPUTS = L.MAX_HELD_INPUTS


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


@dataclass
class Block:
    """The outputs of ``process_block``: per event (and joint) a status (``loop.OUTPUT``,
    ``loop.INPUT_TAKEN``, ``loop.HELD`` or a rejection code, see ``reason``) and, where it is
    OUTPUT, the estimate, the unknown-input estimate and the convergence values."""
    status: np.ndarray               # (K, J) int16
    estimate: np.ndarray             # (K, J, n)
    unknown_input: np.ndarray        # (K, J, r)
    convergence: np.ndarray          # (K, J, len(convergence_fields))


def reason(status: int) -> str | None:
    """The rejection reason of a block status (None: an output or a taken input; HELD)."""
    if status == L.HELD:
        return HELD
    return REJECTIONS[status] if status > 0 else None


class Runner:
    """Validates samples, drives one observer (a compiled kernel), builds outputs and
    diagnostics.  Observer families not yet compiled run on the previous runner
    (runner/legacy.py) behind the same interface."""

    def __new__(cls, flat_params: Mapping[str, Any] | None = None):
        if flat_params is None:                     # copy.deepcopy, _snapshot
            return super().__new__(cls)
        settings, obs_class, obs_config = S.split(flat_params)
        if cls is Runner and not issubclass(obs_class, KernelObserver):
            from .legacy import LegacyRunner
            return LegacyRunner(flat_params)
        self = super().__new__(cls)
        self._split = (settings, obs_class, obs_config)
        return self

    def __init__(self, flat_params: Mapping[str, Any] | None = None):
        if flat_params is None:
            return
        self.settings, self.observer_class, self.observer_config = self._split
        del self._split
        self.observer: KernelObserver = self.observer_class(self.observer_config)
        obs = self.observer
        S.check_settings(self.settings, obs.n_states, obs.n_outputs, obs.n_inputs)
        self._update_us: deque[float] = deque(maxlen=2000)
        self._health = HealthWindow(self.settings["diagnostics.window"])
        self._extra: Counter[str] = Counter()      # rejections the caller names (not coded)
        self._last_extra: str | None = None
        self._extra_resets: Counter[str] = Counter()
        self._window_start: float | None = None
        self.last_error: str | None = None
        self._configure(None)

    # -- the compiled runner's arrays ------------------------------------------------------
    def _configure(self, old: "Runner | None") -> None:
        """The layout, the settings array and the runner state for the current observer and
        settings (keeping the counters, the input and a held sample of ``old``)."""
        s, obs = self.settings, self.observer
        n, p, m = obs.n_states, obs.n_outputs, obs.n_inputs
        self._r = r = int(obs._ic[obs._K.N_UI])
        self._nconv = len(convergence_fields(obs))
        confirm = s["outlier.confirm"]
        ylim = G.channel_limits(s["limits.measurement"], p, "limits.measurement")
        ulim = G.channel_limits(s["limits.input"], m, "limits.input") if m else np.zeros(0)
        floor = G.channel_limits(s["outlier.min_scale"], p, "outlier.min_scale")
        x0 = s["observer.initial_estimate"]
        init = np.asarray(x0, dtype=float) if x0 else np.zeros(n)
        cfg = np.zeros(L.CFG_SCALARS)
        cfg[L.C_TIMEOUT] = s["input.timeout"]
        cfg[L.C_MAX_GAP] = s["time.max_gap"]
        cfg[L.C_RESET_ON_JUMP] = float(s["time.reset_on_jump"])
        cfg[L.C_JUMP] = s["time.jump_threshold"]
        cfg[L.C_LIM_EST] = s["limits.estimate"]
        cfg[L.C_RES_THR] = s["convergence.residual_threshold"]
        cfg[L.C_G_THRESH] = s["outlier.threshold"]
        cfg[L.C_G_ALPHA] = 1.0 / s["outlier.window"]
        cfg[L.C_G_MINHIST] = max(2, s["outlier.window"] // 4)
        cfg[L.C_G_MAXCONS] = s["outlier.max_consecutive"]
        cfg[L.C_HAS_INIT] = 1.0 if x0 else 0.0
        rl = np.zeros(16, dtype=np.int64)
        rl[L.L_N], rl[L.L_P], rl[L.L_M], rl[L.L_R], rl[L.L_NCONV] = n, p, m, r, self._nconv
        rl[L.L_CONFIRM] = confirm
        off = L.RS_SCALARS
        for key, width in ((L.L_U, m), (L.L_HELD_Y, p), (L.L_HELD_U, m), (L.L_X0, n),
                           (L.L_GATE, G.size(p, confirm)), (L.L_E, p)):
            rl[key] = off
            off += width
        width = off
        parts = [cfg]
        off = L.CFG_SCALARS
        for key, arr in ((L.L_YLIM, ylim), (L.L_ULIM, ulim), (L.L_FLOOR, floor), (L.L_INIT, init)):
            rl[key] = off
            off += arr.size
            parts.append(arr)
        self._cfg = np.concatenate(parts)
        self._rl = rl
        self._gate_args = (p, s["outlier.threshold"], int(cfg[L.C_G_MINHIST]))
        rs, rc, rh = L.new_state(1, rl, width, MAX_HELD_INPUTS * (1 + m))
        if old is not None:
            o = old._rs[0]
            for k in (L.T_INPUT, L.U_OK, L.HELD_ON, L.HELD_T, L.HELD_TINPUT, L.HELD_UOK,
                      L.HELD_KIND, L.HELD_N, L.ACCEPTED, L.REBASES, L.WIN_ACCEPTED, L.LAST_REJ,
                      L.HAS_OUT, L.LAST_RES, L.LAST_CONV, L.LAST_SINCE, L.LAST_GT):
                rs[0, k] = o[k]
            orl = old._rl
            rs[0, rl[L.L_U]:rl[L.L_U] + m] = o[orl[L.L_U]:orl[L.L_U] + m]
            rs[0, rl[L.L_HELD_Y]:rl[L.L_HELD_Y] + p] = o[orl[L.L_HELD_Y]:orl[L.L_HELD_Y] + p]
            rs[0, rl[L.L_HELD_U]:rl[L.L_HELD_U] + m] = o[orl[L.L_HELD_U]:orl[L.L_HELD_U] + m]
            rc[:] = old._rc
            rh[:] = old._rh
        self._rs, self._rc, self._rh = rs, rc, rh
        self._bind()
        self._js = self._joint_state_mapping()
        self._health.window = s["diagnostics.window"]
        self._one = self._events(1)

    def _bind(self) -> None:
        """The observer's arrays as rows of the (one-joint) arrays the block loop takes."""
        kernels, models, st, nx, c, ic, wk, clk = self.observer.program()
        self._prog = (kernels, models) + tuple(a.reshape(1, -1) for a in (st, nx, c, ic, wk, clk))

    def __deepcopy__(self, memo):
        import copy
        new = object.__new__(type(self))
        memo[id(self)] = new
        for k, v in self.__dict__.items():
            if k != "_prog":
                new.__dict__[k] = copy.deepcopy(v, memo)
        new._bind()
        return new

    def _events(self, count: int):
        """Event buffers and output arrays for ``count`` events of one joint."""
        v = max(self.observer.n_outputs, self.observer.n_inputs, 1)
        return (np.zeros(count, np.int8), np.zeros(count), np.zeros((count, 1, v)),
                np.zeros((count, 1), np.int16), np.zeros((count, 1), np.int16),
                np.zeros((count, 1, self.observer.n_states)), np.zeros((count, 1, self._r)),
                np.zeros((count, 1, self._nconv)))

    def _run(self, ev) -> None:
        start = time.perf_counter()
        L.run_block(*self._prog, self._rs, self._rl, self._rc, self._rh, self._cfg, *ev)
        count = ev[1].shape[0]
        if count:
            us = (time.perf_counter() - start) * 1e6 / count
            self._update_us.append(us)

    # -- configuration ------------------------------------------------------
    @property
    def observer_type(self) -> str:
        return self.observer_class.TYPE

    @property
    def convergence_fields(self) -> tuple[str, ...]:
        """The labels of the ``convergence`` values: the common ones, then the observer's."""
        return convergence_fields(self.observer)

    def reconfigure(self, flat_params: Mapping[str, Any]) -> None:
        """Apply changed parameters: validate everything, then swap in a new observer.

        Raises ConfigError and keeps running the old configuration when the
        new one is unusable.  The observer restarts (counted as 'reconfigure').
        """
        new = Runner(flat_params)
        if new.observer_type != self.observer_type:
            raise ConfigError("observer.type", "cannot be changed at run time; restart the node")
        old = self._snapshot()
        self.settings, self.observer_config, self.observer = new.settings, new.observer_config, new.observer
        self._configure(old)
        self.reset("reconfigure")

    def _snapshot(self) -> "Runner":
        """The arrays ``_configure`` carries over (a shallow stand-in)."""
        snap = Runner()
        snap._rs, snap._rl, snap._rc, snap._rh = self._rs, self._rl, self._rc, self._rh
        return snap

    # -- samples ----------------------------------------------------------------------
    def set_input(self, t: float, u) -> str | None:
        """Store the known input u valid from time t on.  Returns a rejection reason or None."""
        bad = check_vector(u, self.observer.n_inputs, "input")
        if bad is not None:
            self.reject(bad)
            return bad
        kind, ts, vals, pre, status = self._one[:5]
        kind[0] = L.INPUT
        ts[0] = t
        vals[0, 0, :self.observer.n_inputs] = u
        self._run(self._one)
        return reason(int(status[0, 0]))

    def process(self, t: float, y) -> Output | str:
        """Feed the measurement y taken at t.  Returns the Output, or why there is none:
        a rejection reason (counted), or ``HELD`` (held at a time discontinuity until the
        next sample confirms it)."""
        obs = self.observer
        bad = check_vector(y, obs.n_outputs, "measurement")
        if bad is not None:
            self.reject(bad)
            return bad
        ev = self._one
        kind, ts, vals, pre, status, ox, oui, oconv = ev
        kind[0] = L.MEASUREMENT
        ts[0] = t
        vals[0, 0, :obs.n_outputs] = y
        self._run(ev)
        st = int(status[0, 0])
        if st != L.OUTPUT:
            return reason(st)
        return self._output(t, ox[0, 0], oui[0, 0], oconv[0, 0])

    def process_block(self, kind: np.ndarray, t: np.ndarray, values: np.ndarray,
                      refused: np.ndarray | None = None) -> Block:
        """Many events at once, in time order: ``kind[k]`` (loop.MEASUREMENT, loop.INPUT,
        loop.REFUSED), ``t[k]``, ``values[k]`` (y or u: ``(K, width)`` or ``(K, 1, width)``)
        and ``refused[k]`` (the intake's rejection code of a REFUSED event, else 0).  The same
        outputs, rejections and restarts as the events one by one through ``process`` and
        ``set_input``."""
        count = len(t)
        kind = np.ascontiguousarray(kind, dtype=np.int8)
        t = np.ascontiguousarray(t, dtype=float)
        values = np.asarray(values, dtype=float)
        if values.ndim == 2:
            values = values[:, None, :]
        width = max(self.observer.n_outputs, self.observer.n_inputs, 1)
        if values.shape[2] < width:
            values = np.concatenate((values, np.zeros((count, 1, width - values.shape[2]))), axis=2)
        values = np.ascontiguousarray(values)
        pre = np.zeros((count, 1), np.int16) if refused is None else \
            np.ascontiguousarray(np.asarray(refused, dtype=np.int16).reshape(count, 1))
        ev = (kind, t, values, pre) + self._events(count)[4:]
        self._run(ev)
        return Block(ev[4], ev[5], ev[6], ev[7])

    def _output(self, t, x, ui, conv) -> Output:
        x = x.copy()
        js = None
        if self._js is not None:
            names, idx = self._js
            js = (names,) + tuple([float(x[i]) for i in ix] if ix is not None else [] for ix in idx)
        return Output(t, x, ui.copy() if self.observer.unknown_input is not None else None,
                      conv.copy(), js)

    @property
    def last_sample_time(self) -> float | None:
        """Time of the last accepted measurement since the last restart (None right after one)."""
        v = self._rs[0, L.T_LAST]
        return None if math.isnan(v) else float(v)

    def time_jump(self, t: float) -> None:
        """Time went back to t (bag loop, sim time reset, told by the node's clock): restart
        at once, and forget an input stamped after t, which belongs to the old timeline."""
        L.time_jump(self._rs[0], self._rc[0], self._rl, float(t), RESTART_CODE["time_jump"])

    def set_state(self, x) -> str | None:
        """Restart the observer from the estimate x (plant coordinates) at the next sample:
        the node's ``~/set_state``.  None when taken, else why not (length, non-finite,
        beyond ``limits.estimate``); counted as the restart ``set_state``."""
        n = self.observer.n_states
        bad = check_vector(x, n, "state")
        if bad is None and any(abs(v) > self.settings["limits.estimate"] for v in x):
            bad = "state_implausible"
        if bad is not None:
            return bad
        L.set_state(self._rs[0], self._rc[0], self._rl, np.asarray(x, dtype=float))
        self._requested()
        return None

    def reset(self, reason_: str = "service") -> None:
        """Restart the observer at the next sample (counted under ``reason_``).  A reset
        requested by a person (``service``, ``enable``, ``reconfigure``, ``set_state``) also
        clears the health window: the diagnostics level starts afresh."""
        requested = reason_ in REQUESTED
        code = RESTART_CODE.get(reason_)
        if code is None:                            # a reason of the caller's own
            self._extra_resets[reason_] += 1
            code = RESTART_CODE["other"]
        L.reset(self._rs[0], self._rc[0], self._rl, code, requested)
        if requested:
            self._requested()

    def _requested(self) -> None:
        self._rc[0, L.HW:] = 0
        self._health.clear()
        self.last_error = None

    def reject(self, reason_: str) -> None:
        """Count a sample the caller refused before it reached the runner (e.g. a
        JointState without the configured joint, a future stamp)."""
        code = CODE.get(reason_)
        if code is None:
            self._extra[reason_] += 1
            self._rc[0, L.HW_REJECTED] += 1
            self._last_extra = reason_
            self._rs[0, L.LAST_REJ] = -1.0
        else:
            L.reject(self._rs[0], self._rc[0], code)

    # -- counters by name -----------------------------------------------------------------
    @property
    def accepted(self) -> int:
        return int(self._rs[0, L.ACCEPTED])

    @property
    def rebases(self) -> int:
        return int(self._rs[0, L.REBASES])

    @property
    def rejected(self) -> Counter:
        out = Counter({REJECTIONS[i]: int(v) for i, v in enumerate(self._rc[0, :L.NREJ]) if v})
        out.update(self._extra)
        return out

    @property
    def resets(self) -> Counter:
        out = Counter({RESTARTS[i]: int(v) for i, v in
                       enumerate(self._rc[0, L.NREJ:L.NREJ + L.NRST]) if v and RESTARTS[i] != "other"})
        out.update(self._extra_resets)
        return out

    @property
    def last_rejection(self) -> str | None:
        code = int(self._rs[0, L.LAST_REJ])
        if code < 0:
            return self._last_extra
        return REJECTIONS[code] if code > 0 else None

    def _take_health(self) -> None:
        """Move the compiled loop's health bucket into the health window."""
        row = self._rc[0]
        for name_, idx in (("accepted", L.HW_ACCEPTED), ("rejected", L.HW_REJECTED),
                           ("rebase", L.HW_REBASE)):
            if row[idx]:
                self._health.count(name_, int(row[idx]))
        for i, name_ in enumerate(RESTARTS):
            v = row[L.HW_RESTARTS + i]
            if v and name_ != "other":
                self._health.count(name_, int(v))
        row[L.HW:] = 0

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
        rs = self._rs[0]
        if rs[L.HAS_OUT] == 0.0 or math.isnan(rs[L.T0]):
            return "waiting"
        if not rs[L.LAST_CONV]:
            return "converging"
        if rs[L.LAST_RES] > self.settings["convergence.residual_threshold"]:
            return "diverging"
        return "converged"

    def update_time_us(self) -> tuple[float, float]:
        """(p50, p99) of the recent per-sample processing times in microseconds (a block's
        time divided by its events; nan before any)."""
        if not self._update_us:
            return float("nan"), float("nan")
        a = np.fromiter(self._update_us, float)
        return float(np.percentile(a, 50)), float(np.percentile(a, 99))

    def _last_convergence(self) -> tuple[float, float, float] | None:
        """(time since start, guaranteed time, residual) of the last output, if any."""
        rs = self._rs[0]
        if rs[L.HAS_OUT] == 0.0:
            return None
        return float(rs[L.LAST_SINCE]), float(rs[L.LAST_GT]), float(rs[L.LAST_RES])

    def status(self, now: float | None = None) -> Status:
        """The diagnostics status; the level from the last ``diagnostics.window`` seconds
        of ``now`` (the caller's clock: node ROS time, replay sample time), see health.py."""
        obs, s = self.observer, self.settings
        self._take_health()
        state = self.state_name()
        recent = self._health.close(now)
        rs = self._rs[0]
        values: list[tuple[str, str]] = [("observer", obs.TYPE), ("state", state)]
        level, problems = OK, []
        last = self._last_convergence()
        if last is not None:
            since, gt, res = last
            values += [("time since start (s)", f"{since:.4f}"),
                       ("guaranteed convergence time (s)",
                        "none" if math.isinf(gt) else f"{gt:.4g}"),
                       ("output residual", f"{res:.4g}")]
        values += [("samples accepted", str(self.accepted)),
                   ("samples rejected", str(sum(self.rejected.values())))]
        values += [(f"rejected: {k}", str(v)) for k, v in sorted(self.rejected.items())]
        values += [(f"restarts: {k}", str(v)) for k, v in sorted(self.resets.items())]
        gate = G.summary(rs[self._rl[L.L_GATE]:], *self._gate_args)
        values.append(("outlier gate", gate + (f"; re-based {self.rebases} time(s)" if self.rebases else "")))
        if obs.n_inputs:
            t_in = rs[L.T_INPUT]
            age = (now - t_in) if (now is not None and not math.isnan(t_in)) else None
            values.append(("input age (s)", "never received" if math.isnan(t_in) else
                           (f"{age:.4f}" if age is not None else "n/a")))
        p50, p99 = self.update_time_us()
        values.append(("update time p50/p99 (us)", f"{p50:.1f} / {p99:.1f}"))
        win = rs[L.WIN_ACCEPTED]
        if now is not None and self._window_start is not None and now > self._window_start:
            rate = win / (now - self._window_start)
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
        rs[L.WIN_ACCEPTED] = 0.0
        message = state if not problems else f"{state}: " + "; ".join(problems)
        return Status(level, message, values)
