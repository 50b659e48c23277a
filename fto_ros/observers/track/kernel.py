"""Per-sample kernel of the acquire-then-track composition (protocol and compositions:
observers/kernel.py; the rules: design.py).

Child 1 is the acquirer, child 2 the tracker (an EKF kernel: its st[HEALTH] is its NIS).
The kernel asks for the children's restarts and samples one call at a time and decides
between them: the hand-over, the NIS window test, the re-acquisition.  Every phase below
is a point where it resumes after a call (``RQ_PC``); one sample makes at most five calls.

State:   header | the published estimate (n) | mode, hand-overs and re-acquisitions since
         the restart (the extra convergence values), hand-overs and re-acquisitions over
         the observer's life, certificate run, window count, window head, window sum |
         acquirer state | acquirer clock | tracker state | tracker clock
Consts:  header | threshold, clip, certificate residual | acquirer c | tracker c
Ints:    header | n, scalars offset, window, certificate samples, ring offset, partials
         offset | child table | acquirer ic | tracker ic
Work:    request record (RQ_X0 + n) | window ring (window + 1: a new term goes into a free
         slot, so a rejected sample leaves the live terms as they were) | fsum partials
         (PARTIALS) | acquirer candidate, acquirer wk | tracker candidate, tracker wk
Models:  none of its own; the children's after the first MODEL_SLOTS
"""
from __future__ import annotations

import math

from ...core import jit as J
from ...core.jit import jit
from .. import kernel as K
from ..kernel import (C_HEADER, CALL, CALL_RESTART, CALL_UPDATE, CLK_K, CONVERGED,
                      GUARANTEED, HEADER, HEALTH, IC_HEADER, RESIDUAL, RQ_CHILD, RQ_HAS_X0,
                      RQ_OP, RQ_PC, RQ_RESULT, RQ_X0, STEP_QUANTUM)
from .design import ACQUIRING, REACQUIRING, TRACKING

T_N, T_SC, T_WINDOW, T_CERT, T_RING, T_PARTIALS = range(IC_HEADER, IC_HEADER + 6)
THRESHOLD, CLIP, CERT_RES = range(C_HEADER, C_HEADER + 3)
# the composition's scalars at st[ic[T_SC]:]
MODE, RUN_HANDOVERS, RUN_REACQ, HANDOVERS, REACQ, QUIET, WIN_COUNT, WIN_HEAD, WIN_SUM = range(9)
SCALARS = 9
ACQUIRER, TRACKER = 1, 2
#: fsum partials: at most ~40 non-overlapping doubles are ever needed
PARTIALS = 64
# where the kernel resumes
(RESTARTED_ACQ, RESTARTED_TRK, ACQ_TAKEN, HANDOVER_STARTED, HANDOVER_TAKEN,
 HANDOVER_UNDONE, TRK_TAKEN, REACQ_TAKEN, REACQ_UNDONE, REACQ_STARTED, REACQ_FIRST) = range(11)


# -- the children's values ---------------------------------------------------------------
@jit
def _row(ic, child):
    return ic[K.COMPOSED] + K.TAB_HEADER + (child - 1) * K.CHILD_WIDTH


@jit
def child_state(home, ic, child):
    """The child's state (a view into the composition's state or candidate)."""
    e = _row(ic, child)
    return home[ic[e + K.CH_ST]:ic[e + K.CH_ST] + ic[e + K.CH_ST_LEN]]


@jit
def _child_ic(ic, child):
    e = _row(ic, child)
    return ic[ic[e + K.CH_IC]:ic[e + K.CH_IC] + ic[e + K.CH_IC_LEN]]


@jit
def _estimate(home, ic, child):
    st = child_state(home, ic, child)
    ci = _child_ic(ic, child)
    return st[ci[K.EST]:ci[K.EST] + ci[K.N_STATES]]


@jit
def _call(wk, ic, pc, child, op, has_x0):
    """Ask for a call (observers/kernel.py); resume at pc."""
    rq = ic[ic[K.COMPOSED] + K.TAB_REQUEST]
    wk[rq + RQ_PC] = pc
    wk[rq + RQ_CHILD] = child
    wk[rq + RQ_OP] = op
    wk[rq + RQ_HAS_X0] = 1.0 if has_x0 else 0.0
    return CALL


