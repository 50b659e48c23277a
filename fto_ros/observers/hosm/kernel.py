"""Per-sample kernel of the hosm observer (protocol: observers/kernel.py; the method:
observers/hosm/adapter.py's docstring).

Per step h, with the output error ytil = y - C z first-order held (implicit in z):

    z     = K_h [z, u0, (F0,) ytil0, u_end, (F1,) y]     K_h cached per step size (ns key)
    ytil  = y - C z
    v_i   = differentiator i on ytil_i (core/differentiator_step.py; none when r_i = 1 and
            the unknown input is not identified: v_i1 = ytil_i)
    om1   = (v_i,1..v_i,r_i)_i,   vbar_i = v_i,r_i+1
    om2   = exact step of om2' = A22 om2 + A21 om1 (om1 linear over the step)
    x_hat = z + Tinv1 om1 + Tinv2 om2,   zeta = Qinv (vbar - G [om1; om2])

K_h is built where a step size is met for the first time, by the numpy/scipy code of
``_fill_step_matrix`` (through numba's object mode when compiled): the same matrices as the
numpy path, bit for bit.  The (F0,) (F1,) columns are absent when F is identically zero.

State:   header | x_hat (n) | zeta (p, when identified) | z (n) | ytil (p) | y (p) | u (m) |
         F (n) | om1 (r) | om2 (nz) | has_x0 | x0 (n) | the differentiators' states
Consts:  header | A (n x n) | [B | I | L] (n x (m+n+p)) | C (p x n) | C^+ (n x p) |
         Tinv1 (n x r) | Tinv2 (n x nz) | Qinv (p x p) | G (p x (r+nz)) | A22 | A21 |
         the differentiators' descriptors
Ints:    header | the sizes and flags and offsets below (names = index constants), then per
         output i: ORDER (0: no differentiator), block start and length in om1, the
         differentiator's descriptor offset in c and state offset in st
Work:    the K_h cache (entries [ok, K_h]), the om2 step cache, scratch: Tinv products (n),
         theta (r + nz), G theta / y - C x_hat (p), vbar (p), F1 (n), the product's vector
         (ncol), then the differentiators' or the om2 step's scratch (shared)
Models:  [F(y, u)] (n terms)
"""
from __future__ import annotations

import numpy as np

from ...core import differentiator_step as red
from ...core import jit as J
from ...core.exact_step import exact_step
from ...core.jit import jit
from ...core.linalg import finite, matvec, norm
from ...core.reasons import CODE
from ...core.step_cache import cache_claim, cache_find
from ..kernel import HEADER, HEALTH, IC_HEADER, RESIDUAL

(N, P, M, R, NZ, IDENT, FOH, FZERO, FHASU, NCOL,
 CA, CBW, CC, CCPINV, CTINV1, CTINV2, CQINV, CG, CA22, CA21,
 SZ, SYT, SY, SU, SF, SOM1, SOM2, SHASX0, SX0,
 WK, KSLOTS, WZ, ZSLOTS, WT1, WTH, WGT, WVB, WF1, WV, WR,
 PER_OUT) = range(IC_HEADER, IC_HEADER + 41)
#: per-output integers, from ic[PER_OUT] on: order, om1 block start, block length,
#: descriptor offset, state offset
OUT_WIDTH = 5
_SINGULAR = CODE["singular_step"]
_NON_FINITE = CODE["non_finite_estimate"]
_NON_FINITE_TERM = CODE["non_finite_model_term"]


def _fill_step_matrix(A, Bw, C, fzero, h, out):
    """out = K_h (n x ncol), z_new = K_h [z, u0, F0, ytil0, u1, F1, y] (no F columns when
    F is zero), from the exact FOH step of z' = A z + [B | I | L] [u; F; ytil] with ytil
    held first-order and solved for z at the new sample; 0 when that solve is singular
    (cond > 1e12).  numpy/scipy: the matrices of the previous Python code, bit for bit."""
    from ...core.discretize import foh_matrices
    n, p = A.shape[0], C.shape[0]
    m = Bw.shape[1] - n - p
    with np.errstate(all="ignore"):
        try:
            S = np.hstack(foh_matrices(A, Bw, h))     # [Phi | G0 | G1], w = [u, F, ytil]
        except (ValueError, np.linalg.LinAlgError):   # a design that overflows the exponential
            return 0
        if not np.isfinite(S).all():
            return 0
        w = m + n + p
        Phi, G0, G1 = S[:, :n], S[:, n:n + w], S[:, n + w:]
        G1L = G1[:, m + n:]
        Mimp = np.eye(n) + G1L @ C
        try:
            if not np.isfinite(Mimp).all() or np.linalg.cond(Mimp) > 1e12:
                return 0
            if fzero:               # no F columns: [z, u0, ytil0, u1, y1]
                blocks = [Phi, G0[:, :m], G0[:, m + n:], G1[:, :m], G1L]
            else:
                blocks = [Phi, G0, G1[:, :m + n], G1L]
            K = np.linalg.solve(Mimp, np.hstack(blocks))
        except np.linalg.LinAlgError:
            return 0
    if not np.isfinite(K).all():
        return 0
    out[:, :] = K
    return 1


