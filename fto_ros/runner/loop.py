"""The runner's per-sample work, compiled: value checks, the timeline, the outlier gate, the
observer's kernel, the output checks and the counters, for a whole block of samples in
one call, for every joint of the block.

``run_block`` takes events in time order (an input u, a measurement y, a measurement
PAIRED with the input just before it (a JointState carries both: skipped when that input
was refused, never paired with a bad u), or a sample the intake already refused, each for
every joint; a negative intake code skips the joint) and, per event and joint, writes a
status (OUTPUT, INPUT_TAKEN, HELD, SKIPPED or a rejection code) and, for an accepted
measurement, the estimate, the unknown-input estimate and the convergence values.  Joints are independent
runners that share the observer family and the settings: a joint's bad sample rejects or
restarts that joint only.  The same functions run one sample (the Python API of
runner/runner.py is a block of one), so a block and the same samples one by one give the
same outputs, rejections, restarts and counts by construction.

The runner's memory per joint is a float row ``rs`` (scalars below, then arrays at offsets
the layout ``rl`` gives: the current input, the held sample, the next start's estimate,
the gate's memory), counters ``rc`` (rejections and restarts by code, then the health
bucket) and ``rh``: the inputs kept while a sample is held, then the inputs a predicting
observer has still to be advanced to (MAX_HELD_INPUTS of each); ``cfg`` holds the settings.
The rules are the runner's (runner/runner.py's docstring; docs/architecture.md).
"""
from __future__ import annotations

import math

import numpy as np

from ..core import jit as J
from ..core.jit import jit
from ..core.reasons import CODE, REJECTIONS, RESTART_CODE, RESTARTS
from ..observers import kernel as K
from . import gate as G
from .timeline import CONFIRM, HOLD, REJECT, STEP, classify

# -- event kinds and statuses ---------------------------------------------------------
MEASUREMENT, INPUT, REFUSED, PAIRED = 0, 1, 2, 3
OUTPUT, INPUT_TAKEN, HELD, SKIPPED = 0, -2, -1, -3
#: a ROS builtin_interfaces/Time holds int32 seconds
MAX_STAMP = float(2 ** 31)
#: inputs kept while a sample is held (replayed when the next sample confirms the jump)
MAX_HELD_INPUTS = 10000

# -- rs: scalars --------------------------------------------------------------------
(T_LAST, T0, T_INPUT, U_OK, HELD_ON, HELD_T, HELD_TINPUT, HELD_UOK, HELD_KIND, HELD_N,
 START_FROM, ACCEPTED, REBASES, WIN_ACCEPTED, LAST_REJ, HAS_OUT, LAST_RES, LAST_CONV,
 LAST_SINCE, LAST_GT, PEND_N, COLD) = range(22)
RS_SCALARS = 24
# -- rl: the layout -----------------------------------------------------------------
(L_N, L_P, L_M, L_R, L_NCONV, L_U, L_HELD_Y, L_HELD_U, L_X0, L_GATE, L_E, L_CONFIRM,
 L_YLIM, L_ULIM, L_FLOOR, L_INIT) = range(16)
# -- cfg: settings ------------------------------------------------------------------
(C_TIMEOUT, C_MAX_GAP, C_RESET_ON_JUMP, C_JUMP, C_LIM_EST, C_RES_THR, C_G_THRESH, C_G_ALPHA,
 C_G_MINHIST, C_G_MAXCONS, C_HAS_INIT) = range(11)
CFG_SCALARS = 12
# -- rc: counters ---------------------------------------------------------------------
NREJ = len(REJECTIONS)
NRST = len(RESTARTS)
HW = NREJ + NRST                         # the health window's current bucket
HW_ACCEPTED, HW_REJECTED, HW_REBASE = HW, HW + 1, HW + 2
HW_RESTARTS = HW + 3                     # + restart code
RC_SIZE = HW_RESTARTS + NRST

