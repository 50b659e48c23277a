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
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError
from ..core.reasons import CODE, REJECTIONS, RESTART_CODE, RESTARTS, REQUESTED
from ..core.params import check_vector
from ..observers.base import KernelObserver, Observer
from . import gate as G
from . import loop as L
from . import joints as JX
from . import settings as S
from ..core import jit as J_
from .arm_intake import arm_intake
from .build import changed_names, design_guard
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
    """The rejection reason of a block status (None: an output, a taken input or a skipped
    event; HELD)."""
    if status == L.HELD:
        return HELD
    return REJECTIONS[status] if status > 0 else None


class Runner:
    """Validates samples, drives one observer per joint (compiled kernels), builds outputs and
    diagnostics.  Without ``joints`` there is one "joint": the observer of the whole plant.
    Observer families not yet compiled run on the previous runner (runner/legacy.py) behind
    the same interface."""

    def __new__(cls, flat_params: Mapping[str, Any] | None = None,
                changed: Sequence[str] | None = None):
        if flat_params is None:                     # copy.deepcopy
            return super().__new__(cls)
        with design_guard(flat_params, changed):
            joints = flat_params.get("joints") or []
            flats = [dict(flat_params)]
            if isinstance(joints, (list, tuple)) and joints and not S.is_arm(flat_params) \
                    and all(isinstance(j, str) for j in joints):
                flats = JX.per_joint(flat_params, joints)
            parts = [S.split(f) for f in flats]
        obs_class = parts[0][1]
        if cls is Runner and not issubclass(obs_class, KernelObserver):
            if len(flats) > 1:
                raise ConfigError("joints", f"{obs_class.TYPE} runs one observer at a time until "
                                  "its compiled kernel exists: leave joints empty")
            from .legacy import LegacyRunner
            return LegacyRunner(flat_params, changed)
        self = super().__new__(cls)
        self._split = (flats, parts)
        return self

    def __init__(self, flat_params: Mapping[str, Any] | None = None,
                 changed: Sequence[str] | None = None):
        """ConfigError for unusable parameters, whatever fails (build.py): blamed on the
        ``changed`` names when given (a run-time change), else on the observer's section."""
        if flat_params is None:
            return
        flats, parts = self._split
        del self._split
        self.settings, self.observer_class, self.observer_config = parts[0]
        arm = getattr(self.observer_class, "ARM", False)
        #: an arm family's JointState intake (runner/arm_intake.py), else None
        self.intake = None
        self.joints = [] if arm else list(self.settings["joints"])
        with design_guard(flat_params, changed):
            self.observers: list[KernelObserver] = [cls(cfg) for _, cls, cfg in parts]
            self.observer = obs = self.observers[0]
            if arm:
                self.intake = arm_intake(obs, self.settings)
            else:
                S.check_settings(self.settings, obs.n_states, obs.n_outputs, obs.n_inputs)
            self._roles = self._joint_roles(flats) if self.joints else None
        self._flat = dict(flat_params)
        self._update_us: deque[float] = deque(maxlen=2000)
        J = len(self.observers)
        self._health = [HealthWindow(self.settings["diagnostics.window"]) for _ in range(J)]
        self._extra = [Counter() for _ in range(J)]     # rejections the caller names (not coded)
        self._last_extra: list[str | None] = [None] * J
        self._extra_resets = [Counter() for _ in range(J)]
        self._window_start: float | None = None
        self.last_error: str | None = None
        self._stack()
        self._configure()
        self._warm()

    def _warm(self) -> None:
        """Compile (or load from the cache) the block loop for this observer now, not at the
        first sample: an empty block."""
        start = time.perf_counter()
        self._run(self._events(0))
        J_.COMPILED.note("runner block loop", time.perf_counter() - start)

    def _joint_roles(self, flats) -> list:
        from ..plant import given, resolve_plant
        out = []
        for f, obs in zip(flats, self.observers):
            plant = resolve_plant(f) if given(f) else None
            out.append(JX.roles(self.settings, plant, obs.state_names,
                                obs.unknown_input is not None))
        return out

    def _stack(self) -> None:
        """The joints' observer memories as rows of one array each (the adapters keep views
        of their rows), and every joint's model terms."""
        progs = [o.program() for o in self.observers]
        first = progs[0]
        for j, prog in enumerate(progs[1:], 1):
            same = all(a.shape == b.shape for a, b in zip(prog[2:], first[2:])) and \
                np.array_equal(prog[5], first[5])
            if not same:
                raise ConfigError("joints", f"the observer of joint {self.joints[j]} has another "
                                  f"structure than that of {self.joints[0]} (a per-joint constant "
                                  "changed what the observer derives): give such joints a plant "
                                  "and a node of their own")
        arrays = [np.ascontiguousarray(np.stack([p[k] for p in progs])) for k in range(2, 8)]
        for j, o in enumerate(self.observers):
            o.adopt(*(a[j] for a in arrays))
        self._arrays = arrays
        self._bind()

    def _bind(self) -> None:
        kernels = self.observer.program()[0]
        models = J_.function_list([o.program()[1] for o in self.observers], J_.MODELS_BY_JOINT)
        self._prog = (kernels, models, *self._arrays)

    def __deepcopy__(self, memo):
        import copy
        new = object.__new__(type(self))
        memo[id(self)] = new
        for k, v in self.__dict__.items():
            if k not in ("_prog", "_arrays"):
                new.__dict__[k] = copy.deepcopy(v, memo)
        new._stack()
        return new

    # -- the compiled runner's arrays ------------------------------------------------------
    def _configure(self, old: "Runner | None" = None) -> None:
        """The layout, the settings array and the runner state for the current observers and
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
        rs, rc, rh = L.new_state(len(self.observers), rl, width, MAX_HELD_INPUTS * (1 + m))
        if old is not None:
            orl = old._rl
            same_inputs = orl[L.L_M] == m          # else the old input does not fit: forgotten
            for j in range(rs.shape[0]):
                o = old._rs[j]
                for k in (L.ACCEPTED, L.REBASES, L.WIN_ACCEPTED, L.LAST_REJ, L.HAS_OUT,
                          L.LAST_RES, L.LAST_CONV, L.LAST_SINCE, L.LAST_GT):
                    rs[j, k] = o[k]
                if same_inputs:
                    for k in (L.T_INPUT, L.U_OK, L.HELD_ON, L.HELD_T, L.HELD_TINPUT, L.HELD_UOK,
                              L.HELD_KIND, L.HELD_N):
                        rs[j, k] = o[k]
                    for key, w in ((L.L_U, m), (L.L_HELD_Y, p), (L.L_HELD_U, m)):
                        rs[j, rl[key]:rl[key] + w] = o[orl[key]:orl[key] + w]
            rc[:] = old._rc
            if same_inputs:
                rh[:] = old._rh
        self._rs, self._rc, self._rh = rs, rc, rh
        self._js = self._joint_state_mapping()
        for h in self._health:
            h.window = s["diagnostics.window"]
        self._one = self._events(1)
        self._joint_ev: dict = {}       # process_joints_arrays' event buffers, per count


    def _events(self, count: int):
        """Event buffers and output arrays for ``count`` events of every joint."""
        J, obs = len(self.observers), self.observer
        v = max(obs.n_outputs, obs.n_inputs, 1)
        return (np.zeros(count, np.int8), np.zeros(count), np.zeros((count, J, v)),
                np.zeros((count, J), np.int16), np.zeros((count, J), np.int16),
                np.zeros((count, J, obs.n_states)), np.zeros((count, J, self._r)),
                np.zeros((count, J, self._nconv)))

    def _run(self, ev) -> None:
        start = time.perf_counter()
        L.run_block(*self._prog, self._rs, self._rl, self._rc, self._rh, self._cfg, *ev)
        count = ev[1].shape[0]
        if count:
            self._update_us.append((time.perf_counter() - start) * 1e6 / count)

    # -- configuration ------------------------------------------------------
    @property
    def observer_type(self) -> str:
        return self.observer_class.TYPE

    @property
    def convergence_fields(self) -> tuple[str, ...]:
        """The labels of the ``convergence`` values: the common ones, then the observer's."""
        return convergence_fields(self.observer)

    @property
    def n_joints(self) -> int:
        """Observers this runner runs side by side (1 without ``joints``)."""
        return len(self.observers)

    def reconfigure(self, flat_params: Mapping[str, Any]) -> None:
        """Apply changed parameters: validate everything, then swap in new observers.

        Raises ConfigError and keeps running the old configuration when the
        new one is unusable.  The observers restart (counted as 'reconfigure').
        """
        new = Runner(flat_params, changed_names(self._flat, flat_params))
        if new.observer_type != self.observer_type:
            raise ConfigError("observer.type", "cannot be changed at run time; restart the node")
        if new.joints != self.joints:
            raise ConfigError("joints", "cannot be changed at run time; restart the node")
        new._configure(self)                     # the counters, inputs and held samples go on
        for k in ("settings", "observer_config", "observer", "observers", "_roles", "_arrays",
                  "_prog", "_r", "_nconv", "_cfg", "_rl", "_gate_args", "_rs", "_rc", "_rh",
                  "_js", "_one", "_joint_ev", "_flat", "intake"):
            setattr(self, k, getattr(new, k))
        for h in self._health:
            h.window = self.settings["diagnostics.window"]
        self.reset("reconfigure")

    # -- samples ----------------------------------------------------------------------
    def _single(self) -> None:
        if len(self.observers) != 1:
            raise TypeError("a runner of several joints takes samples through process_joints "
                            "or process_block")

    def set_input(self, t: float, u) -> str | None:
        """Store the known input u valid from time t on.  Returns a rejection reason or None."""
        self._single()
        bad = check_vector(u, self.observer.n_inputs, "input")
        if bad is not None:
            self.reject(bad)
            return bad
        kind, ts, vals, pre, status = self._one[:5]
        kind[0] = L.INPUT
        ts[0] = t
        pre[0, 0] = 0
        vals[0, 0, :self.observer.n_inputs] = u
        self._run(self._one)
        return reason(int(status[0, 0]))

    def process(self, t: float, y) -> Output | str:
        """Feed the measurement y taken at t.  Returns the Output, or why there is none:
        a rejection reason (counted), or ``HELD`` (held at a time discontinuity until the
        next sample confirms it)."""
        self._single()
        obs = self.observer
        bad = check_vector(y, obs.n_outputs, "measurement")
        if bad is not None:
            self.reject(bad)
            return bad
        ev = self._one
        kind, ts, vals, pre, status, ox, oui, oconv = ev
        kind[0] = L.MEASUREMENT
        ts[0] = t
        pre[0, 0] = 0
        vals[0, 0, :obs.n_outputs] = y
        self._run(ev)
        st = int(status[0, 0])
        if st != L.OUTPUT:
            return reason(st)
        return self._output(t, 0, ox[0, 0], oui[0, 0], oconv[0, 0])

    def process_joints(self, t: float, y: np.ndarray, u: np.ndarray | None = None,
                       refused: np.ndarray | None = None) -> list[Output | str | None]:
        """One message for every joint (a JointState): the inputs u (J x m; None: no input
        in this message), then the measurements y (J x p) at t, each joint's own.
        ``refused[j]`` is the intake's rejection code for joint j (0: none; its values are
        then not used, the rejection counted once).  Per joint: its Output, a rejection
        reason, None (its input was refused: the measurement is not paired with it), or
        HELD."""
        status, ox, oui, oconv = self.process_joints_arrays(t, y, u, refused)
        out: list[Output | str | None] = []
        for j in range(len(self.observers)):
            st = int(status[-1, j])
            if st == L.SKIPPED:
                out.append(reason(int(status[0, j])) if status.shape[0] == 2 else None)
            elif st == L.OUTPUT:
                out.append(self._output(t, j, ox[-1, j], oui[-1, j], oconv[-1, j]))
            else:
                out.append(reason(st))
        return out

    def process_joints_arrays(self, t: float, y: np.ndarray, u: np.ndarray | None = None,
                              refused: np.ndarray | None = None):
        """``process_joints`` without building an Output per joint (the node's per-message
        path): (status (K, J), estimate (K, J, n), unknown input (K, J, r), convergence
        (K, J, c)) with K = 2 when u is given (the input's event, then the measurement's),
        else 1; the last row is the measurement's.  The arrays are reused by the next call."""
        obs = self.observer
        count = 1 if u is None else 2
        ev = self._joint_ev.get(count)
        if ev is None:
            ev = self._joint_ev[count] = self._events(count)
        kind, ts, vals, pre, status, ox, oui, oconv = ev
        ts[:] = t
        pre[:] = 0
        if refused is not None:
            pre[-1] = refused
            if count == 2:
                pre[0] = np.where(np.asarray(refused) != 0, -1, 0)
        if u is not None:
            kind[0] = L.INPUT
            vals[0, :, :obs.n_inputs] = u
        kind[-1] = L.PAIRED if u is not None else L.MEASUREMENT
        vals[-1, :, :obs.n_outputs] = y
        self._run(ev)
        return status, ox, oui, oconv

    def process_block(self, kind: np.ndarray, t: np.ndarray, values: np.ndarray,
                      refused: np.ndarray | None = None) -> Block:
        """Many events at once, in time order: ``kind[k]`` (loop.MEASUREMENT, loop.INPUT,
        loop.REFUSED), ``t[k]``, ``values[k]`` (y or u: ``(K, width)`` for one joint or
        ``(K, J, width)``) and ``refused[k]`` (``(K,)`` or ``(K, J)``: the intake's
        rejection code, else 0).  The same outputs, rejections and restarts as the events
        one by one through ``process`` and ``set_input``."""
        J, obs = len(self.observers), self.observer
        count = len(t)
        kind = np.ascontiguousarray(kind, dtype=np.int8)
        t = np.ascontiguousarray(t, dtype=float)
        values = np.asarray(values, dtype=float)
        if values.ndim == 2:
            values = values[:, None, :]
        width = max(obs.n_outputs, obs.n_inputs, 1)
        if values.shape[2] < width:
            values = np.concatenate((values, np.zeros(values.shape[:2] + (width - values.shape[2],))),
                                    axis=2)
        # writable: a broadcast view is read-only, and the compiled loop takes writable arrays
        values = np.require(np.broadcast_to(values, (count, J, values.shape[2])),
                            requirements=("C", "W"))
        pre = np.zeros((count, J), np.int16)
        if refused is not None:
            r = np.asarray(refused, dtype=np.int16)
            pre[:] = r.reshape(count, 1) if r.ndim == 1 else r
        ev = (kind, t, values, pre) + self._events(count)[4:]
        self._run(ev)
        return Block(ev[4], ev[5], ev[6], ev[7])

    def _output(self, t, j, x, ui, conv) -> Output:
        x = x.copy()
        js = None
        if self._js is not None:
            names, idx = self._js
            js = (names,) + tuple([float(x[i]) for i in ix] if ix is not None else [] for ix in idx)
        return Output(t, x, ui.copy() if self._r else None, conv.copy(), js)

    def last_sample_time(self, joint: int = 0) -> float | None:
        """Time of the last accepted measurement since the last restart (None right after one)."""
        v = self._rs[joint, L.T_LAST]
        return None if math.isnan(v) else float(v)

    def time_jump(self, t: float) -> None:
        """Time went back to t (bag loop, sim time reset, told by the node's clock): restart
        at once, and forget an input stamped after t, which belongs to the old timeline."""
        for j in range(len(self.observers)):
            L.time_jump(self._rs[j], self._rc[j], self._rl, float(t), RESTART_CODE["time_jump"])

    def set_state(self, x, joint: int = 0) -> str | None:
        """Restart the observer (of ``joint``) from the estimate x (plant coordinates) at the
        next sample: the node's ``~/set_state``.  None when taken, else why not (length,
        non-finite, beyond ``limits.estimate``); counted as the restart ``set_state``."""
        n = self.observer.n_states
        bad = check_vector(x, n, "state")
        if bad is None and any(abs(v) > self.settings["limits.estimate"] for v in x):
            bad = "state_implausible"
        if bad is not None:
            return bad
        L.set_state(self._rs[joint], self._rc[joint], self._rl, np.asarray(x, dtype=float))
        self._requested(joint)
        return None

    def reset(self, reason_: str = "service", joint: int | None = None) -> None:
        """Restart the observer (of every joint, or of ``joint``) at the next sample
        (counted under ``reason_``).  A reset requested by a person (``service``, ``enable``,
        ``reconfigure``, ``set_state``) also clears the health window: the diagnostics level
        starts afresh."""
        requested = reason_ in REQUESTED
        code = RESTART_CODE.get(reason_)
        for j in (range(len(self.observers)) if joint is None else (joint,)):
            c = code
            if c is None:                               # a reason of the caller's own
                self._extra_resets[j][reason_] += 1
                c = RESTART_CODE["other"]
            L.reset(self._rs[j], self._rc[j], self._rl, c, requested)
            if requested:
                self._requested(j)

    def _requested(self, j: int) -> None:
        self._rc[j, L.HW:] = 0
        self._health[j].clear()
        self.last_error = None

    def reject(self, reason_: str, joint: int | None = None) -> None:
        """Count a sample the caller refused before it reached the runner (e.g. a
        JointState without the configured joint, a future stamp): for every joint, or for
        ``joint``."""
        code = CODE.get(reason_)
        for j in (range(len(self.observers)) if joint is None else (joint,)):
            if code is None:
                self._extra[j][reason_] += 1
                self._rc[j, L.HW_REJECTED] += 1
                self._last_extra[j] = reason_
                self._rs[j, L.LAST_REJ] = -1.0
            else:
                L.reject(self._rs[j], self._rc[j], code)

    # -- counters by name (summed over the joints) -------------------------------------------
    @property
    def accepted(self) -> int:
        return int(self._rs[:, L.ACCEPTED].sum())

    @property
    def rebases(self) -> int:
        return int(self._rs[:, L.REBASES].sum())

    def rejected_of(self, j: int) -> Counter:
        out = Counter({REJECTIONS[i]: int(v) for i, v in enumerate(self._rc[j, :L.NREJ]) if v})
        out.update(self._extra[j])
        return out

    def resets_of(self, j: int) -> Counter:
        out = Counter({RESTARTS[i]: int(v) for i, v in
                       enumerate(self._rc[j, L.NREJ:L.NREJ + L.NRST]) if v and RESTARTS[i] != "other"})
        out.update(self._extra_resets[j])
        return out

    @property
    def rejected(self) -> Counter:
        return sum((self.rejected_of(j) for j in range(len(self.observers))), Counter())

    @property
    def resets(self) -> Counter:
        return sum((self.resets_of(j) for j in range(len(self.observers))), Counter())

    def last_rejection_of(self, j: int) -> str | None:
        code = int(self._rs[j, L.LAST_REJ])
        if code < 0:
            return self._last_extra[j]
        return REJECTIONS[code] if code > 0 else None

    @property
    def last_rejection(self) -> str | None:
        return self.last_rejection_of(0)

    def _take_health(self, j: int) -> None:
        """Move the compiled loop's health bucket of joint j into its health window."""
        row, health = self._rc[j], self._health[j]
        for name_, idx in (("accepted", L.HW_ACCEPTED), ("rejected", L.HW_REJECTED),
                           ("rebase", L.HW_REBASE)):
            if row[idx]:
                health.count(name_, int(row[idx]))
        for i, name_ in enumerate(RESTARTS):
            v = row[L.HW_RESTARTS + i]
            if v and name_ != "other":
                health.count(name_, int(v))
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

    @property
    def joint_state_map(self):
        """(names, per JointState field the state indices or None) of the
        estimated_joint_states settings, or None when they name no joint."""
        return self._js

    @property
    def roles(self):
        """Per joint (per-joint mode): which state is its position and velocity and where its
        effort comes from (runner/joints.py); None without ``joints``."""
        return self._roles

    # -- diagnostics --------------------------------------------------------
    def state_name(self, joint: int = 0) -> str:
        """'waiting', 'converging', 'converged' or 'diverging'."""
        rs = self._rs[joint]
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

    def status(self, now: float | None = None) -> Status:
        """The diagnostics status (of the one observer; with several joints, the summary of
        theirs: the worst level, and the joints that are not OK); the level from the last
        ``diagnostics.window`` seconds of ``now`` (the caller's clock: node ROS time, replay
        sample time), see health.py."""
        statuses = self.statuses(now)
        return statuses[0]

    def statuses(self, now: float | None = None) -> list[Status]:
        """[the status] with one joint; [summary, joint 1, ..., joint J] with several."""
        J = len(self.observers)
        each = [self._joint_status(now, j) for j in range(J)]
        self._window_start = now
        self._rs[:, L.WIN_ACCEPTED] = 0.0
        if J == 1:
            return each
        worst = max(st.level for st in each)
        bad = [f"{name}: {st.message}" for name, st in zip(self.joints, each) if st.level > OK]
        values = [("observer", self.observer.TYPE), ("joints", ", ".join(self.joints)),
                  ("samples accepted", str(self.accepted)),
                  ("samples rejected", str(sum(self.rejected.values())))]
        values += [(f"{name}: state", self.state_name(j)) for j, name in enumerate(self.joints)]
        p50, p99 = self.update_time_us()
        values.append(("update time p50/p99 (us, all joints)", f"{p50:.1f} / {p99:.1f}"))
        message = "all joints OK" if not bad else "; ".join(bad)
        return [Status(worst, message, values)] + each

    def _joint_status(self, now: float | None, j: int) -> Status:
        obs, s = self.observers[j], self.settings
        self._take_health(j)
        state = self.state_name(j)
        recent = self._health[j].close(now)
        rs = self._rs[j]
        values: list[tuple[str, str]] = [("observer", obs.TYPE), ("state", state)]
        if self.joints:
            values.insert(0, ("joint", self.joints[j]))
        level, problems = OK, []
        if rs[L.HAS_OUT] != 0.0:
            gt = float(rs[L.LAST_GT])
            values += [("time since start (s)", f"{float(rs[L.LAST_SINCE]):.4f}"),
                       ("guaranteed convergence time (s)",
                        "none" if math.isinf(gt) else f"{gt:.4g}"),
                       ("output residual", f"{float(rs[L.LAST_RES]):.4g}")]
        accepted = int(rs[L.ACCEPTED])
        rejected = self.rejected_of(j)
        values += [("samples accepted", str(accepted)),
                   ("samples rejected", str(sum(rejected.values())))]
        values += [(f"rejected: {k}", str(v)) for k, v in sorted(rejected.items())]
        values += [(f"restarts: {k}", str(v)) for k, v in sorted(self.resets_of(j).items())]
        rebases = int(rs[L.REBASES])
        gate = G.summary(rs[self._rl[L.L_GATE]:], *self._gate_args)
        values.append(("outlier gate", gate + (f"; re-based {rebases} time(s)" if rebases else "")))
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
                            f"(last: {self.last_rejection_of(j)})")
        if recent.get("rebase"):
            level = WARN
            problems.append("the outlier gate accepted a persisting change of the signal")
        for warning in getattr(obs, "warnings", lambda: ())():   # the observer's own
            level = max(level, WARN)
            problems.append(warning)
        if state == "diverging":
            level = WARN
            problems.append("output residual above convergence.residual_threshold after the guaranteed time")
        if state == "waiting":
            level = WARN
            problems.append("no accepted measurement yet" if accepted == 0 else "restarted, waiting for a sample")
        idle = self._health[j].idle_for(now)
        if accepted and idle > s["diagnostics.stale_after"]:
            level = WARN
            problems.append(f"no measurement accepted for {idle:.1f} s")
        if self.last_error:
            values.append(("last observer error", self.last_error))
        if failures:
            level = ERROR
            problems.append(f"the observer failed (non-finite or implausible values, or an internal "
                            f"error) and was restarted in the {window}")
        message = state if not problems else f"{state}: " + "; ".join(problems)
        return Status(level, message, values)
