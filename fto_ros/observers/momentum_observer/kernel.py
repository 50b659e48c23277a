"""Per-sample kernel of the generalized-momentum observer of an arm's external torques, the
baseline (protocol: observers/kernel.py; docs/external_torque.md "The baselines").

    r_k = K (p_k - p_0 - I_k),   I_k = I_k-1 + h_k (tau_k-1 + (beta_k-1 + beta_k) / 2 + r_k-1)

p = M(q) v, beta = C^T v - g - tau_f(v), v the backward difference over the actual step
h_k; the torque of sample k - 1 held over [t_k-1, t_k) (across a bridged gap too). After a
restart p_0 is taken at the second sample (the first with a velocity: a velocity of zero
there would read p itself as an external torque), and the first residual comes at the
third; the residual starts at zero, so a restart is never a contact. The detector
(arm/detect.py) runs on r over its noise scale g ||M_i,:(q)||.

The layout is the adapter's (observers/momentum_observer/adapter.py): offsets in ic.
"""
from __future__ import annotations

import math

from ...arm import detect as DT
from ...arm import dynamics as dyn
from ...arm import window as WN
from ...arm.tree import COL
from ...core import jit as J
from ...core.jit import jit
from ...core.reasons import CODE
from ..kernel import CONVERGED, GUARANTEED, HEALTH, IC_HEADER, RESIDUAL

(I_N, I_K, I_NB, I_MEANING, I_ROWS, I_B, I_FC, I_TF, I_GAIN, I_DET, I_SC, I_SDET, I_WV,
 I_WG, I_WE, I_EST, I_UI, I_EXTRA) = range(IC_HEADER, IC_HEADER + 18)
C_WIDTH, C_PERIOD, C_NOISE = 1, 2, 3
# -- state scalars, then arrays, at ic[I_SC] ---------------------------------------------------
COUNT, VALID, BRIDGED, MAX_BRIDGED = range(4)
N_SCALARS = 4
NO_GRAVITY = 1
_NON_FINITE_TERM = CODE["non_finite_model_term"]
_NON_FINITE = CODE["non_finite_estimate"]


@jit
def offsets(n, k):
    """Offsets after the scalars: q_prev, v, p0, I, beta_prev, tau_prev, p_last (n each),
    M (n x n), passive (k), the last five stamps (5) and positions (5 n); the total."""
    o = N_SCALARS
    oq = o
    ov = oq + n
    op0 = ov + n
    oi = op0 + n
    ob = oi + n
    ot = ob + n
    opl = ot + n
    om = opl + n
    opas = om + n * n
    oh = opas + k
    ohq = oh + 5
    return oq, ov, op0, oi, ob, ot, opl, om, opas, oh, ohq, ohq + 5 * n


@jit
def _terms(st, c, ic, q, pas, v):
    """M and p = M v (p_last) at (q, v) into the state; 0, or 1 when a term is not finite."""
    n, k = ic[I_N], ic[I_K]
    sc = ic[I_SC]
    oq, ov, op0, oi, ob, ot, opl, om, opas, oh, ohq, end = offsets(n, k)
    rows = c[ic[I_ROWS]:ic[I_ROWS] + ic[I_NB] * COL].reshape(ic[I_NB], COL)
    out = dyn.momentum_terms(rows, n, q, pas, v, True)
    acc = 0.0
    for x in out:
        acc += x * 0.0
    if acc != 0.0:
        return 1
    for i in range(n):
        p = 0.0
        for j in range(n):
            st[sc + om + i * n + j] = out[i * n + j]
            p += out[i * n + j] * v[j]
        st[sc + opl + i] = p
    return 0


@jit
def _restart(st, c, ic):
    sc = ic[I_SC]
    st[sc + COUNT] = 0.0
    st[sc + VALID] = 0.0
    st[RESIDUAL] = math.nan
    st[CONVERGED] = 0.0
    st[GUARANTEED] = math.inf
    n = ic[I_N]
    for i in range(n):
        st[ic[I_UI] + i] = 0.0
    DT.restarted(st, ic[I_SDET], n)
    DT.write_extras(st, ic[I_SDET], n, 0.0, st, ic[I_EXTRA])
    return 0


