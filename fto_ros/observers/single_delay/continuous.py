"""Per-sample kernel of the continuous-measurement single-delay observer (Theorem 1;
protocol: observers/kernel.py, layout: kernel.py).

Between samples the extension z' = Az z + Bz w is stepped exactly, w = [F1, F2, Y] linear
from the last sample's to this one's (u held unless input_hold is foh).  One cached matrix
per step size, K(h) = [S(h); Mo [S(h); 0 0 I]] with S(h) = [Phi | G0 | G1], gives from
[z; w0; w1] in one product the new z, the delayed combination dl, its derivative and
Me z + R Y (the fused step).  A step longer than tau / FILL_POINTS fills the ring with at
most FILL_POINTS exact intermediate points over the last tau (w linear over the gap).

Work (after the ring): the fused-step cache, then the scratch (after kernel.py's part):
[z, w0, w1] (N + 2W), the product (N + 3 n1), w1 (W), w at the new input (W), dl (n1),
A2 xi_e (q), the residual (q).
"""
from __future__ import annotations

import math

import numpy as np

from ...core import jit as J
from ...core.discretize import foh_matrices
from ...core.jit import jit, numba
from ...core.linalg import finite, norm
from ...core.step_cache import cache_claim, cache_find, cache_floats
from .. import kernel as K
from . import kernel as SD
from .kernel import (C_A, C_A2, C_B, C_MO, FILL_STEP, FOH, K_, M, N1, NON_FINITE,
                     NON_FINITE_TERM, Q, S_T, S_U, S_W, S_XI, S_Y, S_Z, TAU, W_CACHE, W_SCRATCH,
                     W_SLOTS, mat, model_w, mv)

#: a step longer than tau / FILL_POINTS fills the delay ring with at most this many exact
#: intermediate points over the last tau (bounded work per sample, whatever the gap)
FILL_POINTS = 16
#: pushes onto the ring in one sample at most: the fill points and the sample's own
PUSHES = FILL_POINTS + 1
SLOTS = 256


def fused_shape(n1: int, q: int) -> tuple[int, int]:
    N, W = 3 * n1 + q, n1 + 2 * q
    return N + 3 * n1, N + 2 * W


def cache_size(n1: int, q: int) -> int:
    rows, cols = fused_shape(n1, q)
    return cache_floats(SLOTS, rows * cols)


def scratch_floats(n1: int, q: int, m: int) -> int:
    N, W = 3 * n1 + q, n1 + 2 * q
    return (N + 2 * W) + (N + 3 * n1) + 2 * W + n1 + 2 * q


@jit
def _scratch(wk, ic):
    n1, q, m = ic[N1], ic[Q], ic[M]
    N = 3 * n1 + q
    W = n1 + 2 * q
    o = ic[W_SCRATCH] + SD.common_scratch(n1, q, m)
    vec = wk[o:o + N + 2 * W]
    o += N + 2 * W
    out = wk[o:o + N + 3 * n1]
    o += N + 3 * n1
    w1 = wk[o:o + W]
    wn = wk[o + W:o + 2 * W]
    o += 2 * W
    dl = wk[o:o + n1]
    pr = wk[o + n1:o + n1 + q]
    r = wk[o + n1 + q:o + n1 + 2 * q]
    return vec, out, w1, wn, dl, pr, r


def _fused_np(Az, Bz, Mo, h):
    """K(h): the exact step S(h) = [Phi | G0 | G1] stacked on Mo [S(h); 0 0 I] (numpy and
    scipy, built once per step size)."""
    S_h = np.hstack(foh_matrices(Az, Bz, h))
    N, W = S_h.shape[0], Bz.shape[1]
    z_w1 = np.zeros((N + W, N + 2 * W))
    z_w1[:N] = S_h
    z_w1[N:, N + W:] = np.eye(W)
    return np.ascontiguousarray(np.vstack([S_h, Mo @ z_w1]))


def _fused_jit(Az, Bz, Mo, h):
    with numba.objmode(out="float64[:, ::1]"):
        out = _fused_np(Az, Bz, Mo, h)
    return out


#: built by the numpy code itself (numba's object mode): the cached matrices, and so every
#: step, are bit for bit those of the numpy path
fused_matrix = _fused_np if not J.ENABLED else jit(_fused_jit, gil=True)


@jit
def _fused(c, ic, wk, h):
    """The cached K(h) (keyed by h in integer ns, FIFO, as the steps' cache)."""
    n1, q = ic[N1], ic[Q]
    N = 3 * n1 + q
    W = n1 + 2 * q
    rows = N + 3 * n1
    cols = N + 2 * W
    size = rows * cols
    key = float(round(h * 1e9))
    off = cache_find(wk, ic[W_CACHE], ic[W_SLOTS], size, key)
    if off < 0:
        off = cache_claim(wk, ic[W_CACHE], ic[W_SLOTS], size, key)
        Kh = fused_matrix(mat(c, ic[C_A], N, N), mat(c, ic[C_B], N, W),
                          mat(c, ic[C_MO], 3 * n1, N + W), key * 1e-9)
        wk[off:off + size] = Kh.reshape(size)
    return wk[off:off + size].reshape(rows, cols)


