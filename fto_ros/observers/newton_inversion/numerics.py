"""The newton_inversion kernel's numerics (compiled, core/jit.py): the backward-Euler step of
the finite-time flow, the small linear solves, cond(J), the Remark-6 filter's step.

Each is the arithmetic of the previous Python code in the same order (scalar libm math,
the closed-form solves for n <= 3, BLAS products where numpy made them), so the kernel
reproduces it bit for bit; the exceptions are said where they are.  No allocation on the
paths a regular sample takes (n <= 3): scratch comes from the kernel's work memory.
"""
from __future__ import annotations

import math

import numpy as np

from ...core.exact_step import stacked
from ...core.jit import jit
from ...core.linalg import solve as gauss_solve


@jit
def _radius(a, tau):
    """(|(a - tau)_+|_2, sum (a - tau)_+)."""
    s = 0.0
    s1 = 0.0
    for i in range(a.shape[0]):
        d = a[i] - tau
        if d > 0.0:
            s += d * d
            s1 += d
    return math.sqrt(s), s1


@jit
def implicit_flow(e, c, alpha, out, a):
    """out = the backward-Euler step of e' = -mu |e|_2^alpha sign(e) (entry-wise sign),
    c = h mu: e+ = sign(e) max(|e| - tau, 0) with tau = c |e+|_2^alpha, the unique root of
    the increasing phi(tau) = tau - c R(tau)^alpha, R(tau) = |(|e| - tau)_+|_2, on
    [0, min(c |e|^alpha, max|e|)] (safeguarded Newton).  ``a``: scratch (len(e))."""
    n = e.shape[0]
    amax = 0.0
    for i in range(n):
        a[i] = abs(e[i])
        if i == 0 or a[i] > amax:
            amax = a[i]
    if amax == 0.0:
        out[:] = 0.0
        return
    r0 = _radius(a, 0.0)[0]
    hi = min(c * r0 ** alpha, amax)
    # root within 1e-12 of amax: e+ is zero to 1e-12 relative, return it exactly
    t_test = amax * (1.0 - 1e-12)
    if t_test - c * _radius(a, t_test)[0] ** alpha <= 0.0:
        out[:] = 0.0
        return
    hi = min(hi, t_test)
    lo = 0.0
    tau = hi
    for _ in range(60):
        r, s1 = _radius(a, tau)
        if r <= 0.0:
            phi, dphi = tau, math.inf
        else:
            phi = tau - c * r ** alpha
            dphi = 1.0 + c * alpha * r ** (alpha - 2.0) * s1
        if phi > 0.0:
            hi = tau
        else:
            lo = tau
        if abs(phi) <= 1e-15 * max(tau, 1e-300) or hi - lo <= 1e-15 * hi:
            break
        nxt = tau - phi / dphi if dphi < math.inf else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        tau = nxt
    for i in range(n):
        out[i] = math.copysign(max(a[i] - tau, 0.0), e[i])


def _cond_np(M, W):
    return float(np.linalg.cond(M))


@jit(pure=_cond_np)
def cond2(M, W):
    """The 2-norm condition number of the square M (numpy's np.linalg.cond without numba;
    compiled: one-sided Jacobi on W, a scratch copy, singular values to a few ulps of
    LAPACK's, so the figure agrees to ~1e-15 relative); inf when M is singular, nan when
    not finite."""
    n = M.shape[0]
    W[:, :] = M
    for _ in range(60):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                al = 0.0
                be = 0.0
                ga = 0.0
                for i in range(n):
                    al += W[i, p] * W[i, p]
                    be += W[i, q] * W[i, q]
                    ga += W[i, p] * W[i, q]
                if not abs(ga) > 1e-15 * math.sqrt(al * be):
                    continue
                rotated = True
                zeta = (be - al) / (2.0 * ga)
                t = math.copysign(1.0, zeta) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                cs = 1.0 / math.sqrt(1.0 + t * t)
                sn = cs * t
                for i in range(n):
                    wp = W[i, p]
                    W[i, p] = cs * wp - sn * W[i, q]
                    W[i, q] = sn * wp + cs * W[i, q]
        if not rotated:
            break
    smax = 0.0
    smin = math.inf
    for j in range(n):
        s = 0.0
        for i in range(n):
            s += W[i, j] * W[i, j]
        s = math.sqrt(s)
        if s != s:
            return math.nan
        smax = max(smax, s)
        smin = min(smin, s)
    return smax / smin if smin > 0.0 else math.inf


