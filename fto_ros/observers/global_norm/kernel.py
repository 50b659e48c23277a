"""Per-sample kernel of the global observer with a state-norm estimator (protocol:
observers/kernel.py; the method: the adapter's module docstring).

One step of h: y between the samples (output_polynomial), the norm estimator w exactly
(gamma_1 linear), the gains frozen at w(mid-step), e^(A h) of the frozen error matrix
afresh (companion.py: closed form for two states), then the exact linear step with the
model term as a predictor-corrector pair (Heun), the model term saturated at gamma_hat.

State:   header | w, y, has y_prev, y_prev, h_prev, gamma_1(y), gamma_hat, saturation
         active, saturated steps, steps | x_hat (m) | k(w) (dim) | u held over the step (n_u) |
         the published estimate T^-1 x_hat (m; only with a state map)
Consts:  header | w0 | T (m x m), T^-1 (m x m): the observer runs on z = T x (the plant's
         observability form, observers/chain_map.py; identity without a map)
Ints:    header | m, dim (m, or m - 1 in the reduced form), n_u, reduced, quadratic hold,
         scratch base, state map (0/1)
Work:    scratch: the gains at w(mid) and w(end) (1 + m + dim each), e^(A h) (dim^2), its
         work (2 dim^2), G, x_s, r0, r1, r2, x_p, x (dim each), the model's x (m - 1), the
         step's work (5 dim), two cells, the complex work (2 dim complex = 4 dim floats)
Models:  [gamma_hat(w), a_0..a_n(w), k(w) | f(y, x_1..x_n, u) | gamma_1(y)]

Where the Python code this replaced raised (math's overflow), the compiled code gets
infinities: a non-finite e^(A h) is rejected as the exception was (non_finite_estimate), a
non-finite gain at the first sample as non_finite_gain.
"""
from __future__ import annotations

import math

import numpy as np

from ...core import jit as J
from ...core.jit import jit
from ...core.linalg import matvec
from ...core.reasons import CODE
from ..kernel import C_HEADER, HEADER, HEALTH, IC_HEADER, RESIDUAL
from .companion import companion_expm, companion_step, gain_forcing, norm_estimator_step, output_polynomial

M, DIM, NIN, REDUCED, QUAD, SCRATCH, MAPPED = range(IC_HEADER, IC_HEADER + 7)
W0 = C_HEADER
T_MAP = C_HEADER + 1
(W, Y, HAS_YPREV, YPREV, HPREV, G1, GH, SAT_ACTIVE, SAT_COUNT, STEPS) = range(HEADER, HEADER + 10)
X_HAT = HEADER + 10
GAINS, F, GAMMA_1 = 0, 1, 2

_NON_FINITE = CODE["non_finite_estimate"]
_NON_FINITE_GAIN = CODE["non_finite_gain"]
_NON_FINITE_TERM = CODE["non_finite_model_term"]
_NON_FINITE_GAMMA_1 = CODE["non_finite_gamma_1"]


def state_size(m: int, dim: int, nin: int) -> int:
    return X_HAT + 2 * m + dim + nin


def published(m: int, dim: int, nin: int) -> int:
    """Where the published estimate is with a state map."""
    return X_HAT + m + dim + nin


@jit
def _publish(s, c, ic):
    """The published estimate T^-1 x_hat (with a state map; else x_hat is published)."""
    m = ic[M]
    if ic[MAPPED]:
        o = X_HAT + m + ic[DIM] + ic[NIN]
        matvec(c[T_MAP + m * m:T_MAP + 2 * m * m].reshape(m, m), s[X_HAT:X_HAT + m], s[o:o + m])


def scratch_size(m: int, dim: int) -> int:
    return 2 * (1 + m + dim) + 3 * dim * dim + 7 * dim + (m - 1) + 5 * dim + 2 + 4 * dim


@jit
def _k(s, ic):
    o = X_HAT + ic[M]
    return s[o:o + ic[DIM]]


@jit
def _u(s, ic):
    o = X_HAT + ic[M] + ic[DIM]
    return s[o:o + ic[NIN]]


