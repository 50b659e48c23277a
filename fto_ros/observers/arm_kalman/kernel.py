"""Per-sample kernel of ``arm_kalman``: a Kalman filter on the arm's rigid-body model
(protocol: observers/kernel.py; docs/arm.md has the model and its tuning).

State x = [q, v, d] (3n), d the generalized disturbance torque (a random walk: friction the
model lacks, model error, external torques). Over each ACTUAL step h (split into m equal
sub-steps no longer than 1.5 sample periods), with the torque of the last sample held:

    a   = M(q)^-1 (tau - C(q, v) v - g(q) - tau_f(v) + d)     (g added to tau for
          commanded_no_gravity; tau = effort * the torque factor)
    q  <- q + h v + h^2 / 2 a,   v <- v + h a,   d <- d
    P  <- F P F' + Q,  F = I + A h + A^2 h^2 / 2,  A = [[0, I, 0], [0, 0, W], [0, 0, 0]],
    W = M(q)^-1 at the sub-step's start; Q the exact integral of the white disturbance rate
    (intensity S_d, Nm^2/s) and a white acceleration (S_a, (rad/s^2)^2/s) through that A:
      Qqq = W S_d W h^5/20 + S_a h^3/3   Qqv = W S_d W h^4/8 + S_a h^2/2   Qqd = W S_d h^3/6
      Qvv = W S_d W h^3/3 + S_a h        Qvd = W S_d h^2/2                 Qdd = S_d h
    (the partials of the bias in q and v are left out of F: gravity's and friction's time
    constants are far longer than the filter's);
then the measurement y = q + noise (variance R per joint): S = Pqq + R, K = P[:, q] S^-1,
x += K nu, P = (I - K H) P (I - K H)' + K R K' (Joseph form, symmetrised), NIS = nu' S^-1 nu.

The first sample after a restart: x = [y, 0, 0], P = diag(R, P0_v, P0_d). The estimate
[q, v] is published, d as the unknown input; the contact detector (arm/detect.py) runs on d
over its noise scale g_i = gn_i ||M_i,:(q)||.

The layout is the adapter's (observers/arm_kalman/adapter.py): offsets in ic.
"""
from __future__ import annotations

import math

import numpy as np

from ...arm import detect as DT
from ...arm import dynamics as dyn
from ...arm import window as WN
from ...arm.tree import COL
from ...core import jit as J
from ...core.jit import jit
from ...core.reasons import CODE
from ..kernel import HEALTH, IC_HEADER, RESIDUAL

(I_N, I_K, I_NB, I_MEANING, I_ROWS, I_B, I_FC, I_TF, I_R, I_SD, I_SA, I_P0, I_GN, I_DET,
 I_SC, I_SDET, I_EST, I_UI, I_EXTRA) = range(IC_HEADER, IC_HEADER + 19)
C_WIDTH, C_PERIOD = 1, 2
# -- state scalars at ic[I_SC], then the arrays (offsets) --------------------------------------
COUNT, BRIDGED, MAX_BRIDGED, NIS_SUM = range(4)
N_SCALARS = 4
NO_GRAVITY = 1
_NON_FINITE_TERM = CODE["non_finite_model_term"]
_NON_FINITE = CODE["non_finite_estimate"]


@jit
def offsets(n, k):
    """After the scalars: x (3n), P (9 n^2), tau held (n), passive (k), the last five stamps
    (5) and positions (5 n); the total."""
    ox = N_SCALARS
    op = ox + 3 * n
    ot = op + 9 * n * n
    opas = ot + n
    oh = opas + k
    ohq = oh + 5
    return ox, op, ot, opas, oh, ohq, ohq + 5 * n


@jit
def _rows(c, ic):
    return c[ic[I_ROWS]:ic[I_ROWS] + ic[I_NB] * COL].reshape(ic[I_NB], COL)


@jit
def _finite(a):
    acc = 0.0
    for x in a.ravel():
        acc += x * 0.0
    return acc == 0.0