@jit
def _sample(st, nx, c, ic, wk, s, h, y, u):
    """FIRST (h <= 0) or STEP."""
    n, k = ic[I_N], ic[I_K]
    sc = ic[I_SC]
    oq, ov, op0, oi, ob, ot, opl, om, opas, oh, ohq, end = offsets(n, k)
    count = int(st[sc + COUNT]) + 1
    nx[sc + COUNT] = min(count, 5)
    v = wk[ic[I_WV]:ic[I_WV] + n]
    for i in range(n):
        v[i] = (y[i] - st[sc + oq + i]) / h if count > 1 else 0.0
    for i in range(k):
        nx[sc + opas + i] = u[n + i]
    if _terms(nx, c, ic, y, u[n:n + k], v) != 0:
        return _NON_FINITE_TERM
    rows = c[ic[I_ROWS]:ic[I_ROWS] + ic[I_NB] * COL].reshape(ic[I_NB], COL)
    terms = dyn.momentum_terms(rows, n, y, u[n:n + k], v, False)
    o = 2 * n * n
    r = nx[ic[I_UI]:ic[I_UI] + n]
    for i in range(n):
        beta = terms[o + i] - terms[o + n + i] - c[ic[I_B] + i] * v[i] \
            - c[ic[I_FC] + i] * math.tanh(v[i] / c[C_WIDTH])
        tau = u[i] * c[ic[I_TF] + i]
        if ic[I_MEANING] == NO_GRAVITY:
            tau += terms[o + n + i]
        if count == 2:                              # the first velocity: p_0
            nx[sc + op0 + i] = nx[sc + opl + i]
            nx[sc + oi + i] = 0.0
            r[i] = 0.0
        elif count > 2:
            nx[sc + oi + i] = st[sc + oi + i] + h * (st[sc + ot + i] + 0.5 * (st[sc + ob + i]
                                                                          + beta) + st[ic[I_UI] + i])
            r[i] = c[ic[I_GAIN] + i] * (nx[sc + opl + i] - nx[sc + op0 + i] - nx[sc + oi + i])
        nx[sc + ob + i] = beta
        nx[sc + ot + i] = tau
        nx[sc + oq + i] = y[i]
        nx[sc + ov + i] = v[i]
        nx[ic[I_EST] + i] = y[i]
        nx[ic[I_EST] + n + i] = v[i]
    WN.push_history(nx, sc + oh, sc + ohq, n, s, y)
    if count > 1 and h > 1.5 * c[C_PERIOD]:
        nx[sc + BRIDGED] += 1.0
        nx[sc + MAX_BRIDGED] = max(nx[sc + MAX_BRIDGED], h)
    if count >= 5:
        e = wk[ic[I_WE]:ic[I_WE] + n]
        WN.extrapolation_residual(nx[sc + oh:sc + oh + 5], nx[sc + ohq:sc + ohq + 5 * n]
                                  .reshape(5, n), n, e)
        DT.encoder_sample(nx, ic[I_SDET], c, ic[I_DET], n, e)
    nx[RESIDUAL] = 0.0
    acc = 0.0
    for i in range(n):
        acc += r[i] * 0.0
    if acc != 0.0:
        return _NON_FINITE
    if count < 3:
        DT.write_extras(nx, ic[I_SDET], n, 0.0, nx, ic[I_EXTRA])
        return 0
    nx[sc + VALID] = 1.0
    nx[CONVERGED] = 1.0
    g = wk[ic[I_WG]:ic[I_WG] + n]
    for i in range(n):
        a = 0.0
        for j in range(n):
            x = nx[sc + om + i * n + j]
            a += x * x
        g[i] = c[C_NOISE] * c[ic[I_GAIN] + i] * math.sqrt(a)
    DT.update(nx, ic[I_SDET], c, ic[I_DET], n, h, r, g, nx, ic[I_EXTRA])
    worst = 0.0
    lo = ic[I_EXTRA] + DT.X_HEAD + 2 * n
    for i in range(n):
        if nx[lo + i] > 0.0:
            worst = max(worst, abs(r[i]) / nx[lo + i])
    nx[HEALTH] = worst
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _sample(st, nx, c, ic, wk, a, b, y, u)
    if op == J.FIRST:
        return _sample(st, nx, c, ic, wk, 0.0, 0.0, y, u)
    if op == J.RESTART:
        return _restart(st, c, ic)
    return 0


@jit
def refresh(st, c, ic):
    """The tree's rows changed (a payload): p_0 moves by the change of p at the last sample,
    so the residual goes on where it was; M is taken again. 0, or 1 (not finite)."""
    n, k = ic[I_N], ic[I_K]
    sc = ic[I_SC]
    oq, ov, op0, oi, ob, ot, opl, om, opas, oh, ohq, end = offsets(n, k)
    if st[sc + COUNT] < 1.0:
        return 0
    old = st[sc + opl:sc + opl + n].copy()
    if _terms(st, c, ic, st[sc + oq:sc + oq + n].copy(), st[sc + opas:sc + opas + k].copy(),
              st[sc + ov:sc + ov + n].copy()) != 0:
        return 1
    for i in range(n):
        st[sc + op0 + i] += st[sc + opl + i] - old[i]
    return 0
