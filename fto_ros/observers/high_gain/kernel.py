"""Per-sample kernel of the constant-gain high-gain observer (protocol: observers/kernel.py;
the method: the adapter's module docstring).

The same exact step as global_norm's (global_norm/companion.py) with constant gains: e^(A h)
cached per step size (64 entries, first in first out, keyed by integer ns), y between the
samples linear or quadratic, the model term (its estimates clipped at +-M) a
predictor-corrector pair.

State:   header | y, has y_prev, y_prev, h_prev, saturation active, saturated steps |
         x_hat (m) | u held over the step (n_u) | the published estimate T^-1 x_hat (m; only
         with a state map)
Consts:  header | M | the gains G (m) | c = -G (m) | T (m x m), T^-1 (m x m): the observer
         runs on z = T x (observers/chain_map.py; identity without a map)
Ints:    header | m, n_u, the model at the estimate (0/1), quadratic hold, cache base,
         cache slots, scratch base, state map (0/1)
Work:    the cache of e^(A h), then scratch: e^(A h) built (m^2), its work (2 m^2), r0, r1,
         r2, x_p, x (m each), the model's x (m), the step's work (5 m), two cells, the
         complex work (4 m floats)
Models:  [f(y, x_1..x_n, u)]
"""
from __future__ import annotations

import math

import numpy as np

from ...core import jit as J
from ...core.jit import jit
from ...core.linalg import matvec
from ...core.reasons import CODE
from ...core.step_cache import cache_claim, cache_find
from ..global_norm.companion import companion_expm, companion_step, gain_forcing, output_polynomial
from ..kernel import C_HEADER, HEADER, IC_HEADER, RESIDUAL

M_, NIN, ON_EST, QUAD, CACHE, SLOTS, SCRATCH, MAPPED = range(IC_HEADER, IC_HEADER + 8)
SAT_M = C_HEADER
GAINS = C_HEADER + 1
(Y, HAS_YPREV, YPREV, HPREV, SAT_ACTIVE, SAT_COUNT) = range(HEADER, HEADER + 6)
X_HAT = HEADER + 6
#: entries of the e^(A h) cache
CACHE_SLOTS = 64

_NON_FINITE = CODE["non_finite_estimate"]
_NON_FINITE_TERM = CODE["non_finite_model_term"]


def state_size(m: int, nin: int) -> int:
    return X_HAT + 2 * m + nin


def published(m: int, nin: int) -> int:
    """Where the published estimate is with a state map."""
    return X_HAT + m + nin


def t_map(m: int) -> int:
    """Where T is in the constants (T^-1 follows)."""
    return GAINS + 2 * m


@jit
def _publish(s, c, ic):
    """The published estimate T^-1 x_hat (with a state map; else x_hat is published)."""
    m = ic[M_]
    if ic[MAPPED]:
        o = X_HAT + m + ic[NIN]
        t = GAINS + 2 * m + m * m
        matvec(c[t:t + m * m].reshape(m, m), s[X_HAT:X_HAT + m], s[o:o + m])


def scratch_size(m: int) -> int:
    return 3 * m * m + 5 * m + m + 5 * m + 2 + 4 * m


@jit
def _scratch(ic, wk, k):
    """0 e^(A h) built; 1 its work; 2 r0, 3 r1, 4 r2, 5 x_p, 6 x; 7 the model's x; 8 the
    step's work; 9 a cell (the model's y); 10 a cell (its value); 11 the complex work."""
    m = ic[M_]
    sizes = (m * m, 2 * m * m, m, m, m, m, m, m, 5 * m, 1, 1, 4 * m)
    o = ic[SCRATCH]
    for i in range(k):
        o += sizes[i]
    return wk[o:o + sizes[k]]


@jit
def _expm(c, ic, wk, h):
    """The cached e^(A h) of step h (keyed by integer ns), built where first met."""
    m = ic[M_]
    key = float(round(h * 1e9))
    off = cache_find(wk, ic[CACHE], ic[SLOTS], m * m, key)
    if off < 0:
        E = _scratch(ic, wk, 0).reshape(m, m)
        companion_expm(c[GAINS + m:GAINS + 2 * m], key * 1e-9, E, _scratch(ic, wk, 1),
                       _scratch(ic, wk, 11).view(np.complex128))
        off = cache_claim(wk, ic[CACHE], ic[SLOTS], m * m, key)
        wk[off:off + m * m] = _scratch(ic, wk, 0)
    return wk[off:off + m * m].reshape(m, m)