if J.ENABLED:
    def _fill_jit(A, Bw, C, fzero, h, out):
        with J.numba.objmode(ok="int64"):
            ok = _fill_step_matrix(A, Bw, C, fzero, h, out)
        return ok
    fill_step_matrix = J.jit(_fill_jit, gil=True)
else:
    fill_step_matrix = _fill_step_matrix


@jit
def _mat(c, ic, key, rows, cols):
    o = ic[key]
    return c[o:o + rows * cols].reshape(rows, cols)


@jit
def _put(v, o, a):
    """v[o:o + len(a)] = a; the offset after it."""
    v[o:o + a.shape[0]] = a
    return o + a.shape[0]


@jit
def _gather(nx, c, ic, ytil, om1, vbar):
    """om1 and vbar from the output error and the differentiators' estimates (in nx)."""
    p = ic[P]
    for i in range(p):
        b = ic[PER_OUT] + OUT_WIDTH * i
        order, start, ri, dc, ds = ic[b], ic[b + 1], ic[b + 2], ic[b + 3], ic[b + 4]
        if order == 0:
            om1[start] = ytil[i]
            continue
        NT = int(c[dc])
        e0 = ds + NT + int(c[dc + 1])              # z+ of the signal (past the filter)
        for j in range(ri):
            om1[start + j] = nx[e0 + j]
        if ic[IDENT]:
            vbar[i] = nx[e0 + ri]


@jit
def _finish(nx, c, ic, wk, z, om1, vbar, om2):
    """x_hat and zeta into nx, the output residual and the health figure; False when a
    value is not finite."""
    n, p, r, nz = ic[N], ic[P], ic[R], ic[NZ]
    t1 = wk[ic[WT1]:ic[WT1] + n]
    xh = nx[HEADER:HEADER + n]
    matvec(_mat(c, ic, CTINV1, n, r), om1, t1)
    for i in range(n):
        xh[i] = z[i] + t1[i]
    if nz:
        matvec(_mat(c, ic, CTINV2, n, nz), om2, t1)
        for i in range(n):
            xh[i] += t1[i]
    ok = finite(xh)
    if ic[IDENT]:
        theta = wk[ic[WTH]:ic[WTH] + r + nz]
        theta[:r] = om1
        theta[r:] = om2
        gt = wk[ic[WGT]:ic[WGT] + p]
        matvec(_mat(c, ic, CG, p, r + nz), theta, gt)
        for i in range(p):
            gt[i] = vbar[i] - gt[i]
        zeta = nx[HEADER + n:HEADER + n + p]
        matvec(_mat(c, ic, CQINV, p, p), gt, zeta)
        ok = ok and finite(zeta)
    # the output residual |y - C x_hat| and the largest differentiator residual
    res = wk[ic[WGT]:ic[WGT] + p]
    matvec(_mat(c, ic, CC, p, n), xh, res)
    y = nx[ic[SY]:ic[SY] + p]
    for i in range(p):
        res[i] = y[i] - res[i]
    nx[RESIDUAL] = norm(res)
    health = 0.0
    for i in range(p):
        b = ic[PER_OUT] + OUT_WIDTH * i
        if ic[b] != 0:
            health = max(health, red.residual(c, ic[b + 3], nx, ic[b + 4], 0))
    nx[HEALTH] = health
    return ok


@jit
def _restart(st, ic, x0, has_x0):
    n = ic[N]
    st[ic[SHASX0]] = 1.0 if has_x0 else 0.0
    for i in range(n):
        st[ic[SX0] + i] = x0[i] if has_x0 else 0.0
    st[RESIDUAL] = np.nan
    return 0