_SET_STATE = RESTART_CODE["set_state"]
_OBSERVER_ERROR = RESTART_CODE["observer_error"]
_NON_FINITE_STATE = RESTART_CODE["non_finite_state"]
_ESTIMATE_IMPLAUSIBLE = RESTART_CODE["estimate_implausible"]
#: restarts after which nothing of the old estimate is kept (a family that keeps its
#: estimate over a restart, prescribed_time, starts cold)
_FAULTS = (_OBSERVER_ERROR, _NON_FINITE_STATE, _ESTIMATE_IMPLAUSIBLE)
_R_NON_FINITE = CODE["non_finite_estimate"]
_R_IMPLAUSIBLE = CODE["estimate_implausible"]
_R_M_NON_FINITE = CODE["measurement_non_finite"]
_R_M_IMPLAUSIBLE = CODE["measurement_implausible"]
_R_BAD_STAMP = CODE["bad_stamp"]
_R_I_NON_FINITE = CODE["input_non_finite"]
_R_I_IMPLAUSIBLE = CODE["input_implausible"]
_R_I_BAD_STAMP = CODE["input_bad_stamp"]
_R_UNCONFIRMED = CODE["stamp_jump_unconfirmed"]
_R_MISSING = CODE["missing_input"]
_R_STALE = CODE["stale_input"]
_R_OUTLIER = CODE["outlier"]
_NAN = math.nan


# -- counting -----------------------------------------------------------------------------
@jit
def reject(rs, rc, code):
    """Count a refused sample."""
    rc[code] += 1
    rc[HW_REJECTED] += 1
    rs[LAST_REJ] = code


@jit
def reset(rs, rc, rl, reason, requested):
    """Restart the observer at the next sample, counted under restart code ``reason``; a
    restart a person asked for (``requested``) leaves the health bucket alone (the caller
    clears the window), the others count in it."""
    rc[NREJ + reason] += 1
    rs[T0] = _NAN
    rs[T_LAST] = _NAN
    p = rl[L_P]
    G.clear(rs[rl[L_GATE]:], p, rl[L_CONFIRM])
    if reason != _SET_STATE:
        rs[START_FROM] = 0.0
    rs[PEND_N] = 0.0
    if reason in _FAULTS:        # the estimate is not to be trusted: the next start is cold
        rs[COLD] = 1.0
    if not requested:
        rc[HW_RESTARTS + reason] += 1


@jit
def _fail(rs, rc, rl, restart, rejection):
    reset(rs, rc, rl, restart, False)
    reject(rs, rc, rejection)
    return rejection


# -- the state name the gate and /diagnostics use --------------------------------------
@jit
def converged_state(rs, cfg):
    """Whether the runner's state is 'converged' (the gate acts only then)."""
    if rs[HAS_OUT] == 0.0 or rs[T0] != rs[T0]:
        return False
    if rs[LAST_CONV] == 0.0:
        return False
    return not rs[LAST_RES] > cfg[C_RES_THR]


# -- one sample ----------------------------------------------------------------------------
@jit
def _finite(v):
    acc = 0.0
    for i in range(v.shape[0]):
        acc += v[i] * 0.0
    return acc == 0.0


@jit
def _output(rs, rl, cfg, st, ic, t, ox, oui, oconv):
    """Write the output of the sample just taken; 0, or the (restart, rejection) pair coded
    as restart * 1000 + rejection when the estimate is not finite or beyond the limit."""
    n = ic[K.N_STATES]
    x = st[ic[K.EST]:ic[K.EST] + n]
    r = ic[K.N_UI]
    ui = st[ic[K.UI]:ic[K.UI] + r]
    if not (_finite(x) and _finite(ui)):
        return _NON_FINITE_STATE * 1000 + _R_NON_FINITE
    big = 0.0
    for i in range(n):
        big = max(big, abs(x[i]))
    for i in range(r):
        big = max(big, abs(ui[i]))
    if big > cfg[C_LIM_EST]:
        return _ESTIMATE_IMPLAUSIBLE * 1000 + _R_IMPLAUSIBLE
    since = t - rs[T0]
    gt = st[K.GUARANTEED]
    res = st[K.RESIDUAL]
    obs_conv = st[K.CONVERGED]
    if obs_conv >= 0.0:
        conv = obs_conv > 0.0
    elif gt < math.inf:
        conv = since >= gt - 1e-9
    else:
        conv = res == res and abs(res) < math.inf and res <= cfg[C_RES_THR]
    health = st[K.HEALTH]
    ox[:n] = x
    oui[:r] = ui
    oconv[0] = since
    oconv[1] = res if (res == res and abs(res) < math.inf) else -1.0
    oconv[2] = 1.0 if conv else 0.0
    oconv[3] = gt
    oconv[4] = health if (health == health and abs(health) < math.inf) else 0.0
    ne = ic[K.N_EXTRA]
    oconv[5:5 + ne] = st[ic[K.EXTRA]:ic[K.EXTRA] + ne]
    rs[HAS_OUT] = 1.0
    rs[LAST_RES] = oconv[1]
    rs[LAST_CONV] = oconv[2]
    rs[LAST_SINCE] = since
    rs[LAST_GT] = gt
    return 0


