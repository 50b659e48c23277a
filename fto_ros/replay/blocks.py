"""The interface between the replay and the runner: blocks of samples in, blocks of
outputs out, one compiled call (``Runner.process_block``) per window.

:func:`plan_rows` turns the bag's events (replay/events.py) into the runner's event rows
once, as the live node would hand them over: a measurement is a MEASUREMENT row, an input
an INPUT row, a JointState (its sample time: the header stamp) an INPUT row then a PAIRED
row (the measurement, skipped when that input was refused) or one MEASUREMENT row without
inputs; a sample the intake refuses (a Float64MultiArray of the wrong length, a JointState
without a configured joint, a future stamp) is a REFUSED row with its rejection code.  An
intake reason without a code (a caller's own) is counted by ``Runner.reject`` between two
compiled calls, in order.  :func:`run_window` runs the rows of a window of events and
returns an :class:`OutputBlock`: one row per sample with an output (its time, estimate,
unknown-input estimate and convergence values, per joint) and a status per sample and
joint.  The same calls as the events one by one through ``set_input`` / ``process``
(runner/loop.py runs a block of one for those), so the same outputs, rejections, restarts
and counters.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..core.reasons import CODE, REJECTIONS
from ..runner import loop as L
from ..runner.intake import JointIntake, joint_sample
from ..runner.messages import joint_state_sample
from . import events as E

#: per-sample status codes (per joint)
ACCEPTED, IS_HELD, REJECTED, NO_SAMPLE = 0, 1, 2, 3
#: a row counted in Python (an intake reason without a code): not handed to the runner
PYTHON = 99


@dataclass
class Rows:
    """The runner's event rows of a whole replay (see the module doc)."""

    kind: np.ndarray          # (R,) int8: loop.MEASUREMENT, INPUT, PAIRED, REFUSED or PYTHON
    t: np.ndarray             # (R,) s
    values: np.ndarray        # (R, J, width)
    pre: np.ndarray           # (R, J) int16: the intake's code (0: none, -1: not this joint's)
    first: np.ndarray         # (E + 1,): the rows of event e are first[e]:first[e + 1]
    srow: np.ndarray          # (E,): the row whose status is the sample's (-1: not a sample)
    irow: np.ndarray          # (E,): the input row a sample is paired with (-1: none)
    stamp_ns: np.ndarray      # (E,) int64: a sample's time (log time, or a JointState's stamp)
    py_rows: np.ndarray       # sorted rows of kind PYTHON
    py_reasons: list          # their reasons


@dataclass
class OutputBlock:
    """What the runner produced for one window: k samples with an output, e samples in all,
    J joints (1 without ``joints``)."""

    t_ns: np.ndarray          # (k,) int64: sample times
    x: np.ndarray             # (k, J, n): estimates
    w: np.ndarray             # (k, J, r): unknown-input estimates (NaN: none)
    c: np.ndarray             # (k, J, ncf): convergence values (guaranteed_time inf: none)
    ok: np.ndarray            # (k, J) bool: the joint has an output in this row
    status: np.ndarray        # (e, J) int8: ACCEPTED, IS_HELD, REJECTED or NO_SAMPLE
    reasons: list             # the rejection reason of each REJECTED (sample, joint), in order
    runner_s: float           # wall time of the window's runner calls