@jit
def solve(J, b, n, out, W):
    """out = J^-1 b (J row-major n x n in a flat array); closed form for n <= 3, Gaussian
    elimination otherwise (numpy's solve without numba; it allocates: n > 3 only); False
    where singular (|det| <= 1e-13 of its scale, or cond > 1e13 for n > 3).  W: n x n
    scratch."""
    if n == 1:
        d = J[0]
        if d == 0.0:
            return False
        out[0] = b[0] / d
        return True
    if n == 2:
        a, bb, c, d = J[0], J[1], J[2], J[3]
        det = a * d - bb * c
        scale = (abs(a) + abs(bb)) * (abs(c) + abs(d))
        if not abs(det) > 1e-13 * scale:
            return False
        out[0] = (d * b[0] - bb * b[1]) / det
        out[1] = (a * b[1] - c * b[0]) / det
        return True
    if n == 3:
        a, bb, c, d, e, f, g, hh, i = J[0], J[1], J[2], J[3], J[4], J[5], J[6], J[7], J[8]
        A = e * i - f * hh
        B = f * g - d * i
        C = d * hh - e * g
        det = a * A + bb * B + c * C
        scale = ((abs(a) + abs(bb) + abs(c)) * (abs(d) + abs(e) + abs(f))
                 * (abs(g) + abs(hh) + abs(i)))
        if not abs(det) > 1e-13 * scale:
            return False
        y0, y1, y2 = b[0], b[1], b[2]
        out[0] = (A * y0 + (c * hh - bb * i) * y1 + (bb * f - c * e) * y2) / det
        out[1] = (B * y0 + (a * i - c * g) * y1 + (c * d - a * f) * y2) / det
        out[2] = (C * y0 + (bb * g - a * hh) * y1 + (a * e - bb * d) * y2) / det
        return True
    M = J[:n * n].reshape(n, n)
    if cond2(M, W) > 1e13:
        return False
    return gauss_solve(M, b, out)


@jit
def filter_step(Af, Bf, Cf, D, X, w0, w1, h, wk, base, slots, Xn, out, P, T):
    """The Remark-6 filter Q(s) (controllable canonical form, state X (k x ch)) over h with
    its inputs linear from w0 to w1 (ch): Xn, and its output at the new sample into out.
    The previous code's products (BLAS gemm through np.dot, on contiguous copies) and
    sums in its order.  P (k x k), T (k x ch): scratch."""
    k = Af.shape[0]
    ch = w1.shape[0]
    if k == 0:
        for j in range(ch):
            out[j] = D * w1[j]
        return
    S = stacked(Af, Bf, h, wk, base, slots)          # [Phi | G0 | G1]
    P[:, :] = S[:, :k]
    np.dot(P, X, T)
    for i in range(k):
        g0 = S[i, k]
        g1 = S[i, k + 1]
        for j in range(ch):
            Xn[i, j] = T[i, j] + g0 * w0[j] + g1 * w1[j]
    filter_output(Cf, D, Xn, w1, out)


@jit
def filter_output(Cf, D, X, w, out):
    """out = C X + D w: the filter's output for its state X and input w (C: 1 x k)."""
    ch = w.shape[0]
    np.dot(Cf, X, out.reshape(1, ch))
    for j in range(ch):
        out[j] = out[j] + D * w[j]
