"""The interface between the replay and the runner: blocks of samples in, blocks of
outputs out, one compiled call (``Runner.process_block``) per window.

:func:`plan_rows` turns the bag's events (replay/events.py) into the runner's event rows
once, as the live node hands them over: each of the source's topics is decoded in one
batch by the source (runner/sources/: its rows per message, the intake's refusals as
codes) and the rows are put in event order.  An intake reason without a code (a caller's
own) is counted by ``Runner.reject`` between two compiled calls, in order.
:func:`run_window` runs the rows of a window of events and returns an
:class:`OutputBlock`: one row per sample with an output (its time, estimate,
unknown-input estimate and convergence values, per joint) and a status per sample and
joint.  The same calls as the node's message by message (runner/loop.py runs a block of
one for those), so the same outputs, rejections, restarts and counters.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..core.reasons import REJECTIONS
from ..runner import loop as L
from ..runner.sources.base import PYTHON, Rows as SourceRows
from . import events as E

#: per-sample status codes (per joint)
ACCEPTED, IS_HELD, REJECTED, NO_SAMPLE = 0, 1, 2, 3


@dataclass
class Rows(SourceRows):
    """The runner's event rows of a whole replay (see the module doc): a source's Rows of
    E events (each a message of one of the source's topics, in time order), whose
    ``py_reasons`` is the list of the reasons of the rows ``py_rows`` (sorted) of kind
    PYTHON."""

    py_rows: np.ndarray = None


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


def plan_rows(source, ev: E.Events, streams) -> Rows:
    """The runner's rows of every event of ``ev`` (see the module doc)."""
    J, width = source.runner.n_joints, source.width
    count = np.zeros(ev.t.size, np.int64)
    batches = []
    for topic in source.topics:
        t, payloads = streams.raw[topic.key]
        sel = np.flatnonzero(ev.kind == ev.roles.index(topic.key))
        if not sel.size:
            continue
        rows = source.rows(topic.key, payloads, t, t, t * 1e-9)
        m = ev.idx[sel]
        count[sel] = np.diff(rows.first)[m]
        batches.append((sel, m, rows))
    first = np.zeros(ev.t.size + 1, np.int64)
    np.cumsum(count, out=first[1:])
    R = int(first[-1])
    stamps = ev.t.astype(np.int64)
    out = Rows(np.zeros(R, np.int8), np.zeros(R), np.zeros((R, J, width)),
               np.zeros((R, J), np.int16), first, np.full(ev.t.size, -1, np.int64),
               np.full(ev.t.size, -1, np.int64), stamps.copy(), stamps,
               np.zeros(ev.t.size, bool), [], np.zeros(0, np.int64))
    py = {}
    for sel, m, rows in batches:
        src, dst, n = rows.first[m], first[sel], count[sel]
        for k in range(int(n.max())):
            have = n > k
            a, b = src[have] + k, dst[have] + k
            out.kind[b], out.t[b] = rows.kind[a], rows.t[a]
            out.values[b], out.pre[b] = rows.values[a], rows.pre[a]
        shift = dst - src
        out.srow[sel] = np.where(rows.srow[m] >= 0, rows.srow[m] + shift, -1)
        out.irow[sel] = np.where(rows.irow[m] >= 0, rows.irow[m] + shift, -1)
        out.stamp_ns[sel] = rows.stamp_ns[m]
        if rows.py_reasons:
            msg_of = np.searchsorted(rows.first, list(rows.py_reasons), "right") - 1
            where = dict(zip(m.tolist(), (dst - src).tolist()))
            for r, mm in zip(rows.py_reasons, msg_of.tolist()):
                py[r + where[mm]] = rows.py_reasons[r]
    out.py_rows = np.asarray(sorted(py), np.int64)
    out.py_reasons = [py[r] for r in sorted(py)]
    return out


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
