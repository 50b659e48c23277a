"""Per-sample kernel of the newton_inversion observer (protocol: observers/kernel.py; the
method: observers/newton_inversion/adapter.py's docstring).

Per sample: the differentiator on y (and the one on the inputs) steps; u_e is built; the
Remark-6 filter (if any) steps on the derivative estimates; then, once the delay is over,
the feed-forward predictor x_p = x + J^-1 (trapezoid of eta^(1,n) - h G) (n_dimensional:
the increment of eta), the map at x_p, the backward-Euler step of the finite-time flow on
eta~ = eta - O(x_p), and one Newton step with J(x_p).  The map [O, J, G](x, u_e) is the
model term in slot 0 (core/model_code.py).  cond(J) at the estimate is the health figure.

State:   header | x (n) | J (n x n) | G (n) | O (n) | eta_raw (ne) | eta (ne, filtered) |
         filter state (k x ne) | inversion active | |eta~| | Dy's state | Du's state
Consts:  header | x_hat(0) (n) | mu, alpha, delay | Dy's descriptor | Du's descriptor |
         the filter: A (k x k), B (k), C (k), D, its state at rest for a unit input (k)
Ints:    header | the sizes, flags and offsets below (names = index constants)
Work:    the filter's step cache, the rejection counter, the map's values (n + n^2 + n),
         u_e (m (n + 1)), temporaries (6 n), cond/solve scratch (n x n), the filter's scratch,
         the differentiators' scratch
Models:  [O, J row-major, G](x, u_e)
"""
from __future__ import annotations

import math

from ...core import differentiator_step as red
from ...core import jit as J
from ...core.jit import jit
from ...core.linalg import finite
from ...core.reasons import CODE
from ..kernel import HEADER, HEALTH, IC_HEADER, RESIDUAL
from .numerics import cond2, filter_output, filter_step, implicit_flow, solve

(N, M, NUE, KNOWN, NDIM, NE, HASDU, KF,
 CX0, CPAR, CDY, CDU, CAF, CBF, CCF, CDF, CDC,
 SJ, SG, SO, SRAW, SETA, SXF, SACT, SET, SDY, SDU,
 WFC, FSLOTS, WREJ, WEV, WUE, WT, WW, WFT, WR) = range(IC_HEADER, IC_HEADER + 36)
MU, ALPHA, DELAY = 0, 1, 2
_NON_FINITE_DIFF = CODE["non_finite_differentiator"]
_UNDEFINED = CODE["model_undefined_at_estimate"]
_SINGULAR = CODE["singular_jacobian"]
_NON_FINITE = CODE["non_finite_estimate"]


@jit
def _ue(nx, c, ic, u, ue):
    """u_e = [u_j, u_j', ..., u_j^(n)] per input: the known channels, or the input
    differentiator's estimates (derivatives it does not give are 0; none: u_j only)."""
    n, m = ic[N], ic[M]
    if ic[KNOWN]:
        ue[:] = u
        return
    ue[:] = 0.0
    if not ic[HASDU]:
        for j in range(m):
            ue[j * (n + 1)] = u[j]
        return
    NT = int(c[ic[CDU]])
    for j in range(m):
        row = ic[SDU] + j * (2 * NT + 1) + NT
        for d in range(min(NT, n + 1)):
            ue[j * (n + 1) + d] = nx[row + d]


@jit
def _w(wk, ic):
    """The n x n scratch of cond(J) and the solves."""
    n = ic[N]
    return wk[ic[WW]:ic[WW] + n * n].reshape(n, n)


@jit
def _commit(nx, c, ic, wk, ev, y):
    """J, G, O from the map's values; the residual |y - O_0| and cond(J)."""
    n = ic[N]
    nx[ic[SJ]:ic[SJ] + n * n] = ev[n:n + n * n]
    nx[ic[SG]:ic[SG] + n] = ev[n + n * n:]
    nx[ic[SO]:ic[SO] + n] = ev[:n]
    nx[RESIDUAL] = abs(y[0] - ev[0])
    nx[HEALTH] = cond2(nx[ic[SJ]:ic[SJ] + n * n].reshape(n, n), _w(wk, ic))


@jit
def _restart(st, c, ic, x0, has_x0):
    n = ic[N]
    for i in range(n):
        st[HEADER + i] = x0[i] if has_x0 else c[ic[CX0] + i]
    st[HEALTH] = math.nan
    st[RESIDUAL] = math.nan
    st[ic[SET]] = math.nan
    st[ic[SACT]] = 0.0
    return 0


@jit
def _first(st, nx, c, ic, wk, y, u, models):
    n, ne, k = ic[N], ic[NE], ic[KF]
    if ic[HASDU]:
        red.reset(c, ic[CDU], nx, ic[SDU], u, u[0:0], False)
    ue = wk[ic[WUE]:ic[WUE] + ic[NUE]]
    _ue(nx, c, ic, u, ue)
    ev = wk[ic[WEV]:ic[WEV] + 2 * n + n * n]
    x = nx[HEADER:HEADER + n]
    if models[0](x, y[0:0], ue, ev) != 0:
        return _UNDEFINED
    if ic[NDIM]:
        red.reset(c, ic[CDY], nx, ic[SDY], ev[0:1], ev[1:n], True)
    else:
        red.reset(c, ic[CDY], nx, ic[SDY], y, y[0:0], False)
    raw = nx[ic[SRAW]:ic[SRAW] + ne]
    raw[:] = nx[ic[SDY] + ne:ic[SDY] + 2 * ne]
    eta = nx[ic[SETA]:ic[SETA] + ne]
    eta[:] = raw
    if k:
        X = nx[ic[SXF]:ic[SXF] + k * ne].reshape(k, ne)
        for i in range(k):
            for j in range(ne):
                X[i, j] = c[ic[CDC] + i] * raw[j]
        # the filter starts at rest: its output C X + D eta
        filter_output(c[ic[CCF]:ic[CCF] + k].reshape(1, k), c[ic[CDF]], X, raw, eta)
    nx[ic[SACT]] = 1.0 if c[ic[CPAR] + DELAY] <= 0.0 else 0.0
    if ic[NDIM]:
        nx[ic[SET]] = 0.0
    else:
        s = 0.0
        for i in range(n):
            s += (raw[i] - ev[i]) ** 2
        nx[ic[SET]] = math.sqrt(s)
    _commit(nx, c, ic, wk, ev, y)
    return 0