@jit
def _acceleration(c, ic, q, v, d, tau, pas):
    """(a, M^-1) at (q, v) with the torque tau and the disturbance d."""
    n = ic[I_N]
    rows = _rows(c, ic)
    M = dyn.mass_matrix(rows, n, q, pas)
    bias = dyn.inverse_dynamics(rows, n, q, pas, v, np.zeros(n), True)
    rhs = np.empty(n)
    for i in range(n):
        rhs[i] = tau[i] - bias[i] - c[ic[I_B] + i] * v[i] \
            - c[ic[I_FC] + i] * math.tanh(v[i] / c[C_WIDTH]) + d[i]
    W = np.linalg.inv(M)
    return W @ rhs, W


@jit
def _predict(nx, c, ic, h):
    """x and P over h (module doc), in the candidate; 0, or 1 when a term is not finite."""
    n, k = ic[I_N], ic[I_K]
    sc = ic[I_SC]
    ox, op, ot, opas, oh, ohq, end = offsets(n, k)
    m = max(1, int(math.ceil(h / (1.5 * c[C_PERIOD]) - 1e-9)))
    dt = h / m
    N3 = 3 * n
    x = nx[sc + ox:sc + ox + N3]
    P = nx[sc + op:sc + op + N3 * N3].reshape(N3, N3)
    tau = nx[sc + ot:sc + ot + n].copy()
    pas = nx[sc + opas:sc + opas + k].copy()
    sd = c[ic[I_SD]:ic[I_SD] + n]
    sa = c[ic[I_SA]:ic[I_SA] + n]
    for _ in range(m):
        q, v, d = x[:n].copy(), x[n:2 * n].copy(), x[2 * n:].copy()
        a, W = _acceleration(c, ic, q, v, d, tau, pas)
        if not (_finite(a) and _finite(W)):
            return 1
        for i in range(n):
            x[i] = q[i] + dt * v[i] + 0.5 * dt * dt * a[i]
            x[n + i] = v[i] + dt * a[i]
        F = np.eye(N3)
        for i in range(n):
            F[i, n + i] = dt
            for j in range(n):
                F[i, 2 * n + j] = 0.5 * dt * dt * W[i, j]
                F[n + i, 2 * n + j] = dt * W[i, j]
        WS = W * sd                                    # W diag(S_d)
        WSW = WS @ W.T
        Pn = F @ P @ F.T
        for i in range(n):
            for j in range(n):
                w = WSW[i, j]
                Pn[i, j] += w * dt ** 5 / 20.0
                Pn[i, n + j] += w * dt ** 4 / 8.0
                Pn[n + i, j] += w * dt ** 4 / 8.0
                Pn[n + i, n + j] += w * dt ** 3 / 3.0
                Pn[i, 2 * n + j] += WS[i, j] * dt ** 3 / 6.0
                Pn[2 * n + j, i] += WS[i, j] * dt ** 3 / 6.0
                Pn[n + i, 2 * n + j] += WS[i, j] * dt ** 2 / 2.0
                Pn[2 * n + j, n + i] += WS[i, j] * dt ** 2 / 2.0
            Pn[i, i] += sa[i] * dt ** 3 / 3.0
            Pn[i, n + i] += sa[i] * dt ** 2 / 2.0
            Pn[n + i, i] += sa[i] * dt ** 2 / 2.0
            Pn[n + i, n + i] += sa[i] * dt
            Pn[2 * n + i, 2 * n + i] += sd[i] * dt
        P[:, :] = Pn
    return 0


@jit
def _correct(nx, c, ic, y):
    """The measurement update (module doc); NIS and |nu|, or (nan, nan) if not finite."""
    n, k = ic[I_N], ic[I_K]
    sc = ic[I_SC]
    ox, op, ot, opas, oh, ohq, end = offsets(n, k)
    N3 = 3 * n
    x = nx[sc + ox:sc + ox + N3]
    P = nx[sc + op:sc + op + N3 * N3].reshape(N3, N3)
    R = c[ic[I_R]:ic[I_R] + n]
    S = P[:n, :n].copy()
    nu = np.empty(n)
    for i in range(n):
        S[i, i] += R[i]
        nu[i] = y[i] - x[i]
    Si = np.linalg.inv(S)
    K = P[:, :n] @ Si
    x += K @ nu
    T = P - K @ P[:n, :]
    KR = K * R
    Pn = T - T[:, :n] @ K.T + KR @ K.T
    P[:, :] = 0.5 * (Pn + Pn.T)
    nis = nu @ (Si @ nu)
    return nis, math.sqrt(nu @ nu)