@jit
def _scratch(ic, wk, k):
    """0, 1 the gains at w(mid), w(end); 2 e^(A h) (flat); 3 its work; 4 G, 5 x_s, 6 r0, 7 r1,
    8 r2, 9 x_p, 10 x; 11 the model's x; 12 the step's work; 13 a cell (the model's y or
    w); 14 a cell (a model's value); 15 the complex work (as floats)."""
    m, dim = ic[M], ic[DIM]
    ng = 1 + m + dim
    sizes = (ng, ng, dim * dim, 2 * dim * dim, dim, dim, dim, dim, dim, dim, dim, m - 1,
             5 * dim, 1, 1, 4 * dim)
    o = ic[SCRATCH]
    for i in range(k):
        o += sizes[i]
    return wk[o:o + sizes[k]]


@jit
def _model(models, ic, wk, y, xbar, u, gh):
    """f(y, xbar, u) saturated at +-gh: (value, saturated, 0) or (nan, False, rejection)."""
    cell = _scratch(ic, wk, 13)
    out = _scratch(ic, wk, 14)
    cell[0] = y
    models[F](xbar, cell, u, out)
    fv = out[0]
    if fv != fv:
        return fv, False, _NON_FINITE_TERM
    if fv > gh:
        return gh, True, 0
    if fv < -gh:
        return -gh, True, 0
    return fv, False, 0


@jit
def _gains(models, ic, wk, w, out):
    """gamma_hat, a, k at w into out; whether all are finite."""
    cell = _scratch(ic, wk, 13)
    cell[0] = w
    return models[GAINS](cell, cell[:0], cell[:0], out) == 0


@jit
def _gamma_1(models, ic, wk, y):
    cell = _scratch(ic, wk, 13)
    out = _scratch(ic, wk, 14)
    cell[0] = y
    models[GAMMA_1](cell[:0], cell, cell[:0], out)
    return out[0]


@jit
def _step(st, nx, c, ic, wk, h, y, u, models):
    m, dim = ic[M], ic[DIM]
    reduced = ic[REDUCED] != 0
    yk = y[0]
    y0 = st[Y]
    ya, yb, yc = output_polynomial(st[HAS_YPREV] > 0.0, st[YPREV], st[HPREV], y0, yk, h,
                                   ic[QUAD] != 0)
    g1a = st[G1]
    g1b = _gamma_1(models, ic, wk, yk)
    if not math.isfinite(g1b):
        return _NON_FINITE_GAMMA_1
    w0 = st[W]
    w1 = norm_estimator_step(w0, g1a, g1b, h)
    wm = 0.5 * (w0 + w1)
    gh0 = st[GH]
    gm = _scratch(ic, wk, 0)
    ge = _scratch(ic, wk, 1)
    _gains(models, ic, wk, wm, gm)
    _gains(models, ic, wk, w1, ge)
    k = gm[1 + m:1 + m + dim]
    gh1 = ge[0]
    E = _scratch(ic, wk, 2).reshape(dim, dim)
    companion_expm(k, h, E, _scratch(ic, wk, 3), _scratch(ic, wk, 15).view(np.complex128))
    for i in range(dim):
        for j in range(dim):
            if not math.isfinite(E[i, j]):
                return _NON_FINITE             # where math raised its overflow before
    xhat = st[X_HAT:X_HAT + m]
    xbar0 = xhat[1:]
    G = _scratch(ic, wk, 4)
    xs = _scratch(ic, wk, 5)
    if reduced:
        # eq. (83) in chi = xh + k y, re-based at every step with the frozen k = k(w_mid):
        # within a frozen-gain step k_dot = 0, and the change of k between steps is carried
        # exactly by the re-basing (no k_dot, no cancellation between chi and k y)
        for i in range(dim):
            G[i] = -(k[i + 1] if i + 1 < dim else 0.0) - k[i] * k[0]
            xs[i] = xbar0[i] + k[i] * y0
    else:
        for i in range(dim):
            G[i] = -k[i]
        xs[:] = xhat
    uh = _u(st, ic)
    v0, _, code = _model(models, ic, wk, y0, xbar0, uh, gh0)
    if code != 0:
        return code
    r0 = _scratch(ic, wk, 6)
    r1 = _scratch(ic, wk, 7)
    r2 = _scratch(ic, wk, 8)
    gain_forcing(G, ya, yb, yc, v0, r0, r1, r2)
    xp = _scratch(ic, wk, 9)
    work = _scratch(ic, wk, 12)
    companion_step(k, E, xs, h, r0, r1, r2, xp, work)
    xbar1 = _scratch(ic, wk, 11)
    if reduced:
        for i in range(dim):
            xbar1[i] = xp[i] - k[i] * yk
    else:
        xbar1[:] = xp[1:]
    v1, _, code = _model(models, ic, wk, yk, xbar1, uh, gh1)
    if code != 0:
        return code
    r1[dim - 1] += (v1 - v0) / h
    x = _scratch(ic, wk, 10)
    companion_step(k, E, xs, h, r0, r1, r2, x, work)
    xn = nx[X_HAT:X_HAT + m]
    if reduced:
        xn[0] = yk
        for i in range(dim):
            xn[i + 1] = x[i] - k[i] * yk
        resid = 0.0
    else:
        xn[:] = x
        resid = abs(yk - x[0])
    _, sat, code = _model(models, ic, wk, yk, xn[1:], uh, gh1)
    if code != 0:
        return code
    for i in range(m):
        if not math.isfinite(xn[i]):
            return _NON_FINITE
    if not math.isfinite(w1):
        return _NON_FINITE
    nx[W] = w1
    nx[G1] = g1b
    nx[GH] = gh1
    nx[HEALTH] = gh1
    _k(nx, ic)[:] = ge[1 + m:1 + m + dim]
    nx[SAT_ACTIVE] = 1.0 if sat else 0.0
    nx[SAT_COUNT] += 1.0 if sat else 0.0
    nx[STEPS] += 1.0
    nx[YPREV] = y0
    nx[HPREV] = h
    nx[HAS_YPREV] = 1.0
    nx[Y] = yk
    nx[RESIDUAL] = resid
    _u(nx, ic)[:] = u
    _publish(nx, c, ic)
    return 0


