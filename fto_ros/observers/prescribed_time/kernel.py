"""Per-sample kernel of the prescribed-time observer (protocol: observers/kernel.py; the
method: the adapter's module docstring; the window mechanics: windows.py; where everything
lives in the flat arrays: layout.py).

One step from the last sample (model quanta kp) to the sample at k: the plant model's
exact FOH step ``[Phi | G0 | G1] [x; w0; w1]`` (core/exact_step.py's cached matrix,
w = (u, F(y, u), r)), r(t_k+1) from the one scalar equation y = x_model,1, then the
correction ``e^(A h) q - Phi_err(t_k+1, t_k) q`` with Phi_err from Lemma 1 (``transition``:
the scaled product with the cached E_bar(h) = e^(H Lambda H^-1 h)) across window ends
(``propagate``: restart, stop or constant per mode), the sampling guard, and the commit
(gains, health, the published estimate S x).

State:   header | scalars (below) | x published = S x (n) | x canonical (n) |
         F(y, u) of the last sample (n) | the frozen gains (n)
Consts:  header | T, s_end, beta_guard, n + m | gain coefficients Hg (n x (n + 1)) |
         C (n x n) | C^-1 (n x n) | l (n) | g_end (n) | A_p (n x n) | B (n x W) | S (n x n) |
         the exponents 0..n (n + 1);
         W = n_inputs (+ n with F) + 1 columns of the model's input w = (u, F(y, u), r)
Ints:    header | n, n_inputs, has F, mode, has g_end, has S, reset keeps the estimate,
         foh, W, the three caches' bases, scratch base, cache slots, the offsets in c of
         Hg, C, C^-1, l, g_end, A_p, B, S, the exponents
Work:    [next frozen-gains id, the id the after-window cache holds], the caches (model
         step [Phi | G0 | G1] per step, E_bar per step, the after-window matrix per step;
         256 entries each, first in first out, keyed by integer ns), then scratch
Models:  [F(y, u)] (n terms; slot unused without F)

The after-window matrices depend on the frozen gains: every new set of frozen gains gets
a new id from a counter in the work memory (never reused), and the cache is emptied when
it holds another id's matrices, so a rejected step that froze gains leaves nothing wrong
behind.  The powers (mu^k, the diagonal scalings) are numpy's own array ``power``
(core/powers.py): its SIMD code differs from libm's ``pow`` in the last bit of ~5 % of
the results, and near the end of a window such a bit shows as 4e-12 of the state's scale.
The step matrices are built where a step size is first met with the numpy and scipy code
the observer had before it was compiled (object mode), so both paths step with the same
matrices.
"""
from __future__ import annotations

import math

from ...core import jit as J
from ...core.discretize import STEP_QUANTUM
from ...core.exact_step import stacked
from ...core.jit import jit
from ...core.linalg import matvec
from ...core.reasons import CODE
from ..kernel import HEALTH, RESIDUAL, quanta
from .layout import (AFTER, END_REASON, END_T, FOH, FROZEN_ID, G_PEAK, HAS_END, HAS_F,
                     HAS_FROZEN, HAS_GEND, HAS_PREV, HAS_SMAP, HAS_T, KEEPS, KP, KSTART, MODE,
                     MODE_CONSTANT, N, NIN, O_AP, O_B, O_GEND, O_S, POST, R0, RESTARTS,
                     RESTARTS_TOTAL, RS_AFTER, RS_END_REASON, RS_END_T, RS_FROZEN, RS_HAS_END,
                     RS_NEW, RS_POST, RS_R1, RS_RESTARTS, RS_TW, SLOTS, STEPS, T_, T_MODEL, TW,
                     UP, W, YP, cvec, mat, scratch, vec)
from .windows import gains_of, guard, new_frozen_id, propagate, solve

_NON_FINITE_TERM = CODE["non_finite_model_term"]
_NON_FINITE = CODE["non_finite_estimate"]
_TOO_LONG = CODE["step_too_long"]



@jit
def _np_sum(x):
    """x.sum() as numpy adds (pairwise: eight accumulators from eight elements on; the
    orders here have at most MAX_ORDER = 10 < 16 elements)."""
    n = x.shape[0]
    if n < 8:
        acc = 0.0
        for i in range(n):
            acc += x[i]
        return acc
    acc = ((x[0] + x[1]) + (x[2] + x[3])) + ((x[4] + x[5]) + (x[6] + x[7]))
    for i in range(8, n):
        acc += x[i]
    return acc


# -- the step ---------------------------------------------------------------------------------
@jit
def _model(models, s, y, u, out):
    """F(y, u) into out; False when a term is not finite (or their sum overflows)."""
    if models[0](s, y, u, out) != 0:
        return False
    acc = 0.0
    for i in range(out.shape[0]):
        acc += out[i]
    return abs(acc) < math.inf


