"""Per-sample kernel of the prescribed-time observer (protocol: observers/kernel.py; the
method: the adapter's module docstring).

One step from the last sample (model quanta kp) to the sample at k: the plant model's
exact FOH step ``[Phi | G0 | G1] [x; w0; w1]`` (core/exact_step.py's cached matrix,
w = (u, F(y, u), r)), r(t_k+1) from the one scalar equation y = x_model,1, then the
correction ``e^(A h) q - Phi_err(t_k+1, t_k) q`` with Phi_err from Lemma 1 (``transition``:
the scaled product with the cached E_bar(h) = e^(H Lambda H^-1 h)) across window ends
(``_propagate``: restart, stop or constant per mode), the sampling guard, and the commit
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
(core/numpy_loops.py): its SIMD code differs from libm's ``pow`` in the last bit of ~5 % of
the results, and near the end of a window such a bit shows as 4e-12 of the state's scale.
The step matrices are built where a step size is first met with the numpy and scipy code
the observer had before it was compiled (object mode), so both paths step with the same
matrices.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from ...core import jit as J
from ...core.discretize import STEP_QUANTUM
from ...core.exact_step import stacked
from ...core.jit import jit, numba
from ...core.linalg import matvec
from ...core.numpy_loops import power
from ...core.reasons import CODE
from ...core.step_cache import cache_claim, cache_clear, cache_find
from ..kernel import C_HEADER, HEADER, IC_HEADER, RESIDUAL, HEALTH, quanta
from .design import is_hurwitz

# -- integer constants ------------------------------------------------------------------
(N, NIN, HAS_F, MODE, HAS_GEND, HAS_SMAP, KEEPS, FOH, W, STEPS, EBARS, AFTERS, SCRATCH,
 SLOTS, O_HG, O_C, O_CINV, O_L, O_GEND, O_AP, O_B, O_S, O_EXP) = range(IC_HEADER, IC_HEADER + 23)
MODE_RESTART, MODE_STOP, MODE_CONSTANT = 0, 1, 2
MODES = ("restart", "stop", "constant")
# -- float constants --------------------------------------------------------------------
T_, S_END, BETA, NM = range(C_HEADER, C_HEADER + 4)
C_ARRAYS = C_HEADER + 4
# -- state scalars ----------------------------------------------------------------------
(HAS_PREV, KP, YP, UP, R0, HAS_T, T_MODEL, KSTART, TW, AFTER, HAS_FROZEN, FROZEN_ID,
 RESTARTS, RESTARTS_TOTAL, HAS_END, END_T, END_REASON, G_PEAK, POST) = range(HEADER, HEADER + 19)
X_PUB = HEADER + 19
#: END_REASON: the configured end (T, t_stop or g_max), or the sampling limit
END_CONFIGURED, END_SAMPLING = 0.0, 1.0
# -- work ---------------------------------------------------------------------------------
WK_NEXT_ID, WK_AFTER_ID = 0, 1
WK_HEADER = 2
# -- the result of a step (scratch): post, r1, tw, after, restarts, has end, end t, end
#    reason, new frozen gains (0/1), whether they are set (0/1)
(RS_POST, RS_R1, RS_TW, RS_AFTER, RS_RESTARTS, RS_HAS_END, RS_END_T, RS_END_REASON, RS_NEW,
 RS_FROZEN) = range(10)
RS_SIZE = 10
_MAX_WINDOWS = 100000

_NON_FINITE_TERM = CODE["non_finite_model_term"]
_NON_FINITE = CODE["non_finite_estimate"]
_TOO_LONG = CODE["step_too_long"]
_TOO_MANY = CODE["step_spans_too_many_windows"]


def state_size(n: int) -> int:
    return X_PUB + 4 * n


def scratch_size(n: int, w: int) -> int:
    """Floats of the scratch (``_scratch``): z, 13 n-vectors, scal, bases, mu^k, result."""
    return (n + 2 * w) + 13 * n + 4 * n + 4 + (n + 1) + 1 + RS_SIZE


# -- the cached matrices, built where they are first needed (numpy and scipy, as before) --
def _balanced(col, h, unbalance):
    """E_bar(h) = e^(H (N - col e_1') H^-1 h) with H = diag(h^(i-1)), N the upper shift
    (unbalance False), or H^-1 E_bar H (True: the step past the window end).

    The balanced matrix has 1 on the superdiagonal and -col_i h^i in the first column, so
    expm's normwise accuracy is accuracy where it matters.
    """
    n = col.size
    M = np.diag(np.ones(n - 1), 1) if n > 1 else np.zeros((1, 1))
    M[:, 0] = -col * h ** np.arange(1, n + 1)
    E = expm(M)
    if unbalance:
        p = np.arange(n, dtype=float)
        E = E / h ** p[:, None] * h ** p[None, :]
    return np.ascontiguousarray(E)


def _solve_py(S, x):
    return np.ascontiguousarray(np.linalg.solve(S, x))


def _hurwitz_py(g):
    return 1 if is_hurwitz(g) else 0


if J.ENABLED:
    def _balanced_obj(col, h, unbalance):
        with numba.objmode(out="float64[:, ::1]"):
            out = _balanced(col, h, unbalance)
        return out

    def _solve_obj(S, x):
        with numba.objmode(out="float64[::1]"):
            out = _solve_py(S, x)
        return out

    def _hurwitz_obj(g):
        with numba.objmode(out="int64"):
            out = _hurwitz_py(g)
        return out

    balanced = jit(_balanced_obj, gil=True)
    solve = jit(_solve_obj, gil=True)
    hurwitz = jit(_hurwitz_obj, gil=True)
else:
    balanced, solve, hurwitz = _balanced, _solve_py, _hurwitz_py


# -- powers: numpy's own array power (core/numpy_loops.py), as the code before the kernel --
def _powers_np(mu, exps, cell, out):
    np.power(mu, exps, out=out)


@jit(pure=_powers_np)
def _powers(mu, exps, cell, out):
    """out[k] = mu^exps[k] (cell: one float of memory for mu)."""
    cell[0] = mu
    power(cell, 0, exps, out)


def _scalings_np(bases, exps, out):
    np.power(bases.reshape(4, 1), np.vstack([exps] * 4), out=out)


@jit(pure=_scalings_np)
def _scalings(bases, exps, out):
    """out[r, i] = bases[r]^exps[i] (4 x n)."""
    for r in range(4):
        power(bases[r:r + 1], 0, exps, out[r])


@jit
def gains(Hg, exps, mu, cell, mu_pow, out):
    """g_1..g_n at mu_1 = mu (Lemma 4 polynomials) into out; exps = 0..n."""
    _powers(mu, exps, cell, mu_pow)
    matvec(Hg, mu_pow, out)


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


# -- views -----------------------------------------------------------------------------
@jit
def _mat(c, ic, at, rows, cols):
    """The rows x cols constant matrix at offset ic[at] of c."""
    o = ic[at]
    return c[o:o + rows * cols].reshape(rows, cols)


@jit
def _cvec(c, ic, at):
    """The n-vector constant at offset ic[at] of c."""
    o = ic[at]
    return c[o:o + ic[N]]


@jit
def _scratch(ic, wk, k):
    """Scratch vector k: 0 z (n + 2W), 1 xm, 2 q, 3 pa, 4 pb, 5 d, 6 t1, 7 t2, 8 g, 9 f0,
    10 f1, 11 f_next, 12 x new, 13 frozen new (n each), 14 scal (4n), 15 bases (4),
    16 mu^k (n + 1), 17 the step's result (RS_SIZE), 18 one float (a power's base)."""
    n, w = ic[N], ic[W]
    o = ic[SCRATCH]
    if k == 0:
        return wk[o:o + n + 2 * w]
    o += n + 2 * w
    if k <= 13:
        o += (k - 1) * n
        return wk[o:o + n]
    o += 13 * n
    if k == 14:
        return wk[o:o + 4 * n]
    o += 4 * n
    if k == 15:
        return wk[o:o + 4]
    o += 4
    if k == 16:
        return wk[o:o + n + 1]
    o += n + 1
    if k == 17:
        return wk[o:o + RS_SIZE]
    o += RS_SIZE
    return wk[o:o + 1]


@jit
def _vec(s, ic, k):
    """State vector k: 0 x published, 1 x, 2 F of the last sample, 3 frozen gains."""
    n = ic[N]
    o = X_PUB + k * n
    return s[o:o + n]


@jit
def _gains(c, ic, wk, mu, out):
    n = ic[N]
    gains(_mat(c, ic, O_HG, n, n + 1), c[ic[O_EXP]:ic[O_EXP] + n + 1], mu, _scratch(ic, wk, 18),
          _scratch(ic, wk, 16), out)


# -- the cached step matrices --------------------------------------------------------------
@jit
def _cached(wk, base, slots, n, col, h, unbalance):
    """The n x n matrix of step h (max(h, 1 ns), keyed by integer ns) from the cache at base."""
    hh = 1e-9 if 1e-9 > h else h
    key = float(round(hh * 1e9))
    off = cache_find(wk, base, slots, n * n, key)
    if off < 0:
        off = cache_claim(wk, base, slots, n * n, key)
        E = balanced(col, key * 1e-9, unbalance)
        for i in range(n):
            for j in range(n):
                wk[off + i * n + j] = E[i, j]
    return wk[off:off + n * n].reshape(n, n)


@jit
def _after_matrix(s, c, ic, wk, h):
    """H^-1 e^(...) H of a step past the window end: free (no frozen gains) or frozen."""
    n = ic[N]
    if wk[WK_AFTER_ID] != s[FROZEN_ID]:
        cache_clear(wk, ic[AFTERS], ic[SLOTS])
        wk[WK_AFTER_ID] = s[FROZEN_ID]
    if s[HAS_FROZEN] > 0.0:
        col = _vec(s, ic, 3)
    else:
        col = _scratch(ic, wk, 13)          # free until the sampling guard
        col[:] = 0.0
    return _cached(wk, ic[AFTERS], ic[SLOTS], n, col, h, True)


@jit
def _new_frozen_id(wk):
    wk[WK_NEXT_ID] += 1.0
    return wk[WK_NEXT_ID]


# -- Lemma 1: the error system's transition inside a window --------------------------------
@jit
def transition(c, ic, wk, v, sa, sb, out):
    """out = Phi(t0 + sb, t0 + sa) v inside one window, 0 <= sa < sb <= T (sb = T: 0)."""
    n = ic[N]
    T = c[T_]
    h = sb - sa
    if not h > 0.0:
        out[:] = v
        return
    kap = 1.0 / (T - sa)
    beta = h * kap
    left = T - sb
    if 0.0 > left:
        left = 0.0
    rho = left * kap
    if rho <= 0.0:
        out[:] = 0.0              # the window ends at T: Phi = 0
        return
    # the diagonal scalings k^-i, beta^i, (rho/beta)^i, (k/rho)^i; k^i rho^(n+m-i) =
    # rho^(n+m) (k/rho)^i
    bases = _scratch(ic, wk, 15)
    scal = _scratch(ic, wk, 14).reshape(4, n)
    bases[0] = 1.0 / kap
    bases[1] = beta
    bases[2] = rho / beta
    bases[3] = kap / rho
    _scalings(bases, c[ic[O_EXP] + 1:ic[O_EXP] + n + 1], scal)
    t1 = _scratch(ic, wk, 6)
    t2 = _scratch(ic, wk, 7)
    for i in range(n):
        t1[i] = v[i] * scal[0, i]
    matvec(_mat(c, ic, O_C, n, n), t1, t2)
    for i in range(n):
        t2[i] *= scal[1, i]
    E = _cached(wk, ic[EBARS], ic[SLOTS], n, _cvec(c, ic, O_L), h, False)
    matvec(E, t2, t1)
    for i in range(n):
        t1[i] *= scal[2, i]
    matvec(_mat(c, ic, O_CINV, n, n), t1, t2)
    f = rho ** c[NM]
    for i in range(n):
        out[i] = t2[i] * scal[3, i] * f


@jit
def _propagate(s, c, ic, wk, ta, tb, rs):
    """Phi(tb, ta) q across window ends into d (scratch 5); the window's new start, phase,
    restarts and last end into rs.  0, or step_spans_too_many_windows."""
    n = ic[N]
    s_end = c[S_END]
    restart = ic[MODE] == MODE_RESTART
    tw = s[TW]
    after = s[AFTER] > 0.0
    restarts = 0
    pa = _scratch(ic, wk, 3)
    pb = _scratch(ic, wk, 4)
    pa[:] = _scratch(ic, wk, 2)
    t = ta
    while t < tb:
        if after:
            matvec(_after_matrix(s, c, ic, wk, tb - t), pa, pb)
            pa, pb = pb, pa
            break
        t_end = tw + s_end
        if tb < t_end - 1e-10:
            transition(c, ic, wk, pa, t - tw, tb - tw, pb)
            pa, pb = pb, pa
            break
        # the window ends within (t, tb]: up to its end exactly, then what mode says
        if t_end - t > 1e-10:
            transition(c, ic, wk, pa, t - tw, s_end, pb)
            pa, pb = pb, pa
        t = t_end
        rs[RS_HAS_END] = 1.0
        rs[RS_END_T] = t_end
        rs[RS_END_REASON] = END_CONFIGURED
        if not restart:
            after = True
            continue
        tw = t_end
        restarts += 1
        nonzero = False
        for i in range(n):
            if pa[i] != 0.0:
                nonzero = True
        if not nonzero and tb - t > s_end:
            # nothing left to carry (a window that runs to T maps every error to 0):
            # skip the whole windows of a long step at once
            k = int((tb - t) // s_end)
            tw += k * s_end
            restarts += k
            t = tw
        if restarts > _MAX_WINDOWS:
            return _TOO_MANY
    _scratch(ic, wk, 5)[:] = pa
    rs[RS_TW] = tw
    rs[RS_AFTER] = 1.0 if after else 0.0
    rs[RS_RESTARTS] = restarts
    return 0


@jit
def _guard(c, ic, wk, t, h, rs):
    """Sampling guard: end the window at t when fewer than 1/beta_guard steps of length h
    are left before T (the sampled output cannot feed a faster observer)."""
    beta = c[BETA]
    if rs[RS_AFTER] > 0.0 or not beta < math.inf:
        return
    T = c[T_]
    left = T - (t - rs[RS_TW])
    if left <= 0 or h < beta * left:
        return
    rs[RS_HAS_END] = 1.0
    rs[RS_END_T] = t
    rs[RS_END_REASON] = END_SAMPLING
    if ic[MODE] == MODE_RESTART:
        rs[RS_TW] = t
        rs[RS_RESTARTS] += 1.0
        return
    if ic[MODE] == MODE_CONSTANT:
        fz = _scratch(ic, wk, 13)
        _gains(c, ic, wk, T / left, fz)
        rs[RS_NEW] = 1.0
        # cannot freeze there: stop the injections instead
        rs[RS_FROZEN] = 1.0 if hurwitz(fz) else 0.0
    rs[RS_AFTER] = 1.0


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
    f1 = _scratch(ic, wk, 10)
    if ic[HAS_F] and not _model(models, s, y, u_end, f1):
        return _NON_FINITE_TERM
    S = stacked(_mat(c, ic, O_AP, n, n), _mat(c, ic, O_B, n, w), h, wk, ic[STEPS], ic[SLOTS])
    ir0 = n + w - 1
    ir1 = n + 2 * w - 1
    den = 1.0 + S[0, ir1]
    if not abs(den) > 1e-9:
        return _TOO_LONG
    inv_den = 1.0 / den
    # [x_hat; w0; w1] with w = (u, F, r) and r(t_k+1) = 0 for now
    z = _scratch(ic, wk, 0)
    z[:n] = _vec(s, ic, 1)
    if nin:
        z[n] = up[0]
        z[n + w] = u_end[0]
    if ic[HAS_F]:
        z[n + nin:n + w - 1] = _vec(s, ic, 2)
        z[n + w + nin:n + 2 * w - 1] = f1
    r0 = s[R0]
    z[ir0] = r0
    z[ir1] = 0.0
    # model prediction, then solve y = x_m,1 for r1 (one scalar equation: x_m depends on r1
    # through the -a r_lin input)
    xm = _scratch(ic, wk, 1)
    matvec(S, z, xm)
    r1 = (y[0] - xm[0]) * inv_den
    for i in range(n):
        xm[i] += S[i, ir1] * r1
    q = _scratch(ic, wk, 2)
    q[:] = 0.0
    q[0] = r0
    if n > 1:
        q[1] = (r1 - r0) / h
    rs = _scratch(ic, wk, 17)
    rs[RS_HAS_END] = s[HAS_END]
    rs[RS_END_T] = s[END_T]
    rs[RS_END_REASON] = s[END_REASON]
    rs[RS_NEW] = 0.0
    code = _propagate(s, c, ic, wk, tp, t, rs)
    if code != 0:
        return code
    d = _scratch(ic, wk, 5)
    # x_hat = x_model + e^(A h) q - Phi q,  e^(A h) q = (q1 + h q2, q2, 0, ...)
    x = _scratch(ic, wk, 12)
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
    _guard(c, ic, wk, t, h, rs)
    # F(y, u) at the start of the next step (u may have changed at t)
    if ic[HAS_F]:
        fn = _scratch(ic, wk, 11)
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
def _gains_now(s, c, ic, wk, t, out):
    """The gains at model time t of state s (frozen or zero after the window)."""
    if s[AFTER] > 0.0:
        if s[HAS_FROZEN] > 0.0:
            out[:] = _vec(s, ic, 3)
        else:
            out[:] = 0.0
        return
    T = c[T_]
    since = t - s[TW]
    if since < T:
        _gains(c, ic, wk, T / (T - since), out)
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
        _vec(nx, ic, 2)[:] = f
    nx[R0] = post
    nx[RESIDUAL] = residual
    nx[POST] = post
    g = _scratch(ic, wk, 8)
    _gains_now(nx, c, ic, wk, t, g)
    gmax = abs(g[0])                  # the first largest, as Python's max
    for i in range(1, n):
        if abs(g[i]) > gmax:
            gmax = abs(g[i])
    nx[HEALTH] = abs(post) * gmax
    if gmax > nx[G_PEAK]:
        nx[G_PEAK] = gmax
    if ic[HAS_SMAP]:
        matvec(_mat(c, ic, O_S, ic[N], ic[N]), _vec(nx, ic, 1), _vec(nx, ic, 0))
    else:
        _vec(nx, ic, 0)[:] = _vec(nx, ic, 1)


@jit
def _step(st, nx, c, ic, wk, s, y, u, models):
    k = st[KSTART] + quanta(s)
    code = _compute(st, c, ic, wk, k, y, u, models)
    if code != 0:
        return code
    rs = _scratch(ic, wk, 17)
    _vec(nx, ic, 1)[:] = _scratch(ic, wk, 12)
    nx[TW] = rs[RS_TW]
    nx[AFTER] = rs[RS_AFTER]
    if rs[RS_NEW] > 0.0:
        nx[HAS_FROZEN] = rs[RS_FROZEN]
        _vec(nx, ic, 3)[:] = _scratch(ic, wk, 13)
        nx[FROZEN_ID] = _new_frozen_id(wk)
    nx[HAS_END] = rs[RS_HAS_END]
    nx[END_T] = rs[RS_END_T]
    nx[END_REASON] = rs[RS_END_REASON]
    nx[RESTARTS] += rs[RS_RESTARTS]
    nx[RESTARTS_TOTAL] += rs[RS_RESTARTS]
    _commit(nx, c, ic, wk, k, y, u, _scratch(ic, wk, 11), rs[RS_POST], abs(rs[RS_R1]))
    return 0


@jit
def _first(st, nx, c, ic, wk, gap, y, u, models):
    """The first sample of a window (after a restart): a warm restart finishes the old
    window's step up to this sample when the gap to it is at most T."""
    f = _scratch(ic, wk, 9)
    if ic[HAS_F] and not _model(models, st, y, u, f):
        return _NON_FINITE_TERM
    k = 0.0
    have_post = False
    post = 0.0
    if st[HAS_PREV] > 0.0 and 0 < gap <= c[T_]:
        k = st[KP] + quanta(gap)
        if _compute(st, c, ic, wk, k, y, u, models) == 0:
            _vec(nx, ic, 1)[:] = _scratch(ic, wk, 12)
            post = _scratch(ic, wk, 17)[RS_POST]
            have_post = True
        # else: keep the estimate as it is
    elif st[HAS_PREV] > 0.0:
        k = st[KP] + 1.0           # model time keeps increasing; the gap is not bridged
    if not have_post:
        post = y[0] - _vec(nx, ic, 1)[0]
    nx[KSTART] = k
    nx[TW] = k * STEP_QUANTUM             # the window starts at this sample
    nx[AFTER] = 0.0
    constant = ic[MODE] == MODE_CONSTANT and ic[HAS_GEND] != 0
    nx[HAS_FROZEN] = 1.0 if constant else 0.0
    if constant:
        _vec(nx, ic, 3)[:] = _cvec(c, ic, O_GEND)
    nx[FROZEN_ID] = _new_frozen_id(wk)
    nx[RESTARTS] = 0.0
    nx[G_PEAK] = 0.0
    nx[HAS_END] = 0.0
    _commit(nx, c, ic, wk, k, y, u, f, post, abs(post))
    return 0


@jit
def _restart(st, c, ic, x0, has_x0):
    """Start a new window at the next sample: from x0 (plant coordinates), else (when the
    estimate is kept) from the current estimate moved on to that sample, else from 0."""
    x = _vec(st, ic, 1)
    if has_x0:
        if ic[HAS_SMAP]:
            x[:] = solve(_mat(c, ic, O_S, ic[N], ic[N]), x0)
        else:
            x[:] = x0
        st[HAS_PREV] = 0.0
    elif not ic[KEEPS]:
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
        return _restart(st, c, ic, y, a > 0.0)
    return 0