@jit
def _fill(st, nx, c, ic, wk, vec, out, w1, k0, k1):
    """Step z = vec[:N] exactly from quanta k0 towards k1, pushing dl at points at most
    the fill step apart over [k1 - tau, k1) (earlier ones would be trimmed at once), with w
    linear from vec's w0 (at k0) to w1 (at k1); leaves vec = [z, w, w1] at the last point.
    At most FILL_POINTS steps, whatever the gap.  The last point's quanta, or -1 if a value
    is not finite."""
    n1, q = ic[N1], ic[Q]
    N = 3 * n1 + q
    W = n1 + 2 * q
    a = max(k0, k1 - K.quanta(c[TAU]))
    span = k1 - a
    m = min(max(1, math.ceil(span * K.STEP_QUANTUM / c[FILL_STEP])), FILL_POINTS, span)
    lead = a > k0
    points = m - 1 + (1 if lead else 0)
    for i in range(points):
        j = i if lead else i + 1
        p = a if j == 0 else a + round(j * span / m)
        frac = (p - k0) / (k1 - k0)
        for e in range(W):
            vec[N + W + e] = vec[N + e] + (w1[e] - vec[N + e]) * frac
        mv(_fused(c, ic, wk, (p - k0) * K.STEP_QUANTUM), vec, out)
        if not finite(out):
            return -1
        SD.push_entry(st, nx, c, ic, wk, p * K.STEP_QUANTUM, out[N:N + n1], out[N + n1:N + 2 * n1])
        vec[:N] = out[:N]
        vec[N:N + W] = vec[N + W:]
        k0 = p
    vec[N + W:] = w1
    return k0


@jit
def _step(st, nx, c, ic, wk, s, h, y, u, models):
    n1, q, m = ic[N1], ic[Q], ic[M]
    N = 3 * n1 + q
    W = n1 + 2 * q
    vec, out, w1, wn, dl, pr, r = _scratch(wk, ic)
    u_prev = st[ic[S_U]:ic[S_U] + m]
    u_end = u if ic[FOH] else u_prev
    if model_w(models, st, y, u_end, w1, q) != 0:
        return NON_FINITE_TERM
    w_prev = st[ic[S_W]:ic[S_W] + W]
    vec[:N] = st[ic[S_Z]:ic[S_Z] + N]
    vec[N:N + W] = w_prev
    vec[N + W:] = w1
    h_last = h
    if h > c[FILL_STEP]:
        # a gap: the reads at s' - tau for the next tau fall inside it, so fill the ring
        # there with exact intermediate states instead of one Hermite segment across it
        k1 = K.quanta(s)
        k0 = _fill(st, nx, c, ic, wk, vec, out, w1, K.quanta(st[ic[S_T]]), k1)
        if k0 < 0:
            return NON_FINITE
        h_last = (k1 - k0) * K.STEP_QUANTUM
    mv(_fused(c, ic, wk, h_last), vec, out)
    xi = nx[ic[S_XI]:ic[S_XI] + n1]
    conv = SD.converged(c, s)
    if conv:
        SD.delayed(nx, c, ic, wk, s, dl)
        for i in range(n1):
            xi[i] = out[N + 2 * n1 + i] + dl[i]
    else:
        xi[:] = out[:n1]
    # a NaN or Inf anywhere in z or w reaches out (0 * nan is nan): one check covers all
    if not finite(out):
        return NON_FINITE
    w_next = w1
    if not ic[FOH] and not SD.same(u, u_prev):
        if model_w(models, st, y, u, wn, q) != 0:
            return NON_FINITE_TERM
        w_next = wn
    # one-step prediction of Y from the previous estimate: the residual
    k = c[K_]
    ek = math.exp(-k * h)
    mv(mat(c, ic[C_A2], q, n1), st[ic[S_XI]:ic[S_XI] + n1], pr)
    y_prev = st[ic[S_Y]:ic[S_Y] + q]
    for i in range(q):
        r[i] = y[i] - (ek * y_prev[i] + (1 - ek) / k * (pr[i] + w_prev[n1 + i]))
    nx[K.RESIDUAL] = norm(r)
    SD.push_entry(st, nx, c, ic, wk, s, out[N:N + n1], out[N + n1:N + 2 * n1])
    SD.trim(nx, ic)
    nx[ic[S_W]:ic[S_W] + W] = w_next
    nx[ic[S_Z]:ic[S_Z] + N] = out[:N]
    nx[ic[S_T]] = s
    nx[ic[S_Y]:ic[S_Y] + q] = y
    nx[ic[S_U]:ic[S_U] + m] = u
    nx[K.HEALTH] = norm(dl) if conv else 0.0
    SD.publish(nx, c, ic, wk, y)
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, a, b, y, u, models)
    if op == J.FIRST:
        return SD.first(st, nx, c, ic, wk, y, u, models)
    if op == J.RESTART:
        return SD.restart(st, c, ic, y, a > 0.0)
    return 0