@jit
def _sample(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t, y, ox, oui, oconv):
    """Hand a classified sample to the observer: OUTPUT (written) or a rejection code."""
    m = rl[L_M]
    if rs[U_OK] == 0.0:
        reject(rs, rc, _R_MISSING)
        return _R_MISSING
    if m > 0 and rs[T_INPUT] == rs[T_INPUT] and t - rs[T_INPUT] > cfg[C_TIMEOUT]:
        reject(rs, rc, _R_STALE)
        return _R_STALE
    first = rs[T0] != rs[T0]
    if first:
        n = rl[L_N]
        cold = rs[COLD] > 0.0
        rs[COLD] = 0.0
        if rs[START_FROM] > 0.0:
            K.restart(kernels, models, st, nx, c, ic, wk, clk, rs[rl[L_X0]:rl[L_X0] + n], True,
                      cold)
        elif cfg[C_HAS_INIT] > 0.0:
            K.restart(kernels, models, st, nx, c, ic, wk, clk, cfg[rl[L_INIT]:rl[L_INIT] + n], True,
                      cold)
        else:
            K.restart(kernels, models, st, nx, c, ic, wk, clk, cfg[0:0], False, cold)
    elif rs[PEND_N] > 0.0:
        _advance_to(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t)
    u = rs[rl[L_U]:rl[L_U] + m]
    code = K.update(kernels, models, st, nx, c, ic, wk, clk, t, y, u)
    if code != 0:
        reject(rs, rc, code)
        return code
    if first:
        rs[T0] = t
    rs[T_LAST] = t
    problem = _output(rs, rl, cfg, st, ic, t, ox, oui, oconv)
    if problem != 0:
        return _fail(rs, rc, rl, problem // 1000, problem % 1000)
    p = rl[L_P]
    G.accepted(rs[rl[L_GATE]:], p, cfg[C_G_ALPHA], t, y, rs[rl[L_E]:rl[L_E] + p])
    rs[ACCEPTED] += 1.0
    rs[WIN_ACCEPTED] += 1.0
    rc[HW_ACCEPTED] += 1
    return OUTPUT


@jit
def step_limit(c, cfg):
    return min(cfg[C_MAX_GAP], c[K.MAX_STEP])


@jit
def set_input(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t, u):
    """Store the known input u valid from t on (checked); INPUT_TAKEN or a rejection code.
    While a sample is held the input is kept too; observers that predict between sparse
    samples integrate up to it (within a step they can bridge)."""
    m = rl[L_M]
    if not _finite(u):
        reject(rs, rc, _R_I_NON_FINITE)
        return _R_I_NON_FINITE
    if G.exceeds(u, cfg[rl[L_ULIM]:rl[L_ULIM] + m]):
        reject(rs, rc, _R_I_IMPLAUSIBLE)
        return _R_I_IMPLAUSIBLE
    if not (0.0 <= t < MAX_STAMP):
        reject(rs, rc, _R_I_BAD_STAMP)
        return _R_I_BAD_STAMP
    if m == 0:               # nothing to hold: an empty input cannot go stale
        return INPUT_TAKEN
    rs[rl[L_U]:rl[L_U] + m] = u
    rs[T_INPUT] = t
    rs[U_OK] = 1.0
    if rs[HELD_ON] > 0.0 and rs[HELD_N] < MAX_HELD_INPUTS:
        i = int(rs[HELD_N])
        rh[i * (1 + m)] = t
        rh[i * (1 + m) + 1:(i + 1) * (1 + m)] = u
        rs[HELD_N] += 1.0
    # a predicting observer integrates up to each input instant, so a fast input is applied
    # when it changes; that happens when a measurement reaches the input's stamp
    # (_advance_to), so an input stamped ahead cannot move the prediction past measurements
    # still to come
    if ic[K.HAS_ADVANCE] != 0 and rs[T0] == rs[T0]:
        w = 1 + m
        base = MAX_HELD_INPUTS * w
        n = int(rs[PEND_N])
        if n == MAX_HELD_INPUTS:                 # full: the oldest goes
            rh[base:base + (n - 1) * w] = rh[base + w:base + n * w].copy()
            n -= 1
        rh[base + n * w] = t
        rh[base + n * w + 1:base + (n + 1) * w] = u
        rs[PEND_N] = n + 1
    return INPUT_TAKEN


@jit
def _advance_to(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t):
    """Apply the pending inputs stamped up to t, in stamp order, to a predicting observer,
    each only within a step it can bridge from the last measurement (a longer silence is a
    gap: restart later).  A refused one is counted, as set_input does."""
    m = rl[L_M]
    w = 1 + m
    base = MAX_HELD_INPUTS * w
    n = int(rs[PEND_N])
    pend = rh[base:base + n * w].reshape(n, w)
    due = np.empty(n, np.int64)
    keep = np.empty(n, np.int64)
    nd = 0
    nk = 0
    for i in range(n):
        if pend[i, 0] <= t:
            due[nd] = i
            nd += 1
        else:
            keep[nk] = i
            nk += 1
    order = due[:nd][np.argsort(pend[due[:nd], 0], kind="mergesort")]
    chosen = pend[order].copy()
    rest = pend[keep[:nk]].copy()
    rh[base:base + nk * w] = rest.ravel()
    rs[PEND_N] = nk
    limit = step_limit(c, cfg)
    for i in range(nd):
        t_in = chosen[i, 0]
        if 0.0 <= t_in - rs[T_LAST] <= limit:
            code = K.advance(kernels, models, st, nx, c, ic, wk, clk, t_in, chosen[i, 1:].copy(),
                             cfg[0:0])
            if code != 0:
                reject(rs, rc, code)


@jit
def process(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t, y, ox, oui, oconv):
    """The measurement y taken at t: OUTPUT (written to ox, oui, oconv), HELD (held at a
    time discontinuity until the next sample confirms it) or a rejection code."""
    p = rl[L_P]
    m = rl[L_M]
    if not _finite(y):
        reject(rs, rc, _R_M_NON_FINITE)
        return _R_M_NON_FINITE
    if G.exceeds(y, cfg[rl[L_YLIM]:rl[L_YLIM] + p]):
        reject(rs, rc, _R_M_IMPLAUSIBLE)
        return _R_M_IMPLAUSIBLE
    if not (0.0 <= t < MAX_STAMP):
        reject(rs, rc, _R_BAD_STAMP)
        return _R_BAD_STAMP
    held = rs[HELD_ON] > 0.0
    verdict, detail = classify(t, rs[T_LAST], held, rs[HELD_T], int(rs[HELD_KIND]),
                               step_limit(c, cfg), cfg[C_JUMP], cfg[C_RESET_ON_JUMP] > 0.0)
    if verdict == REJECT:
        reject(rs, rc, detail)
        return detail
    if verdict == HOLD:
        if held:
            reject(rs, rc, _R_UNCONFIRMED)
        rs[HELD_ON] = 1.0
        rs[HELD_T] = t
        rs[rl[L_HELD_Y]:rl[L_HELD_Y] + p] = y
        rs[rl[L_HELD_U]:rl[L_HELD_U] + m] = rs[rl[L_U]:rl[L_U] + m]
        rs[HELD_UOK] = rs[U_OK]
        rs[HELD_TINPUT] = rs[T_INPUT]
        rs[HELD_KIND] = detail
        rs[HELD_N] = 0.0
        return HELD
    if verdict == CONFIRM:
        rs[HELD_ON] = 0.0
        reset(rs, rc, rl, detail, False)
        # the held sample starts the new run with the input that was current then, unless
        # that input was stamped after it (the old timeline's, before a jump back); the
        # inputs that came while it was held follow, as they would have
        t_held = rs[HELD_T]
        fresh = rs[HELD_TINPUT] == rs[HELD_TINPUT] and rs[HELD_TINPUT] <= t_held
        if fresh:
            rs[rl[L_U]:rl[L_U] + m] = rs[rl[L_HELD_U]:rl[L_HELD_U] + m]
            rs[T_INPUT] = rs[HELD_TINPUT]
            rs[U_OK] = rs[HELD_UOK]
        else:
            rs[T_INPUT] = _NAN
            rs[U_OK] = 1.0 if m == 0 else 0.0
        yh = rs[rl[L_HELD_Y]:rl[L_HELD_Y] + p].copy()
        _sample(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t_held, yh, ox, oui,
                oconv)
        nh = int(rs[HELD_N])
        rs[HELD_N] = 0.0
        for i in range(nh):
            t_in = rh[i * (1 + m)]
            if t_held <= t_in <= t:
                set_input(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t_in,
                          rh[i * (1 + m) + 1:(i + 1) * (1 + m)].copy())
    elif held:                                 # the old timeline goes on: it was junk
        rs[HELD_ON] = 0.0
        reject(rs, rc, _R_UNCONFIRMED)
    if verdict == STEP:
        outcome = G.check(rs[rl[L_GATE]:], p, rl[L_CONFIRM], cfg[C_G_THRESH], cfg[C_G_MINHIST],
                          cfg[C_G_MAXCONS], cfg[rl[L_FLOOR]:rl[L_FLOOR] + p], t, y,
                          converged_state(rs, cfg), rs[rl[L_E]:rl[L_E] + p])
        if outcome == G.OUTLIER:
            reject(rs, rc, _R_OUTLIER)
            return _R_OUTLIER
        if outcome == G.REBASE:
            rs[REBASES] += 1.0
            rc[HW_REBASE] += 1
    return _sample(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg, t, y, ox, oui,
                   oconv)


# -- a block ---------------------------------------------------------------------------------
def _run_block(kernels, models, st, nx, c, ic, wk, clk, rs, rl, rc, rh, cfg,
               ev_kind, ev_t, ev_v, ev_pre, o_status, o_x, o_ui, o_conv):
    """Every event (k) for every joint (j), in order; see the module docstring.  ``models``
    holds every joint's model terms; the arrays have a row per joint."""
    joints = st.shape[0]
    p = rl[L_P]
    m = rl[L_M]
    input_refused = np.zeros(joints, np.bool_)
    for k in range(ev_t.shape[0]):
        kind = ev_kind[k]
        t = ev_t[k]
        for j in range(joints):
            pre = ev_pre[k, j]
            if pre < 0 or (kind == PAIRED and input_refused[j]):
                o_status[k, j] = SKIPPED         # not this joint's event / its input failed
            elif kind == REFUSED or pre != 0:
                reject(rs[j], rc[j], pre)
                o_status[k, j] = pre
            elif kind == INPUT:
                o_status[k, j] = set_input(kernels, models[j], st[j], nx[j], c[j], ic[j], wk[j],
                                           clk[j], rs[j], rl, rc[j], rh[j], cfg, t,
                                           ev_v[k, j, :m])
                input_refused[j] = o_status[k, j] > 0
            else:
                o_status[k, j] = process(kernels, models[j], st[j], nx[j], c[j], ic[j], wk[j],
                                         clk[j], rs[j], rl, rc[j], rh[j], cfg, t,
                                         ev_v[k, j, :p], o_x[k, j], o_ui[k, j], o_conv[k, j])
    return 0


def _set_state(rs, rc, rl, x):
    """Restart from x at the next sample (counted as set_state; a requested restart)."""
    n = rl[L_N]
    rs[rl[L_X0]:rl[L_X0] + n] = x
    rs[START_FROM] = 1.0
    reset(rs, rc, rl, _SET_STATE, True)


def _time_jump(rs, rc, rl, t, reason):
    """Time went back to t (told by the node's clock): restart at once, and forget an
    input stamped after t (the old timeline's)."""
    rs[HELD_ON] = 0.0
    reset(rs, rc, rl, reason, False)
    if rs[T_INPUT] == rs[T_INPUT] and rs[T_INPUT] > t:
        rs[T_INPUT] = _NAN
        rs[U_OK] = 1.0 if rl[L_M] == 0 else 0.0


# compiled at their first call (after the parameters were validated: a refused
# configuration never waits for a compiler), cached on disk
run_block, set_state, time_jump = jit(_run_block), jit(_set_state), jit(_time_jump)


def new_state(joints: int, rl: np.ndarray, width: int, held_width: int):
    """(rs, rc, rh) of ``joints`` runners that have seen nothing yet."""
    rs = np.zeros((joints, width))
    rs[:, [T_LAST, T0, T_INPUT, HELD_T, HELD_TINPUT, LAST_RES]] = _NAN
    rs[:, U_OK] = 1.0 if rl[L_M] == 0 else 0.0
    rc = np.zeros((joints, RC_SIZE), dtype=np.int64)
    rh = np.zeros((joints, 2 * held_width))
    return rs, rc, rh