def _float_rows(values, width: int, code: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows (N, width) zero-padded, intake codes (N,)) of a Float64MultiArray stream: a
    message of another length is refused with ``code`` (check_vector's ``_wrong_length``;
    its values never reach an observer)."""
    if isinstance(values, np.ndarray) and values.ndim == 2:
        n = values.shape[0]
        out = np.zeros((n, max(width, 1)))
        if values.shape[1] == width:
            out[:, :width] = values
            return out, np.zeros(n, np.int16)
        return out, np.full(n, code, np.int16)
    out = np.zeros((len(values), max(width, 1)))
    pre = np.zeros(len(values), np.int16)
    for i, v in enumerate(values):
        if len(v) == width:
            out[i, :width] = v
        else:
            pre[i] = code
    return out, pre


def _joint_rows(runner, msgs, log_t_ns, width: int):
    """Per JointState: (t s, stamp ns, y (J, w), u (J, w) or None, pre (J,), reason or None)."""
    settings = runner.settings
    m = runner.observer.n_inputs
    out = []
    if runner.joints:
        intake = JointIntake(runner.joints, settings["joint_states.output_fields"],
                             settings["joint_states.input_fields"], m)
        for msg, t_log in zip(msgs, log_t_ns.tolist()):
            out.append(joint_sample(intake, msg, settings, t_log * 1e-9, width))
        return out
    J = 1
    for msg, t_log in zip(msgs, log_t_ns.tolist()):
        st = msg.header.stamp
        s_ns = st.sec * 1_000_000_000 + st.nanosec
        sample = joint_state_sample(msg, settings, t_log * 1e-9, runner.intake)
        if sample.__class__ is str:
            out.append((0.0, s_ns, None, None, None, sample))
            continue
        t, y, u = sample
        yv = np.zeros((J, width))
        yv[0, :len(y)] = y
        uv = None
        if u is not None:
            uv = np.zeros((J, width))
            uv[0, :len(u)] = u
        out.append((t, s_ns, yv, uv, np.zeros(J, np.int16), None))
    return out


def plan_rows(runner, ev: E.Events, streams) -> Rows:
    """The runner's rows of every event of ``ev`` (see the module doc)."""
    obs = runner.observer
    J = runner.n_joints
    p, m = obs.n_outputs, obs.n_inputs
    width = max(p, m, 1)
    count = np.zeros(ev.t.size, np.int64)
    is_meas, is_in, is_js = ev.kind == E.MEAS, ev.kind == E.INPUT, ev.kind == E.JOINT
    count[is_meas | is_in] = 1
    joints = _joint_rows(runner, streams.joints[1], streams.joints[0], width) \
        if is_js.any() else []
    js_rows = np.array([2 if (j[3] is not None and j[5] is None) else 1 for j in joints],
                       np.int64)
    if joints:
        count[is_js] = js_rows[ev.idx[is_js]]
    first = np.zeros(ev.t.size + 1, np.int64)
    np.cumsum(count, out=first[1:])
    R = int(first[-1])
    kind = np.zeros(R, np.int8)
    t = np.zeros(R)
    values = np.zeros((R, J, width))
    pre = np.zeros((R, J), np.int16)
    srow = np.full(ev.t.size, -1, np.int64)
    irow = np.full(ev.t.size, -1, np.int64)
    stamp = ev.t.astype(np.int64).copy()
    t_s = ev.t / 1e9
    for which, stream, code, k in ((is_meas, streams.meas[1], CODE["measurement_wrong_length"],
                                    L.MEASUREMENT),
                                   (is_in, streams.inputs[1], CODE["input_wrong_length"], L.INPUT)):
        if not which.any():
            continue
        rows, codes = _float_rows(stream, p if k == L.MEASUREMENT else m, code)
        at = first[:-1][which]
        i = ev.idx[which]
        kind[at] = np.where(codes[i] != 0, L.REFUSED, k)
        t[at] = t_s[which]
        values[at, :, :rows.shape[1]] = rows[i][:, None, :]
        pre[at] = codes[i][:, None]
        if k == L.MEASUREMENT:
            srow[which] = at
    py_rows, py_reasons = [], []
    for e in np.flatnonzero(is_js).tolist():
        ts, s_ns, y, u, refused, why = joints[ev.idx[e]]
        r = int(first[e])
        stamp[e] = s_ns
        srow[e] = r + int(count[e]) - 1
        if why is not None:
            if why in CODE:
                kind[r], pre[r] = L.REFUSED, CODE[why]
            else:
                kind[r] = PYTHON
                py_rows.append(r)
                py_reasons.append(why)
            continue
        t[r:r + int(count[e])] = ts
        if u is not None:
            kind[r] = L.INPUT
            values[r] = u
            pre[r] = np.where(refused != 0, -1, 0)
            irow[e] = r
            r += 1
        kind[r] = L.PAIRED if u is not None else L.MEASUREMENT
        values[r] = y
        pre[r] = refused
    return Rows(kind, t, values, pre, first, srow, irow, stamp,
                np.asarray(py_rows, np.int64), py_reasons)