@jit
def _model(models, c, ic, wk, y, x, u):
    """f_n at (y or xh_0, xh_1..xh_n), the estimates clipped at +-M: (value, clipped, 0), or
    (nan, False, rejection) when f is not finite."""
    m = ic[M_]
    on_est = ic[ON_EST] != 0
    lim = c[SAT_M]
    xbar = _scratch(ic, wk, 7)
    nb = m if on_est else m - 1
    sat = False
    for i in range(nb):
        v = x[i] if on_est else x[i + 1]
        if lim > 0:
            t = v if v > -lim else -lim          # min(M, max(-M, v)), as Python's
            t = t if t < lim else lim
            if not t == v:
                sat = True
            v = t
        xbar[i] = v
    cell = _scratch(ic, wk, 9)
    out = _scratch(ic, wk, 10)
    if on_est:
        cell[0] = xbar[0]
        models[0](xbar[1:m], cell, u, out)
    else:
        cell[0] = y
        models[0](xbar[:m - 1], cell, u, out)
    fv = out[0]
    if not math.isfinite(fv):
        return fv, False, _NON_FINITE_TERM
    return fv, sat, 0


@jit
def _step(st, nx, c, ic, wk, h, y, u, models):
    m = ic[M_]
    yk = y[0]
    E = _expm(c, ic, wk, h)
    G = c[GAINS:GAINS + m]
    cc = c[GAINS + m:GAINS + 2 * m]
    x0 = st[X_HAT:X_HAT + m]
    uh = st[X_HAT + m:X_HAT + m + ic[NIN]]
    y0 = st[Y]
    ya, yb, yc = output_polynomial(st[HAS_YPREV] > 0.0, st[YPREV], st[HPREV], y0, yk, h,
                                   ic[QUAD] != 0)
    v0, _, code = _model(models, c, ic, wk, y0, x0, uh)
    if code != 0:
        return code
    r0 = _scratch(ic, wk, 2)
    r1 = _scratch(ic, wk, 3)
    r2 = _scratch(ic, wk, 4)
    gain_forcing(G, ya, yb, yc, v0, r0, r1, r2)
    xp = _scratch(ic, wk, 5)
    work = _scratch(ic, wk, 8)
    companion_step(cc, E, x0, h, r0, r1, r2, xp, work)
    v1, _, code = _model(models, c, ic, wk, yk, xp, uh)
    if code != 0:
        return code
    r1[m - 1] += (v1 - v0) / h
    x = nx[X_HAT:X_HAT + m]
    companion_step(cc, E, x0, h, r0, r1, r2, x, work)
    for i in range(m):
        if not math.isfinite(x[i]):
            return _NON_FINITE
    _, sat, code = _model(models, c, ic, wk, yk, x, uh)
    if code != 0:
        return code
    nx[SAT_ACTIVE] = 1.0 if sat else 0.0
    nx[SAT_COUNT] += 1.0 if sat else 0.0
    nx[YPREV] = y0
    nx[HPREV] = h
    nx[HAS_YPREV] = 1.0
    nx[Y] = yk
    nx[RESIDUAL] = abs(yk - x[0])
    nx[X_HAT + m:X_HAT + m + ic[NIN]] = u
    _publish(nx, c, ic)
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    m = ic[M_]
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, b, y, u, models)
    if op == J.FIRST:
        nx[Y] = y[0]
        nx[RESIDUAL] = abs(y[0] - nx[X_HAT])
        nx[X_HAT + m:X_HAT + m + ic[NIN]] = u
        _publish(nx, c, ic)
        return 0
    if op == J.RESTART:
        if a > 0.0 and ic[MAPPED]:           # x0 in plant coordinates: T x0
            t = GAINS + 2 * m
            matvec(c[t:t + m * m].reshape(m, m), y, st[X_HAT:X_HAT + m])
        else:
            for i in range(m):
                st[X_HAT + i] = y[i] if a > 0.0 else 0.0
        st[HAS_YPREV] = 0.0
        st[SAT_COUNT] = 0.0
        _publish(st, c, ic)
    return 0


if not J.ENABLED:
    _kernel = kernel

    def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):  # noqa: F811
        """The numpy path: Python's math raises where compiled code gets infinities."""
        try:
            return _kernel(op, st, nx, c, ic, wk, a, b, y, u, models)
        except (ArithmeticError, ValueError):
            return _NON_FINITE