@jit
def _compute(s, c, ic, wk, k, y, u, models):
    """The step from the last sample of state s to model quanta k: the new x into scratch
    12, F for the next step into scratch 11, the rest into the result (scratch 17).  0, or
    the rejection code (nothing is committed)."""
    n, nin, w = ic[N], ic[NIN], ic[W]
    kp = s[KP]
    # model time: an integer number of STEP_QUANTUM (1 us): steps hit cached matrices
    # even for jittery live stamps, and the model time never drifts from the stamps
    h = (k - kp) * STEP_QUANTUM
    tp = kp * STEP_QUANTUM
    t = k * STEP_QUANTUM
    up = s[UP:UP + nin]
    u_end = u if ic[FOH] else up
    f1 = scratch(ic, wk, 10)
    if ic[HAS_F] and not _model(models, s, y, u_end, f1):
        return _NON_FINITE_TERM
    S = stacked(mat(c, ic, O_AP, n, n), mat(c, ic, O_B, n, w), h, wk, ic[STEPS], ic[SLOTS])
    ir0 = n + w - 1
    ir1 = n + 2 * w - 1
    den = 1.0 + S[0, ir1]
    if not abs(den) > 1e-9:
        return _TOO_LONG
    inv_den = 1.0 / den
    # [x_hat; w0; w1] with w = (u, F, r) and r(t_k+1) = 0 for now
    z = scratch(ic, wk, 0)
    z[:n] = vec(s, ic, 1)
    if nin:
        z[n] = up[0]
        z[n + w] = u_end[0]
    if ic[HAS_F]:
        z[n + nin:n + w - 1] = vec(s, ic, 2)
        z[n + w + nin:n + 2 * w - 1] = f1
    r0 = s[R0]
    z[ir0] = r0
    z[ir1] = 0.0
    # model prediction, then solve y = x_m,1 for r1 (one scalar equation: x_m depends on r1
    # through the -a r_lin input)
    xm = scratch(ic, wk, 1)
    matvec(S, z, xm)
    r1 = (y[0] - xm[0]) * inv_den
    for i in range(n):
        xm[i] += S[i, ir1] * r1
    q = scratch(ic, wk, 2)
    q[:] = 0.0
    q[0] = r0
    if n > 1:
        q[1] = (r1 - r0) / h
    rs = scratch(ic, wk, 17)
    rs[RS_HAS_END] = s[HAS_END]
    rs[RS_END_T] = s[END_T]
    rs[RS_END_REASON] = s[END_REASON]
    rs[RS_NEW] = 0.0
    code = propagate(s, c, ic, wk, tp, t, rs)
    if code != 0:
        return code
    d = scratch(ic, wk, 5)
    # x_hat = x_model + e^(A h) q - Phi q,  e^(A h) q = (q1 + h q2, q2, 0, ...)
    x = scratch(ic, wk, 12)
    for i in range(n):
        x[i] = xm[i] - d[i]
    if n > 1:
        x[0] = y[0] - d[0]                  # = xm_1 + r1 - (Phi q)_1, without rounding
        x[1] += q[1]
        post = d[0]                         # y - x_hat_1 after the step, exactly
    else:
        x[0] += r0
        post = y[0] - x[0]
    v = _np_sum(x) + r1
    if not abs(v) < math.inf:
        return _NON_FINITE
    guard(c, ic, wk, t, h, rs)
    # F(y, u) at the start of the next step (u may have changed at t)
    if ic[HAS_F]:
        fn = scratch(ic, wk, 11)
        same = True
        for i in range(nin):
            if u[i] != u_end[i]:
                same = False
        if same:
            fn[:] = f1
        elif not _model(models, s, y, u, fn):
            return _NON_FINITE_TERM
    rs[RS_POST] = post
    rs[RS_R1] = r1
    return 0


@jit
def gains_now(s, c, ic, wk, t, out):
    """The gains at model time t of state s (frozen or zero after the window)."""
    if s[AFTER] > 0.0:
        if s[HAS_FROZEN] > 0.0:
            out[:] = vec(s, ic, 3)
        else:
            out[:] = 0.0
        return
    T = c[T_]
    since = t - s[TW]
    if since < T:
        gains_of(c, ic, wk, T / (T - since), out)
    else:
        out[:] = math.inf