@jit
def _first(nx, c, ic, wk, y, u, models):
    m, dim = ic[M], ic[DIM]
    yk = y[0]
    g = _scratch(ic, wk, 0)
    if not _gains(models, ic, wk, nx[W], g):
        return _NON_FINITE_GAIN
    if ic[REDUCED]:
        nx[X_HAT] = yk
    nx[Y] = yk
    nx[G1] = _gamma_1(models, ic, wk, yk)
    nx[GH] = g[0]
    nx[HEALTH] = g[0]
    _k(nx, ic)[:] = g[1 + m:1 + m + dim]
    nx[RESIDUAL] = abs(yk - nx[X_HAT])
    _u(nx, ic)[:] = u
    _publish(nx, c, ic)
    return 0


@jit
def _restart(st, c, ic, wk, x0, has_x0, models):
    """Forget the run: x_hat from x0 (plant coordinates: T x0 with a state map; else 0),
    w = w0; gamma_hat and k at w0 (what the observer reports before its first sample)."""
    m, dim = ic[M], ic[DIM]
    if has_x0 and ic[MAPPED]:
        matvec(c[T_MAP:T_MAP + m * m].reshape(m, m), x0, st[X_HAT:X_HAT + m])
    else:
        for i in range(m):
            st[X_HAT + i] = x0[i] if has_x0 else 0.0
    st[W] = c[W0]
    st[HAS_YPREV] = 0.0
    st[SAT_COUNT] = 0.0
    st[STEPS] = 0.0
    g = _scratch(ic, wk, 0)
    _gains(models, ic, wk, c[W0], g)
    st[GH] = g[0]
    st[HEALTH] = g[0]
    _k(st, ic)[:] = g[1 + m:1 + m + dim]
    _publish(st, c, ic)
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, b, y, u, models)
    if op == J.FIRST:
        return _first(nx, c, ic, wk, y, u, models)
    if op == J.RESTART:
        return _restart(st, c, ic, wk, y, a > 0.0, models)
    return 0


if not J.ENABLED:
    _kernel = kernel

    def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):  # noqa: F811
        """The numpy path: Python's math raises where compiled code gets infinities."""
        try:
            return _kernel(op, st, nx, c, ic, wk, a, b, y, u, models)
        except (ArithmeticError, ValueError):
            return _NON_FINITE_GAIN if op == J.FIRST else _NON_FINITE