@jit
def _first(st, nx, c, ic, wk, y, u, models):
    n, p, m, r, nz = ic[N], ic[P], ic[M], ic[R], ic[NZ]
    F = nx[ic[SF]:ic[SF] + n]
    if ic[FZERO]:
        F[:] = 0.0
    elif models[0](st, y, u, F) != 0:
        return _NON_FINITE_TERM
    z = nx[ic[SZ]:ic[SZ] + n]
    if st[ic[SHASX0]] > 0.0:
        z[:] = st[ic[SX0]:ic[SX0] + n]
    else:
        matvec(_mat(c, ic, CCPINV, n, p), y, z)
    ytil = nx[ic[SYT]:ic[SYT] + p]
    matvec(_mat(c, ic, CC, p, n), z, ytil)
    for i in range(p):
        ytil[i] = y[i] - ytil[i]
    for i in range(p):
        b = ic[PER_OUT] + OUT_WIDTH * i
        if ic[b] != 0:
            red.reset(c, ic[b + 3], nx, ic[b + 4], ytil[i:i + 1], ytil[0:0], False)
    om1 = nx[ic[SOM1]:ic[SOM1] + r]
    om2 = nx[ic[SOM2]:ic[SOM2] + nz]
    om2[:] = 0.0
    vbar = wk[ic[WVB]:ic[WVB] + p]
    _gather(nx, c, ic, ytil, om1, vbar)
    nx[ic[SY]:ic[SY] + p] = y
    nx[ic[SU]:ic[SU] + m] = u
    _finish(nx, c, ic, wk, z, om1, vbar, om2)
    return 0


@jit
def _step(st, nx, c, ic, wk, h, y, u, models):
    n, p, m, r, nz, ncol = ic[N], ic[P], ic[M], ic[R], ic[NZ], ic[NCOL]
    u0 = st[ic[SU]:ic[SU] + m]
    u_end = u if ic[FOH] else u0
    F0 = st[ic[SF]:ic[SF] + n]
    F1 = wk[ic[WF1]:ic[WF1] + n]
    if ic[FZERO]:
        F1[:] = 0.0
    else:
        models[0](st, y, u_end, F1)
    # the cached K_h
    key = float(round(h * 1e9))
    size = 1 + n * ncol
    off = cache_find(wk, ic[WK], ic[KSLOTS], size, key)
    if off < 0:
        off = cache_claim(wk, ic[WK], ic[KSLOTS], size, key)
        wk[off] = fill_step_matrix(_mat(c, ic, CA, n, n), _mat(c, ic, CBW, n, m + n + p),
                                   _mat(c, ic, CC, p, n), ic[FZERO] != 0, key * 1e-9,
                                   wk[off + 1:off + size].reshape(n, ncol))
    if wk[off] == 0.0:
        return _SINGULAR
    v = wk[ic[WV]:ic[WV] + ncol]
    o = _put(v, 0, st[ic[SZ]:ic[SZ] + n])
    o = _put(v, o, u0)
    if not ic[FZERO]:
        o = _put(v, o, F0)
    o = _put(v, o, st[ic[SYT]:ic[SYT] + p])
    o = _put(v, o, u_end)
    if not ic[FZERO]:
        o = _put(v, o, F1)
    _put(v, o, y)
    z = nx[ic[SZ]:ic[SZ] + n]
    matvec(wk[off + 1:off + size].reshape(n, ncol), v, z)
    ytil = nx[ic[SYT]:ic[SYT] + p]
    matvec(_mat(c, ic, CC, p, n), z, ytil)
    for i in range(p):
        ytil[i] = y[i] - ytil[i]
    wr = ic[WR]
    for i in range(p):
        b = ic[PER_OUT] + OUT_WIDTH * i
        if ic[b] != 0:
            if red.update(c, ic[b + 3], st, ic[b + 4], nx, ic[b + 4], h, ytil[i:i + 1],
                          wk, wr) != 0:
                return _NON_FINITE
    om1 = nx[ic[SOM1]:ic[SOM1] + r]
    vbar = wk[ic[WVB]:ic[WVB] + p]
    _gather(nx, c, ic, ytil, om1, vbar)
    om2 = nx[ic[SOM2]:ic[SOM2] + nz]
    if nz:
        w = nz + 2 * r
        zz = wk[wr:wr + w]
        zz[:nz] = st[ic[SOM2]:ic[SOM2] + nz]
        zz[nz:nz + r] = st[ic[SOM1]:ic[SOM1] + r]
        zz[nz + r:] = om1
        exact_step(_mat(c, ic, CA22, nz, nz), _mat(c, ic, CA21, nz, r), zz, h, wk, ic[WZ],
                   ic[ZSLOTS], om2, wk[wr + w:wr + 2 * w])
    F = nx[ic[SF]:ic[SF] + n]
    if ic[FOH] or not ic[FHASU]:
        F[:] = F1
    else:
        models[0](st, y, u, F)
    nx[ic[SY]:ic[SY] + p] = y
    nx[ic[SU]:ic[SU] + m] = u
    ok = _finish(nx, c, ic, wk, z, om1, vbar, om2)
    if not (ok and finite(z) and finite(om2) and finite(F)):
        return _NON_FINITE
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, b, y, u, models)
    if op == J.FIRST:
        return _first(st, nx, c, ic, wk, y, u, models)
    if op == J.RESTART:
        return _restart(st, ic, y, a > 0.0)
    return 0