@jit
def _step(st, nx, c, ic, wk, s, h, y, u, models):
    code = _advance(st, nx, c, ic, wk, s, h, y, u, models)
    if code != 0:
        wk[ic[WREJ]] += 1.0                    # rejections the observer made (diagnostics)
    return code


@jit
def _advance(st, nx, c, ic, wk, s, h, y, u, models):
    n, ne, k = ic[N], ic[NE], ic[KF]
    wr = ic[WR]
    if red.update(c, ic[CDY], st, ic[SDY], nx, ic[SDY], h, y, wk, wr) != 0:
        return _NON_FINITE_DIFF
    if ic[HASDU] and red.update(c, ic[CDU], st, ic[SDU], nx, ic[SDU], h, u, wk, wr) != 0:
        return _NON_FINITE_DIFF
    raw = nx[ic[SRAW]:ic[SRAW] + ne]
    raw[:] = nx[ic[SDY] + ne:ic[SDY] + 2 * ne]
    ue = wk[ic[WUE]:ic[WUE] + ic[NUE]]
    _ue(nx, c, ic, u, ue)
    eta = nx[ic[SETA]:ic[SETA] + ne]
    if ic[CAF] >= 0:
        Af = c[ic[CAF]:ic[CAF] + k * k].reshape(k, k)
        Bf = c[ic[CBF]:ic[CBF] + k].reshape(k, 1)
        Cf = c[ic[CCF]:ic[CCF] + k].reshape(1, k)
        ft = ic[WFT]
        P = wk[ft:ft + k * k].reshape(k, k)
        T = wk[ft + k * k:ft + k * k + k * ne].reshape(k, ne)
        filter_step(Af, Bf, Cf, c[ic[CDF]], st[ic[SXF]:ic[SXF] + k * ne].reshape(k, ne),
                    st[ic[SRAW]:ic[SRAW] + ne], raw, h, wk, ic[WFC], ic[FSLOTS],
                    nx[ic[SXF]:ic[SXF] + k * ne].reshape(k, ne), eta, P, T)
    else:
        eta[:] = raw
    x = st[HEADER:HEADER + n]
    xn = nx[HEADER:HEADER + n]
    ev = wk[ic[WEV]:ic[WEV] + 2 * n + n * n]
    t = ic[WT]
    ff, dx, xp, ep, en, a = (wk[t:t + n], wk[t + n:t + 2 * n], wk[t + 2 * n:t + 3 * n],
                             wk[t + 3 * n:t + 4 * n], wk[t + 4 * n:t + 5 * n],
                             wk[t + 5 * n:t + 6 * n])
    active = s >= c[ic[CPAR] + DELAY] - 1e-12
    if not active:
        if models[0](x, y[0:0], ue, ev) != 0:
            return _UNDEFINED
        xn[:] = x
        if ic[NDIM]:
            et = 0.0
        else:
            et = 0.0
            for i in range(n):
                et += (eta[i] - ev[i]) ** 2
            et = math.sqrt(et)
    else:
        # 1. feed-forward: trapezoid on eta^(1,n) (filtered) or the increment of xi
        #    (n_dimensional), explicit on G, with J from the last evaluation
        Gp = st[ic[SG]:ic[SG] + n]
        eta0 = st[ic[SETA]:ic[SETA] + ne]
        for i in range(n):
            if ic[NDIM]:
                ff[i] = eta[i] - eta0[i] - h * Gp[i]
            else:
                ff[i] = 0.5 * h * (eta0[i + 1] + eta[i + 1]) - h * Gp[i]
        if not solve(st[ic[SJ]:ic[SJ] + n * n], ff, n, dx, _w(wk, ic)):
            return _SINGULAR
        for i in range(n):
            xp[i] = x[i] + dx[i]
        # 2. the stiff part at the new sample: backward Euler on eta~, one Newton step
        if models[0](xp, y[0:0], ue, ev) != 0:
            return _UNDEFINED
        et = 0.0
        for i in range(n):
            ep[i] = eta[i] - ev[i]
            et += ep[i] * ep[i]
        et = math.sqrt(et)
        if not ic[NDIM]:
            implicit_flow(ep, h * c[ic[CPAR] + MU], c[ic[CPAR] + ALPHA], en, a)
            for i in range(n):
                ep[i] = ep[i] - en[i]
        if not solve(ev[n:n + n * n], ep, n, dx, _w(wk, ic)):
            return _SINGULAR
        for i in range(n):
            xn[i] = xp[i] + dx[i]
    if not (finite(xn) and finite(eta) and finite(nx[ic[SXF]:ic[SXF] + k * ne])):
        return _NON_FINITE
    nx[ic[SACT]] = 1.0 if active else 0.0
    nx[ic[SET]] = et
    _commit(nx, c, ic, wk, ev, y)
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _step(st, nx, c, ic, wk, a, b, y, u, models)
    if op == J.FIRST:
        return _first(st, nx, c, ic, wk, y, u, models)
    if op == J.RESTART:
        return _restart(st, c, ic, y, a > 0.0)
    return 0