@jit
def _commit(nx, c, ic, wk, k, y, u, f, post, residual):
    """Store the accepted sample (model time k quanta); post = y - x_hat_1."""
    n, nin = ic[N], ic[NIN]
    t = k * STEP_QUANTUM
    nx[HAS_T] = 1.0
    nx[T_MODEL] = t
    nx[HAS_PREV] = 1.0
    nx[KP] = k
    nx[YP] = y[0]
    if nin:
        nx[UP] = u[0]
    if ic[HAS_F]:
        vec(nx, ic, 2)[:] = f
    nx[R0] = post
    nx[RESIDUAL] = residual
    nx[POST] = post
    g = scratch(ic, wk, 8)
    gains_now(nx, c, ic, wk, t, g)
    gmax = abs(g[0])                  # the first largest, as Python's max
    for i in range(1, n):
        if abs(g[i]) > gmax:
            gmax = abs(g[i])
    nx[HEALTH] = abs(post) * gmax
    if gmax > nx[G_PEAK]:
        nx[G_PEAK] = gmax
    if ic[HAS_SMAP]:
        matvec(mat(c, ic, O_S, ic[N], ic[N]), vec(nx, ic, 1), vec(nx, ic, 0))
    else:
        vec(nx, ic, 0)[:] = vec(nx, ic, 1)


@jit
def _step(st, nx, c, ic, wk, s, y, u, models):
    k = st[KSTART] + quanta(s)
    code = _compute(st, c, ic, wk, k, y, u, models)
    if code != 0:
        return code
    rs = scratch(ic, wk, 17)
    vec(nx, ic, 1)[:] = scratch(ic, wk, 12)
    nx[TW] = rs[RS_TW]
    nx[AFTER] = rs[RS_AFTER]
    if rs[RS_NEW] > 0.0:
        nx[HAS_FROZEN] = rs[RS_FROZEN]
        vec(nx, ic, 3)[:] = scratch(ic, wk, 13)
        nx[FROZEN_ID] = new_frozen_id(wk)
    nx[HAS_END] = rs[RS_HAS_END]
    nx[END_T] = rs[RS_END_T]
    nx[END_REASON] = rs[RS_END_REASON]
    nx[RESTARTS] += rs[RS_RESTARTS]
    nx[RESTARTS_TOTAL] += rs[RS_RESTARTS]
    _commit(nx, c, ic, wk, k, y, u, scratch(ic, wk, 11), rs[RS_POST], abs(rs[RS_R1]))
    return 0


@jit
def _first(st, nx, c, ic, wk, gap, y, u, models):
    """The first sample of a window (after a restart): a warm restart finishes the old
    window's step up to this sample when the gap to it is at most T."""
    f = scratch(ic, wk, 9)
    if ic[HAS_F] and not _model(models, st, y, u, f):
        return _NON_FINITE_TERM
    k = 0.0
    have_post = False
    post = 0.0
    if st[HAS_PREV] > 0.0 and 0 < gap <= c[T_]:
        k = st[KP] + quanta(gap)
        if _compute(st, c, ic, wk, k, y, u, models) == 0:
            vec(nx, ic, 1)[:] = scratch(ic, wk, 12)
            post = scratch(ic, wk, 17)[RS_POST]
            have_post = True
        # else: keep the estimate as it is
    elif st[HAS_PREV] > 0.0:
        k = st[KP] + 1.0           # model time keeps increasing; the gap is not bridged
    if not have_post:
        post = y[0] - vec(nx, ic, 1)[0]
    nx[KSTART] = k
    nx[TW] = k * STEP_QUANTUM             # the window starts at this sample
    nx[AFTER] = 0.0
    constant = ic[MODE] == MODE_CONSTANT and ic[HAS_GEND] != 0
    nx[HAS_FROZEN] = 1.0 if constant else 0.0
    if constant:
        vec(nx, ic, 3)[:] = cvec(c, ic, O_GEND)
    nx[FROZEN_ID] = new_frozen_id(wk)
    nx[RESTARTS] = 0.0
    nx[G_PEAK] = 0.0
    nx[HAS_END] = 0.0
    _commit(nx, c, ic, wk, k, y, u, f, post, abs(post))
    return 0


@jit
def _restart(st, c, ic, x0, has_x0, cold):
    """Start a new window at the next sample: from x0 (plant coordinates), else (when the
    estimate is kept, and the restart is not a ``cold`` one after a fault) from the current
    estimate moved on to that sample, else from 0."""
    x = vec(st, ic, 1)
    if has_x0:
        if ic[HAS_SMAP]:
            x[:] = solve(mat(c, ic, O_S, ic[N], ic[N]), x0)
        else:
            x[:] = x0
        st[HAS_PREV] = 0.0
    elif cold or not ic[KEEPS]:
        x[:] = 0.0
        st[HAS_PREV] = 0.0
    st[HAS_T] = 0.0
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, a, y, u, models)
    if op == J.FIRST:
        return _first(st, nx, c, ic, wk, a, y, u, models)
    if op == J.RESTART:
        return _restart(st, c, ic, y, a > 0.0, a < 0.0)
    return 0