# -- the NIS window ------------------------------------------------------------------------
@jit
def exact_sum(wk, ring, cap, head, count, partials):
    """The correctly rounded sum of the count terms before head in the ring (what
    math.fsum gives: Shewchuk's non-overlapping partials, rounded half-even at the end)."""
    n = 0
    for q in range(count):
        x = wk[ring + (head - count + q) % cap]
        i = 0
        for j in range(n):
            y = wk[partials + j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                wk[partials + i] = lo
                i += 1
            x = hi
        wk[partials + i] = x
        n = i + 1
    if n == 0:
        return 0.0
    n -= 1
    hi = wk[partials + n]
    lo = 0.0
    while n > 0:
        x = hi
        n -= 1
        y = wk[partials + n]
        hi = x + y
        yr = hi - x
        lo = y - yr
        if lo != 0.0:
            break
    if n > 0 and ((lo < 0.0 and wk[partials + n - 1] < 0.0) or
                  (lo > 0.0 and wk[partials + n - 1] > 0.0)):
        y = lo * 2.0
        x = hi + y
        yr = x - hi
        if y == yr:
            hi = x
    return hi


@jit
def window_add(home, c, ic, wk, nis):
    """Add the tracker's NIS (clipped) to the window; whether the window test fails."""
    s = ic[T_SC]
    w = ic[T_WINDOW]
    cap = w + 1
    clip = c[CLIP]
    v = (clip if clip < nis else nis) if math.isfinite(nis) else clip
    head = int(home[s + WIN_HEAD])
    wk[ic[T_RING] + head] = v
    head = (head + 1) % cap
    count = int(home[s + WIN_COUNT]) + 1
    total = home[s + WIN_SUM] + v
    if count > w:
        total -= wk[ic[T_RING] + (head - count) % cap]
        count = w
    elif count == w:
        total = exact_sum(wk, ic[T_RING], cap, head, count, ic[T_PARTIALS])
    home[s + WIN_HEAD] = head
    home[s + WIN_COUNT] = count
    home[s + WIN_SUM] = total
    return count == w and total > c[THRESHOLD]


@jit
def _clear_window(home, ic):
    s = ic[T_SC]
    home[s + WIN_COUNT] = 0.0
    home[s + WIN_SUM] = 0.0


# -- the published outputs ----------------------------------------------------------------
@jit
def _publish(home, c, ic):
    s = ic[T_SC]
    mode = home[s + MODE]
    src = ACQUIRER if mode == ACQUIRING else TRACKER
    n = ic[T_N]
    home[HEADER:HEADER + n] = _estimate(home, ic, src)
    home[RESIDUAL] = child_state(home, ic, src)[RESIDUAL]
    home[GUARANTEED] = child_state(home, ic, ACQUIRER)[GUARANTEED]
    tracking = mode == TRACKING
    home[CONVERGED] = 1.0 if tracking else 0.0
    home[HEALTH] = home[s + WIN_SUM] / c[THRESHOLD] \
        if tracking and home[s + WIN_COUNT] > 0.0 else 0.0
    return 0


# -- the rules ------------------------------------------------------------------------------
@jit
def _acquired(home, c, ic, wk):
    """Hand over when the acquirer's guarantee (or certificate) holds at this sample."""
    s = ic[T_SC]
    acq = child_state(home, ic, ACQUIRER)
    gt = acq[GUARANTEED]
    if math.isfinite(gt):
        e = _row(ic, ACQUIRER)
        since = home[ic[e + K.CH_CLK] + CLK_K] * STEP_QUANTUM
        ready = since >= gt - 1e-9
    else:
        res = acq[RESIDUAL]
        quiet = home[s + QUIET] + 1.0 if math.isfinite(res) and res <= c[CERT_RES] else 0.0
        home[s + QUIET] = quiet
        ready = quiet >= ic[T_CERT]
    if not ready:
        return _publish(home, c, ic)
    rq = ic[ic[K.COMPOSED] + K.TAB_REQUEST]
    n = ic[T_N]
    wk[rq + RQ_X0:rq + RQ_X0 + n] = _estimate(home, ic, ACQUIRER)
    return _call(wk, ic, HANDOVER_STARTED, TRACKER, CALL_RESTART, True)


@jit
def _resume(st, nx, c, ic, wk):
    rq = ic[ic[K.COMPOSED] + K.TAB_REQUEST]
    pc = int(wk[rq + RQ_PC])
    result = int(wk[rq + RQ_RESULT])
    s = ic[T_SC]
    if pc == RESTARTED_ACQ:
        return _call(wk, ic, RESTARTED_TRK, TRACKER, CALL_RESTART, False)
    if pc == RESTARTED_TRK:
        st[s + MODE] = ACQUIRING
        st[s + RUN_HANDOVERS] = 0.0
        st[s + RUN_REACQ] = 0.0
        st[s + QUIET] = 0.0
        _clear_window(st, ic)
        return _publish(st, c, ic)
    # a sample: everything in the candidate
    if pc == ACQ_TAKEN:
        if result != 0:
            return result
        return _acquired(nx, c, ic, wk)
    if pc == HANDOVER_STARTED:
        return _call(wk, ic, HANDOVER_TAKEN, TRACKER, CALL_UPDATE, False)
    if pc == HANDOVER_TAKEN:
        if result != 0:       # the tracker cannot start here: the acquirer goes on
            return _call(wk, ic, HANDOVER_UNDONE, TRACKER, CALL_RESTART, False)
        nx[s + HANDOVERS] += 1.0
        nx[s + RUN_HANDOVERS] += 1.0
        nx[s + MODE] = TRACKING
        _clear_window(nx, ic)
        return _publish(nx, c, ic)
    if pc == HANDOVER_UNDONE:
        nx[s + MODE] = ACQUIRING
        return _publish(nx, c, ic)
    if pc == TRK_TAKEN:
        if result != 0:
            return result
        if nx[s + MODE] == REACQUIRING:
            return _call(wk, ic, REACQ_TAKEN, ACQUIRER, CALL_UPDATE, False)
        if not window_add(nx, c, ic, wk, child_state(nx, ic, TRACKER)[HEALTH]):
            return _publish(nx, c, ic)
        nx[s + REACQ] += 1.0
        nx[s + RUN_REACQ] += 1.0
        nx[s + MODE] = REACQUIRING
        _clear_window(nx, ic)
        nx[s + QUIET] = 0.0
        return _call(wk, ic, REACQ_STARTED, ACQUIRER, CALL_RESTART, False)
    if pc == REACQ_TAKEN:
        if result != 0:       # acquire afresh from the next sample
            return _call(wk, ic, REACQ_UNDONE, ACQUIRER, CALL_RESTART, False)
        return _acquired(nx, c, ic, wk)
    if pc == REACQ_UNDONE:
        return _publish(nx, c, ic)
    if pc == REACQ_STARTED:
        return _call(wk, ic, REACQ_FIRST, ACQUIRER, CALL_UPDATE, False)
    if pc == REACQ_FIRST:
        if result != 0:
            return result
        return _publish(nx, c, ic)
    return K.BROKEN


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == K.RESUME:
        return _resume(st, nx, c, ic, wk)
    if op == J.RESTART:
        rq = ic[ic[K.COMPOSED] + K.TAB_REQUEST]
        n = ic[T_N]
        if a > 0.0:
            wk[rq + RQ_X0:rq + RQ_X0 + n] = y[:n]
        return _call(wk, ic, RESTARTED_ACQ, ACQUIRER, CALL_RESTART, a > 0.0)
    if op == J.FIRST or op == J.STEP:
        if nx[ic[T_SC] + MODE] == ACQUIRING:
            return _call(wk, ic, ACQ_TAKEN, ACQUIRER, CALL_UPDATE, False)
        return _call(wk, ic, TRK_TAKEN, TRACKER, CALL_UPDATE, False)
    return 0
