"""The window estimator's per-sample steps compiled (numba, ``core.jit``): the same
recursions and state layouts as :mod:`.steps` (its docstrings derive them), written as loops.

:class:`~.external_torque.WindowEstimator` uses these when numba is on (``core.jit.ENABLED``)
and the numpy steps otherwise; ``test_torque_node.py`` holds them to the numpy steps on a
bag.  The adapter has validated the sample (``steps._check``: finite, bounded, one value per
joint, the nominal period) before it calls them; the model terms' finiteness is checked
here: ``window_step`` returns False for a non-finite term or estimate and leaves ``state``
untouched (the result goes into ``new``, a copy).  ROS-free.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.jit import jit


@jit
def _red_advance(z, f, h, N, r, K, A, out):
    """out <- one step of the differentiator over h with the samples f (rows: joints)."""
    n = z.shape[0]
    for c in range(n):
        e = f[c] - z[c, 0]
        a = max(abs(e), 1e-300)
        w = -math.expm1(-(h * r) * a ** (-1.0 / N))
        for b in range(N):
            s = 0.0
            for k in range(N):
                s += z[c, k] * A[b, k] * h ** k / h ** b
            g = 0.0
            wk = 1.0
            for k in range(N):
                wk *= w
                g += wk * K[b, k]
            out[c, b] = s + g / h ** b * e


@jit
def red_step(state, consts, h, y):
    """:func:`.steps.red_step` (no validation of y: the adapter's)."""
    N = int(consts[0])
    r = consts[1]
    K = consts[2:2 + N * N].reshape(N, N)
    A = consts[2 + N * N:2 + 2 * N * N].reshape(N, N)
    B = consts[2 + 2 * N * N:2 + 3 * N * N].reshape(N, N)
    n = y.size
    z = state[:n * N].reshape(n, N)
    yprev = state[2 * n * N:]
    new = np.empty_like(state)
    z1 = new[:n * N].reshape(n, N)
    _red_advance(z, yprev, h, N, r, K, A, z1)
    tmp = np.empty((n, N))
    _red_advance(z1, y, h, N, r, K, A, tmp)
    post = new[n * N:2 * n * N].reshape(n, N)
    for c in range(n):
        for b in range(N):
            s = 0.0
            for a in range(N):
                s += tmp[c, a] * B[b, a] * h ** a / h ** b
            post[c, b] = s
    new[2 * n * N:] = y
    return new


@jit
def window_central(state, consts, y):
    """(q, v) at sample k - m (:func:`.steps.window_central`); call once state[0] >= 2 m."""
    n, W, m = int(consts[0]), int(consts[1]), int(consts[3])
    slot = 5 * n + 2 * n * n
    head = int(state[1])
    ring = state[2 + n:].reshape(W + 1, slot)
    qc = np.empty(n)
    v = np.zeros(n)
    norm = 0.0
    for r in range(2 * m + 1):
        i = r - m
        norm += i * i
        row = y if r == 2 * m else ring[(head - (2 * m - 1 - r)) % (W + 1), :n]
        for c in range(n):
            v[c] += i * row[c]
            if r == m:
                qc[c] = row[c]
    for c in range(n):
        v[c] /= consts[2] * norm
    return qc, v


@jit
def _finite(a):
    for x in a.ravel():
        if not math.isfinite(x):
            return False
    return True


@jit
def window_step(state, consts, y, u, M, Md, phi, Md_c, phi_c, has_c, new):
    """:func:`.steps.window_step` into ``new`` (a copy of state first); False (``new``
    unusable, ``state`` untouched) for a non-finite model term or estimate."""
    if not (_finite(M) and _finite(Md) and _finite(phi)):
        return False
    if has_c and not (_finite(Md_c) and _finite(phi_c)):
        return False
    n, W, m = int(consts[0]), int(consts[1]), int(consts[3])
    slot = 5 * n + 2 * n * n
    oM, oMq, oMd, oMdq, oph, otau = n, n + n * n, 2 * n + n * n, 2 * n + 2 * n * n, \
        3 * n + 2 * n * n, 4 * n + 2 * n * n
    new[:] = state
    count, head = int(state[0]) + 1, (int(state[1]) + 1) % (W + 1)
    ring = new[2 + n:].reshape(W + 1, slot)
    cell = ring[head]
    for i in range(n):
        cell[i] = y[i]
        s = 0.0
        sd = 0.0
        for k in range(n):
            cell[oM + i * n + k] = M[i, k]
            cell[oMd + i * n + k] = Md[i, k]
            s += M[i, k] * y[k]
            sd += Md[i, k] * y[k]
        cell[oMq + i] = s
        cell[oMdq + i] = sd
        cell[oph + i] = phi[i]
        cell[otau + i] = u[i]
    if has_c:
        old = ring[(head - m) % (W + 1)]
        for i in range(n):
            sd = 0.0
            for k in range(n):
                old[oMd + i * n + k] = Md_c[i, k]
                sd += Md_c[i, k] * old[k]
            old[oMdq + i] = sd
            old[oph + i] = phi_c[i]
    new[0], new[1] = min(count, W + 1), head
    if count < W + 1:
        return True
    visc = consts[4:4 + n]
    off = 4 + n
    a = consts[off:off + W + 1]
    b = consts[off + W + 1:off + 2 * (W + 1)]
    c = consts[off + 2 * (W + 1):off + 3 * (W + 1)]
    d = consts[off + 3 * (W + 1):off + 3 * (W + 1) + W]
    est = new[2:2 + n]
    est[:] = 0.0
    for j in range(W + 1):
        R = ring[(head - j) % (W + 1)]
        for i in range(n):
            mq = 0.0
            mdq = 0.0
            for k in range(n):
                mq += R[oM + i * n + k] * y[k]
                mdq += R[oMd + i * n + k] * y[k]
            e = a[j] * (R[oMq + i] - mq) - b[j] * (R[oMdq + i] - mdq) \
                + visc[i] * b[j] * (R[i] - y[i]) - c[j] * R[oph + i]
            if j >= 1:
                e -= d[j - 1] * R[otau + i]
            est[i] += e
    return _finite(est)
