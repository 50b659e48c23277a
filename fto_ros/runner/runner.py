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
message values to arrays, the Output of one sample, counters by name.  Its memory is
laid out by layout.py, its /diagnostics assembled by status.py.

ROS-free.
"""
from __future__ import annotations

import math
import time
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError, UsageError
from ..core.reasons import CODE, REJECTIONS, RESTART_CODE, RESTARTS, REQUESTED
from ..core.params import check_vector
from ..observers import make
from ..observers.base import KernelObserver, Observer
from . import loop as L
from . import joints as JX
from . import layout as LY
from . import settings as S
from ..core import jit as J_
from .arm_intake import arm_intake
from .build import changed_names, design_guard
from . import status as ST
from .health import HealthWindow
from .sources.plan import estimated_joint_states
from .status import Status

#: order of the values on the ``convergence`` topic
CONVERGENCE_FIELDS = ("time_since_start", "output_residual", "converged", "guaranteed_time", "health")


def convergence_fields(obs: Observer) -> tuple[str, ...]:
    """The labels of ``obs``'s ``convergence`` values: the common ones, then its own."""
    return CONVERGENCE_FIELDS + tuple(obs.CONVERGENCE_EXTRA)


#: what ``process`` returns for a sample held at a time discontinuity (not a rejection:
#: it is used once the next sample confirms the jump)
HELD = "held_at_time_jump"


