"""The compiled runner's memory (runner/loop.py reads it): the settings as an array, the
layout of a joint's row, the rows of every joint, the event buffers of a block, and the
joints' observer memories stacked into one array each.

``configure`` builds it for an observer and the typed settings, keeping the counters, the
input and a held sample of the memory it replaces (a run-time change goes on where the old
configuration stopped).  ROS-free.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError
from ..observers.base import KernelObserver
from . import gate as G
from . import loop as L

#: rs scalars a reconfiguration carries over (the counters, the last outputs)
_KEPT = (L.ACCEPTED, L.REBASES, L.WIN_ACCEPTED, L.LAST_REJ, L.HAS_OUT, L.LAST_RES,
         L.LAST_CONV, L.LAST_SINCE, L.LAST_GT)
#: rs scalars carried over when the input still fits (its age, a held sample)
_KEPT_WITH_INPUT = (L.T_INPUT, L.U_OK, L.HELD_ON, L.HELD_T, L.HELD_TINPUT, L.HELD_UOK,
                    L.HELD_KIND, L.HELD_N)


@dataclass
class Memory:
    """What the block loop takes besides the observers' arrays."""
    cfg: np.ndarray          # the settings (loop.C_*), then the per-channel limits, x0
    rl: np.ndarray           # the layout of a row (loop.L_*)
    rs: np.ndarray           # (J, width) the runner state of each joint
    rc: np.ndarray           # (J, RC_SIZE) its counters
    rh: np.ndarray           # (J, 2 held_width) its held and pending inputs
    gate_args: tuple         # (p, threshold, minimum history): gate.summary's arguments
    r: int                   # unknown-input estimates per joint
    nconv: int               # convergence values per joint


def configure(settings: Mapping[str, Any], obs: KernelObserver, joints: int, nconv: int,
              old: Memory | None = None) -> Memory:
    """The memory of ``joints`` runners of ``obs``'s family under ``settings`` (``nconv``
    convergence values), carrying over what ``old`` counted, its input and a held sample."""
    s = settings
    n, p, m = obs.n_states, obs.n_outputs, obs.n_inputs
    r = int(obs._ic[obs._K.N_UI])
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
    rl[L.L_N], rl[L.L_P], rl[L.L_M], rl[L.L_R], rl[L.L_NCONV] = n, p, m, r, nconv
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
    rs, rc, rh = L.new_state(joints, rl, width, L.MAX_HELD_INPUTS * (1 + m))
    if old is not None:
        _carry_over(old, rs, rc, rh, rl)
    return Memory(np.concatenate(parts), rl, rs, rc, rh,
                  (p, s["outlier.threshold"], int(cfg[L.C_G_MINHIST])), r, nconv)


def _carry_over(old: Memory, rs, rc, rh, rl) -> None:
    """The counters of ``old``; its input and held sample when the input still fits (else
    forgotten: a new observer with other inputs)."""
    orl, m, p = old.rl, rl[L.L_M], rl[L.L_P]
    same_inputs = orl[L.L_M] == m
    for j in range(rs.shape[0]):
        o = old.rs[j]
        rs[j, list(_KEPT)] = o[list(_KEPT)]
        if same_inputs:
            rs[j, list(_KEPT_WITH_INPUT)] = o[list(_KEPT_WITH_INPUT)]
            for key, w in ((L.L_U, m), (L.L_HELD_Y, p), (L.L_HELD_U, m)):
                rs[j, rl[key]:rl[key] + w] = o[orl[key]:orl[key] + w]
    rc[:] = old.rc
    if same_inputs:
        rh[:] = old.rh


def events(count: int, joints: int, obs: KernelObserver, r: int, nconv: int):
    """Event buffers and output arrays for ``count`` events of every joint: (kind, t,
    values, intake codes, status, estimate, unknown input, convergence)."""
    v = max(obs.n_outputs, obs.n_inputs, 1)
    return (np.zeros(count, np.int8), np.zeros(count), np.zeros((count, joints, v)),
            np.zeros((count, joints), np.int16), np.zeros((count, joints), np.int16),
            np.zeros((count, joints, obs.n_states)), np.zeros((count, joints, r)),
            np.zeros((count, joints, nconv)))


def stack(observers: Sequence[KernelObserver], joints: Sequence[str]) -> list[np.ndarray]:
    """The observers' memories (state, candidate, constants, integer constants, work, clock)
    as rows of one array each; each observer keeps views of its rows.  ConfigError when a
    joint's observer has another structure than the first's."""
    progs = [o.program() for o in observers]
    first = progs[0]
    for j, prog in enumerate(progs[1:], 1):
        same = all(a.shape == b.shape for a, b in zip(prog[2:], first[2:])) and \
            np.array_equal(prog[5], first[5])
        if not same:
            raise ConfigError("joints", f"the observer of joint {joints[j]} has another "
                              f"structure than that of {joints[0]} (a per-joint constant "
                              "changed what the observer derives): give such joints a plant "
                              "and a node of their own")
    arrays = [np.ascontiguousarray(np.stack([p[k] for p in progs])) for k in range(2, 8)]
    for j, o in enumerate(observers):
        o.adopt(*(a[j] for a in arrays))
    return arrays
