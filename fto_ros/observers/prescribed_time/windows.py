"""The window mechanics of the prescribed-time kernel: the gains (Lemma 4 polynomials), the
error system's transition inside a window in closed form (Lemma 1), the steps past a
window's end (free, or with frozen gains), the crossing of window ends per mode, and the
sampling guard.  The step matrices are cached per step size in the work memory; the powers
are numpy's own (core/powers.py).  kernel.py has the method and the layout.

ROS-free.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm

from ...core import jit as J
from ...core.jit import jit, numba
from ...core.linalg import matvec
from ...core.powers import power
from ...core.reasons import CODE
from ...core.step_cache import cache_claim, cache_clear, cache_find
from .design import is_hurwitz
from .layout import (AFTER, AFTERS, BETA, EBARS, END_CONFIGURED, END_SAMPLING, FROZEN_ID,
                     HAS_FROZEN, MODE, MODE_CONSTANT, MODE_RESTART, N, NM, O_C, O_CINV, O_EXP,
                     O_HG, O_L, RS_AFTER, RS_END_REASON, RS_END_T, RS_FROZEN, RS_HAS_END, RS_NEW,
                     RS_RESTARTS, RS_TW, S_END, SLOTS, T_, TW, WK_AFTER_ID, WK_NEXT_ID, cvec, mat,
                     scratch, vec)

_MAX_WINDOWS = 100000
_TOO_MANY = CODE["step_spans_too_many_windows"]


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


# -- powers: numpy's own array power (core/powers.py), as the code before the kernel --
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
def gains_of(c, ic, wk, mu, out):
    n = ic[N]
    gains(mat(c, ic, O_HG, n, n + 1), c[ic[O_EXP]:ic[O_EXP] + n + 1], mu, scratch(ic, wk, 18),
          scratch(ic, wk, 16), out)


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
        col = vec(s, ic, 3)
    else:
        col = scratch(ic, wk, 13)          # free until the sampling guard
        col[:] = 0.0
    return _cached(wk, ic[AFTERS], ic[SLOTS], n, col, h, True)


@jit
def new_frozen_id(wk):
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
    bases = scratch(ic, wk, 15)
    scal = scratch(ic, wk, 14).reshape(4, n)
    bases[0] = 1.0 / kap
    bases[1] = beta
    bases[2] = rho / beta
    bases[3] = kap / rho
    _scalings(bases, c[ic[O_EXP] + 1:ic[O_EXP] + n + 1], scal)
    t1 = scratch(ic, wk, 6)
    t2 = scratch(ic, wk, 7)
    for i in range(n):
        t1[i] = v[i] * scal[0, i]
    matvec(mat(c, ic, O_C, n, n), t1, t2)
    for i in range(n):
        t2[i] *= scal[1, i]
    E = _cached(wk, ic[EBARS], ic[SLOTS], n, cvec(c, ic, O_L), h, False)
    matvec(E, t2, t1)
    for i in range(n):
        t1[i] *= scal[2, i]
    matvec(mat(c, ic, O_CINV, n, n), t1, t2)
    f = rho ** c[NM]
    for i in range(n):
        out[i] = t2[i] * scal[3, i] * f


@jit
def propagate(s, c, ic, wk, ta, tb, rs):
    """Phi(tb, ta) q across window ends into d (scratch 5); the window's new start, phase,
    restarts and last end into rs.  0, or step_spans_too_many_windows."""
    n = ic[N]
    s_end = c[S_END]
    restart = ic[MODE] == MODE_RESTART
    tw = s[TW]
    after = s[AFTER] > 0.0
    restarts = 0
    pa = scratch(ic, wk, 3)
    pb = scratch(ic, wk, 4)
    pa[:] = scratch(ic, wk, 2)
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
    scratch(ic, wk, 5)[:] = pa
    rs[RS_TW] = tw
    rs[RS_AFTER] = 1.0 if after else 0.0
    rs[RS_RESTARTS] = restarts
    return 0


@jit
def guard(c, ic, wk, t, h, rs):
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
        fz = scratch(ic, wk, 13)
        gains_of(c, ic, wk, T / left, fz)
        rs[RS_NEW] = 1.0
        # cannot freeze there: stop the injections instead
        rs[RS_FROZEN] = 1.0 if hurwitz(fz) else 0.0
    rs[RS_AFTER] = 1.0
