"""Per-sample kernel of the Luenberger observer (protocol: observers/kernel.py).

    x_hat' = (A - L C) x_hat + [B | I | L] w,   w = [u; F(y, u); y]

integrated exactly with w first-order held between samples (u held unless input_hold is
foh): one cached [Phi | G0 | G1] per step size (core/exact_step.py), one product per step.

A restart without an explicit initial estimate starts (``initial_state: measurement``) from
the state consistent with the first sample, x = C^+ y (the least-squares, minimum-norm
solution of C x = y: the measured states, zero for the rest), else from zero.

State:   header | x (n) | y of the last sample (p) | u of the last sample (m) | 1 when the
         next first sample sets x from y, else 0
Consts:  header | A - L C (n x n) | [B | I | L] (n x (m + n + p)) | C (p x n) | C^+ (n x p)
Ints:    header | n, p, m, foh, cache base, cache slots, scratch base, from-measurement
Work:    the step cache, then scratch: z = [x, w0, w1] (n + 2w, w = m + n + p), the
         composed-step scratch (n + 2w), the new x (n), y - C x (p)
Models:  [F(y, u)] (n terms)
"""
from __future__ import annotations

import math

from ...core.exact_step import exact_step
from ...core import jit as J
from ...core.jit import jit
from ...core.linalg import finite, matvec, norm
from ...core.reasons import CODE
from ..kernel import C_HEADER, HEADER, IC_HEADER, RESIDUAL

N, P, M, FOH, CACHE, SLOTS, SCRATCH, FROM_Y = range(IC_HEADER, IC_HEADER + 8)
_NON_FINITE_TERM = CODE["non_finite_model_term"]
_NON_FINITE = CODE["non_finite_estimate"]


@jit
def _views(c, ic):
    n, p, m = ic[N], ic[P], ic[M]
    w = m + n + p
    o = C_HEADER
    Acl = c[o:o + n * n].reshape(n, n)
    o += n * n
    Bw = c[o:o + n * w].reshape(n, w)
    o += n * w
    C = c[o:o + p * n].reshape(p, n)
    return Acl, Bw, C


@jit
def _c_pinv(c, ic):
    n, p, m = ic[N], ic[P], ic[M]
    o = C_HEADER + n * n + n * (m + n + p) + p * n
    return c[o:o + n * p].reshape(n, p)


@jit
def _commit_outputs(nx, C, ic, wk, y, u):
    """y and u of this sample into the state, and the output residual |y - C x|."""
    n, p, m = ic[N], ic[P], ic[M]
    x = nx[HEADER:HEADER + n]
    w = m + n + p
    base = ic[SCRATCH] + 2 * (n + 2 * w) + n
    cx = wk[base:base + p]
    r = wk[base + p:base + 2 * p]
    matvec(C, x, cx)
    for i in range(p):
        r[i] = y[i] - cx[i]
    nx[RESIDUAL] = norm(r)
    nx[HEADER + n:HEADER + n + p] = y
    nx[HEADER + n + p:HEADER + n + p + m] = u


@jit
def _restart(st, ic, x0, has_x0):
    n, p, m = ic[N], ic[P], ic[M]
    for i in range(n):
        st[HEADER + i] = x0[i] if has_x0 else 0.0
    st[HEADER + n + p + m] = 0.0 if has_x0 else float(ic[FROM_Y])
    st[RESIDUAL] = math.nan
    return 0


@jit
def _first(nx, c, ic, wk, y, u, models):
    n, p, m = ic[N], ic[P], ic[M]
    Acl, Bw, C = _views(c, ic)
    f = wk[ic[SCRATCH]:ic[SCRATCH] + n]
    if nx[HEADER + n + p + m] > 0.0:           # start from the state consistent with y
        matvec(_c_pinv(c, ic), y, f)
        nx[HEADER:HEADER + n] = f
        nx[HEADER + n + p + m] = 0.0
    # the first sample's model term is the next step's starting point
    if models[0](nx, y, u, f) != 0:
        return _NON_FINITE_TERM
    _commit_outputs(nx, C, ic, wk, y, u)
    return 0


@jit
def _step(st, nx, c, ic, wk, h, y, u, models):
    n, p, m = ic[N], ic[P], ic[M]
    w = m + n + p
    Acl, Bw, C = _views(c, ic)
    base = ic[SCRATCH]
    z = wk[base:base + n + 2 * w]
    scratch = wk[base + n + 2 * w:base + 2 * (n + 2 * w)]
    xn = wk[base + 2 * (n + 2 * w):base + 2 * (n + 2 * w) + n]
    z[:n] = st[HEADER:HEADER + n]
    w0 = z[n:n + w]
    w1 = z[n + w:]
    y0 = st[HEADER + n:HEADER + n + p]
    u0 = st[HEADER + n + p:HEADER + n + p + m]
    u_end = u if ic[FOH] else u0
    # w0 = [u0, F(y0, u0), y0], w1 = [u_end, F(y, u_end), y]
    w0[:m] = u0
    models[0](st, y0, u0, w0[m:m + n])
    w0[m + n:] = y0
    w1[:m] = u_end
    models[0](st, y, u_end, w1[m:m + n])
    w1[m + n:] = y
    exact_step(Acl, Bw, z, h, wk, ic[CACHE], ic[SLOTS], xn, scratch)
    if not finite(xn):
        return _NON_FINITE
    nx[HEADER:HEADER + n] = xn
    _commit_outputs(nx, C, ic, wk, y, u)
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, b, y, u, models)
    if op == J.FIRST:
        return _first(nx, c, ic, wk, y, u, models)
    if op == J.RESTART:
        return _restart(st, ic, y, a > 0.0)
    return 0