def run_window(runner, rows: Rows, start: int, stop: int) -> OutputBlock:
    """The OutputBlock of the events ``[start, stop)``: their rows through
    ``runner.process_block``, split where an intake reason is counted in Python."""
    r0, r1 = int(rows.first[start]), int(rows.first[stop])
    obs = runner.observer
    J, n, ncf = runner.n_joints, obs.n_states, len(runner.convergence_fields)
    r = ui_width(runner)
    status = np.zeros((r1 - r0, J), np.int16)
    x = np.zeros((r1 - r0, J, n))
    w = np.full((r1 - r0, J, r), np.nan)
    c = np.zeros((r1 - r0, J, ncf))
    lo, hi = np.searchsorted(rows.py_rows, [r0, r1])
    cuts = rows.py_rows[lo:hi].tolist()
    a = r0
    c0 = time.perf_counter()
    for b in cuts + [r1]:
        if b > a:
            blk = runner.process_block(rows.kind[a:b], rows.t[a:b], rows.values[a:b],
                                       rows.pre[a:b])
            status[a - r0:b - r0] = blk.status
            x[a - r0:b - r0] = blk.estimate
            c[a - r0:b - r0] = blk.convergence
            if r:
                w[a - r0:b - r0] = blk.unknown_input[:, :, :r]
        if b < r1:
            runner.reject(rows.py_reasons[lo + cuts.index(b)])
            status[b - r0] = PYTHON
        a = b + 1
    runner_s = time.perf_counter() - c0
    return _outputs(rows, start, stop, r0, status, x, w, c, runner_s)


def ui_width(runner) -> int:
    obs = runner.observer
    if not obs.has_unknown_input:
        return 0
    return len(getattr(obs, "unknown_input_names", None) or range(obs.n_outputs))


def _outputs(rows: Rows, start: int, stop: int, r0: int, status, x, w, c,
             runner_s: float) -> OutputBlock:
    """Per sample of the window: its status per joint; the rows with an output."""
    sr = rows.srow[start:stop]
    samples = np.flatnonzero(sr >= 0)
    srow = sr[samples] - r0
    st = status[srow].astype(np.int32)
    ir = rows.irow[start:stop][samples]
    paired = ir >= 0
    if paired.any():                       # a skipped measurement: its input's verdict
        st_in = status[ir[paired] - r0]
        sub = st[paired]
        skip = sub == L.SKIPPED
        sub[skip] = st_in[skip]
        st[paired] = sub
    out = np.full(st.shape, NO_SAMPLE, np.int8)
    out[st == L.OUTPUT] = ACCEPTED
    out[st == L.HELD] = IS_HELD
    bad = (st > 0)
    out[bad] = REJECTED
    reasons = []
    if bad.any():
        py = {int(rr): why for rr, why in zip(rows.py_rows.tolist(), rows.py_reasons)}
        for e, j in zip(*np.nonzero(bad)):
            code = int(st[e, j])
            reasons.append(py[int(srow[e]) + r0] if code == PYTHON else REJECTIONS[code])
    ok = out == ACCEPTED
    have = ok.any(axis=1)
    keep = srow[have]
    return OutputBlock(
        t_ns=rows.stamp_ns[start:stop][samples][have], x=x[keep], w=w[keep], c=c[keep],
        ok=ok[have], status=out, reasons=reasons, runner_s=runner_s)