@dataclass
class Output:
    """What one accepted sample produces (all finite)."""
    t: float
    estimate: np.ndarray
    unknown_input: np.ndarray | None
    convergence: np.ndarray          # CONVERGENCE_FIELDS; guaranteed_time may be inf (no guarantee)
    joint_state: tuple | None        # (names, position, velocity, effort) lists, or None


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
    diagnostics.  Without ``joints`` there is one "joint": the observer of the whole plant."""

    def __init__(self, flat_params: Mapping[str, Any], changed: Sequence[str] | None = None):
        """ConfigError for unusable parameters, whatever fails (build.py): blamed on the
        ``changed`` names when given (a run-time change), else on the observer's section."""
        with design_guard(flat_params, changed):
            joints = flat_params.get("joints") or []
            flats = [dict(flat_params)]
            if isinstance(joints, (list, tuple)) and joints and not S.is_arm(flat_params) \
                    and all(isinstance(j, str) for j in joints):
                flats = JX.per_joint(flat_params, joints)
            parts = [S.split(f) for f in flats]
            self.settings, self.observer_class, self.observer_config = parts[0]
            arm = getattr(self.observer_class, "ARM", False)
            #: an arm family's JointState intake (runner/arm_intake.py), else None
            self.intake = None
            self.joints = [] if arm else list(self.settings["joints"])
            type_name = self.settings["observer.type"]
            self.observers: list[KernelObserver] = [make(type_name, cfg) for _, _, cfg in parts]
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
        """The joints' observer memories as rows of one array each (layout.py), and every
        joint's model terms: what the block loop takes."""
        self._arrays = LY.stack(self.observers, self.joints)
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

    # -- the compiled runner's memory (layout.py) ------------------------------------------
    def _configure(self, old: "Runner | None" = None) -> None:
        """The memory for the current observers and settings (keeping the counters, the
        input and a held sample of ``old``)."""
        self._mem = LY.configure(self.settings, self.observer, len(self.observers),
                                 len(convergence_fields(self.observer)),
                                 None if old is None else old._mem)
        self._js = estimated_joint_states(self.settings)
        for h in self._health:
            h.window = self.settings["diagnostics.window"]
        self._one = self._events(1)
        self._joint_ev: dict = {}       # process_joints_arrays' event buffers, per count

    def _events(self, count: int):
        return LY.events(count, len(self.observers), self.observer, self._mem.r,
                         self._mem.nconv)

    def _run(self, ev) -> None:
        start = time.perf_counter()
        mem = self._mem
        L.run_block(*self._prog, mem.rs, mem.rl, mem.rc, mem.rh, mem.cfg, *ev)
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
                  "_prog", "_mem", "_js", "_one", "_joint_ev", "_flat", "intake"):
            setattr(self, k, getattr(new, k))
        for h in self._health:
            h.window = self.settings["diagnostics.window"]
        self.reset("reconfigure")

    # -- samples ----------------------------------------------------------------------
    def _single(self) -> None:
        if len(self.observers) != 1:
            raise UsageError("a runner of several joints takes samples through process_joints "
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

    def process_rows(self, kind: np.ndarray, t: np.ndarray, values: np.ndarray,
                     pre: np.ndarray):
        """``process_block`` of rows already in the loop's layout (a source's Rows: int8
        kinds, times, (K, J, width) values, (K, J) int16 codes): (status, estimate, unknown
        input, convergence) in buffers the next call of as many rows reuses (the node)."""
        out = self._joint_ev.get(("rows", len(t)))
        if out is None:
            out = self._joint_ev[("rows", len(t))] = self._events(len(t))[4:]
        self._run((kind, t, values, pre) + out)
        return out

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
        return Output(t, x, ui.copy() if self._mem.r else None, conv.copy(), js)

    def last_sample_time(self, joint: int = 0) -> float | None:
        """Time of the last accepted measurement since the last restart (None right after one)."""
        v = self._mem.rs[joint, L.T_LAST]
        return None if math.isnan(v) else float(v)

    def time_jump(self, t: float) -> None:
        """Time went back to t (bag loop, sim time reset, told by the node's clock): restart
        at once, and forget an input stamped after t, which belongs to the old timeline."""
        for j in range(len(self.observers)):
            L.time_jump(self._mem.rs[j], self._mem.rc[j], self._mem.rl, float(t), RESTART_CODE["time_jump"])

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
        L.set_state(self._mem.rs[joint], self._mem.rc[joint], self._mem.rl, np.asarray(x, dtype=float))
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
            L.reset(self._mem.rs[j], self._mem.rc[j], self._mem.rl, c, requested)
            if requested:
                self._requested(j)

    def _requested(self, j: int) -> None:
        self._mem.rc[j, L.HW:] = 0
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
                self._mem.rc[j, L.HW_REJECTED] += 1
                self._last_extra[j] = reason_
                self._mem.rs[j, L.LAST_REJ] = -1.0
            else:
                L.reject(self._mem.rs[j], self._mem.rc[j], code)

    # -- counters by name (summed over the joints) -------------------------------------------
    @property
    def accepted(self) -> int:
        return int(self._mem.rs[:, L.ACCEPTED].sum())

    @property
    def rebases(self) -> int:
        return int(self._mem.rs[:, L.REBASES].sum())

    def rejected_of(self, j: int) -> Counter:
        out = Counter({REJECTIONS[i]: int(v) for i, v in enumerate(self._mem.rc[j, :L.NREJ]) if v})
        out.update(self._extra[j])
        return out

    def resets_of(self, j: int) -> Counter:
        out = Counter({RESTARTS[i]: int(v) for i, v in
                       enumerate(self._mem.rc[j, L.NREJ:L.NREJ + L.NRST]) if v and RESTARTS[i] != "other"})
        out.update(self._extra_resets[j])
        return out

    @property
    def rejected(self) -> Counter:
        return sum((self.rejected_of(j) for j in range(len(self.observers))), Counter())

    @property
    def resets(self) -> Counter:
        return sum((self.resets_of(j) for j in range(len(self.observers))), Counter())

    def last_rejection_of(self, j: int) -> str | None:
        code = int(self._mem.rs[j, L.LAST_REJ])
        if code < 0:
            return self._last_extra[j]
        return REJECTIONS[code] if code > 0 else None

    @property
    def last_rejection(self) -> str | None:
        return self.last_rejection_of(0)

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

    # -- diagnostics (status.py) ------------------------------------------------------
    def state_name(self, joint: int = 0) -> str:
        """'waiting', 'converging', 'converged' or 'diverging'."""
        return ST.state_name(self, joint)

    def update_time_us(self) -> tuple[float, float]:
        """(p50, p99) of the recent per-sample processing times in microseconds (a block's
        time divided by its events; nan before any)."""
        return ST.update_time_us(self._update_us)

    def status(self, now: float | None = None) -> Status:
        """The diagnostics status (of the one observer; with several joints, the summary of
        theirs: the worst level, and the joints that are not OK); the level from the last
        ``diagnostics.window`` seconds of ``now`` (the caller's clock: node ROS time, replay
        sample time), see health.py."""
        return self.statuses(now)[0]

    def statuses(self, now: float | None = None) -> list[Status]:
        """[the status] with one joint; [summary, joint 1, ..., joint J] with several."""
        return ST.statuses(self, now)