@jit
def _restart(st, c, ic):
    sc = ic[I_SC]
    n = ic[I_N]
    st[sc + COUNT] = 0.0
    st[sc + NIS_SUM] = 0.0
    st[RESIDUAL] = math.nan
    st[HEALTH] = math.nan
    for i in range(n):
        st[ic[I_UI] + i] = 0.0
    DT.restarted(st, ic[I_SDET], n)
    DT.write_extras(st, ic[I_SDET], n, 0.0, st, ic[I_EXTRA])
    return 0


@jit
def _first(nx, c, ic, y):
    """x = [y, 0, 0], P = diag(R, P0_v, P0_d)."""
    n, k = ic[I_N], ic[I_K]
    sc = ic[I_SC]
    ox, op, ot, opas, oh, ohq, end = offsets(n, k)
    N3 = 3 * n
    for i in range(N3 * N3):
        nx[sc + op + i] = 0.0
    for i in range(N3):
        nx[sc + ox + i] = y[i] if i < n else 0.0
        v = c[ic[I_R] + i] if i < n else c[ic[I_P0] + i]
        nx[sc + op + i * N3 + i] = v
    nx[RESIDUAL] = 0.0
    return 0


@jit
def _sample(st, nx, c, ic, wk, s, h, y, u):
    """FIRST (h <= 0) or STEP."""
    n, k = ic[I_N], ic[I_K]
    sc = ic[I_SC]
    ox, op, ot, opas, oh, ohq, end = offsets(n, k)
    count = int(st[sc + COUNT]) + 1
    nx[sc + COUNT] = min(count, 5)
    if h <= 0.0:
        _first(nx, c, ic, y)
    else:
        if _predict(nx, c, ic, h) != 0:
            return _NON_FINITE_TERM
        nis, res = _correct(nx, c, ic, y)
        if not (math.isfinite(nis) and _finite(nx[sc + ox:sc + op + 9 * n * n])):
            return _NON_FINITE
        nx[HEALTH] = nis
        nx[RESIDUAL] = res
        nx[sc + NIS_SUM] += nis
        if h > 1.5 * c[C_PERIOD]:
            nx[sc + BRIDGED] += 1.0
            nx[sc + MAX_BRIDGED] = max(nx[sc + MAX_BRIDGED], h)
    pas = u[n:n + k]
    for i in range(k):
        nx[sc + opas + i] = pas[i]
    for i in range(n):                                  # the torque held until the next sample
        nx[sc + ot + i] = u[i] * c[ic[I_TF] + i]
        nx[ic[I_EST] + i] = nx[sc + ox + i]
        nx[ic[I_EST] + n + i] = nx[sc + ox + n + i]
        nx[ic[I_UI] + i] = nx[sc + ox + 2 * n + i]
    if ic[I_MEANING] == NO_GRAVITY:                    # held as the torque the arm gets
        g = dyn.gravity(_rows(c, ic), n, y, pas)
        for i in range(n):
            nx[sc + ot + i] += g[i]
    WN.push_history(nx, sc + oh, sc + ohq, n, s, y)
    if count >= 5:
        e = np.empty(n)
        WN.extrapolation_residual(nx[sc + oh:sc + oh + 5], nx[sc + ohq:sc + ohq + 5 * n]
                                  .reshape(5, n), n, e)
        DT.encoder_sample(nx, ic[I_SDET], c, ic[I_DET], n, e)
    if count < 2:
        DT.write_extras(nx, ic[I_SDET], n, 0.0, nx, ic[I_EXTRA])
        return 0
    M = dyn.mass_matrix(_rows(c, ic), n, nx[sc + ox:sc + ox + n].copy(), pas)
    g = np.empty(n)
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += M[i, j] * M[i, j]
        g[i] = c[ic[I_GN] + i] * math.sqrt(acc)
    d = nx[ic[I_UI]:ic[I_UI] + n]
    DT.update(nx, ic[I_SDET], c, ic[I_DET], n, h, d, g, nx, ic[I_EXTRA])
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
