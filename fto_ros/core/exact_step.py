"""Exact sampled-data steps of ``x' = A x + B w(t)`` inside a kernel.

Between two samples w is linear from w0 to w1 (FOH; w1 = w0 holds it): one matrix
exponential of the augmented matrix (Van Loan) gives ``[Phi | G0 | G1]`` with
``x(t + h) = Phi x + G0 w0 + G1 w1``, exact for any h; the stacked matrix is cached per
step size in the kernel's work array (core/step_cache.py), so a fixed-rate stream costs one
exponential in all and a step is one matrix-vector product.  Once a stream has shown
COMPOSE_AFTER different step sizes, a new size on the 1 us grid is composed of cached
power-of-two steps (the same linear input interpolated at the joints) instead of a new
exponential: at most ~21 sizes per second of step length.
"""
from __future__ import annotations

import math

import numpy as np

from .discretize import COMPOSE_AFTER, STEP_QUANTUM
from .jit import jit
from .linalg import expm_exact, matvec
from .step_cache import cache_claim, cache_find, cache_misses


@jit
def foh_stacked(A, B, h, out):
    """out (n x (n + 2m)) = [Phi | G0 | G1] of the FOH step of length h."""
    n, m = B.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    for i in range(n):
        for j in range(n):
            M[i, j] = A[i, j] * h
        for j in range(m):
            M[i, n + j] = B[i, j] * h
    for j in range(m):
        M[n + j, n + m + j] = 1.0
    E = expm_exact(M)
    for i in range(n):
        for j in range(n):
            out[i, j] = E[i, j]
        for j in range(m):
            g1 = E[i, n + m + j]
            out[i, n + j] = E[i, n + j] - g1
            out[i, n + m + j] = g1


@jit
def stacked(A, B, h, wk, base, slots):
    """The cached [Phi | G0 | G1] of step h as an (n, n + 2m) view into wk."""
    n, m = B.shape
    size = n * (n + 2 * m)
    key = float(round(h * 1e9))
    off = cache_find(wk, base, slots, size, key)
    if off < 0:
        off = cache_claim(wk, base, slots, size, key)
        foh_stacked(A, B, key * 1e-9, wk[off:off + size].reshape(n, n + 2 * m))
    return wk[off:off + size].reshape(n, n + 2 * m)


@jit
def exact_step(A, B, z, h, wk, base, slots, out, scratch):
    """out = x after h with w linear from w0 to w1, z = [x, w0, w1] (n + 2m; out must not
    alias z; scratch: n + 2m floats for the composed steps)."""
    n, m = B.shape
    size = n * (n + 2 * m)
    key = float(round(h * 1e9))
    q = round(h / STEP_QUANTUM)
    if cache_find(wk, base, slots, size, key) >= 0 or cache_misses(wk, base) < COMPOSE_AFTER \
            or q <= 0 or abs(q * STEP_QUANTUM - h) > 1e-12:
        matvec(stacked(A, B, h, wk, base, slots), z, out)
        return
    # z' = [x_a, w_a, w_b] for each power-of-two piece
    scratch[:] = z
    w0 = z[n:n + m]
    w1 = z[n + m:]
    done = 0
    bits = 0
    while (q >> bits) > 1:
        bits += 1
    for bit in range(bits, -1, -1):
        d = 1 << bit
        if not q & d:
            continue
        if done + d == q:
            scratch[n + m:] = w1
        else:
            frac = (done + d) / q
            for j in range(m):
                scratch[n + m + j] = w0[j] + (w1[j] - w0[j]) * frac
        matvec(stacked(A, B, d * STEP_QUANTUM, wk, base, slots), scratch, out)
        scratch[:n] = out
        scratch[n:n + m] = scratch[n + m:]
        done += d
