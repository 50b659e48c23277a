"""Per-sample kernel of the joint Kalman filter (protocol: observers/kernel.py; the model and
its exact step: design.py).

Per output c (channels are independent: p chains of order r, one covariance block each),
over the actual step h of every sample:

    x_c <- F(h) x_c,  P_c <- F(h) P_c F(h)' + Q(h)     F, Q in closed form (no cache)
    nu = y_c - x_c0,  s = P_c00 + R_c,  K = P_c[:, 0] / s,  x_c <- x_c + K nu
    P_c <- (I - K e1') P_c (I - K e1')' + R_c K K'      Joseph form, then symmetrised
    NIS = sum_c nu^2 / s                                  (health; chi-square, p dof)

The first sample after a restart without an explicit estimate (``initial_state:
measurement``) starts at x_c = (y_c, 0, ...), P_c = P0_c with its first row and column
replaced by (R_c, 0, ...): the measured position and its variance, the initial covariance
for the derivatives; otherwise it is a correction only.  The output residual is |nu|, the
one-step-ahead prediction error of the measurement (the innovation).

State:   header | x (n = p r; output c's chain at c r) | P (p blocks of r x r) | nu (p) |
         s (p) | NIS sum since the restart | updates since the restart | 1 when the next
         first sample starts from the measurement, else 0   (st[HEALTH]: the last NIS)
Consts:  header | qc (p) | R (p) | P0 (n x n; its diagonal blocks are used)
Ints:    header | p, r, the state offsets of P, nu, s, the NIS sum, the updates, the start
         flag; the const offsets of qc, R, P0; 1 for initial_state: measurement; the
         work offset of the scratch
Work:    scratch: h^k / k! (2 r), the product F P (r x r), K (r)
Models:  none
"""
from __future__ import annotations

import math

from ...core import jit as J
from ...core.jit import jit
from ...core.reasons import CODE
from ..kernel import HEADER, HEALTH, IC_HEADER, RESIDUAL

(NP, NR, ST_P, ST_NU, ST_S, ST_NIS_SUM, ST_UPDATES, ST_INIT, C_QC, C_R, C_P0, FROM_Y,
 W_SCRATCH) = range(IC_HEADER, IC_HEADER + 13)
_NON_FINITE = CODE["non_finite_estimate"]


def layout(p: int, r: int) -> tuple[list[int], int]:
    """(the state offsets of P, nu, s, the NIS sum, the updates, the start flag; the state
    size)."""
    o = HEADER + p * r
    offs = []
    for width in (p * r * r, p, p, 1, 1, 1):
        offs.append(o)
        o += width
    return offs, o


def scratch_size(r: int) -> int:
    return 2 * r + r * r + r


@jit
def _restart(st, c, ic, x0, has_x0):
    p, r = ic[NP], ic[NR]
    n = p * r
    for i in range(n):
        st[HEADER + i] = x0[i] if has_x0 else 0.0
    for ch in range(p):
        b = ic[ST_P] + ch * r * r
        for i in range(r):
            for j in range(r):
                st[b + i * r + j] = c[ic[C_P0] + (ch * r + i) * n + ch * r + j]
    st[HEALTH] = math.nan
    st[RESIDUAL] = math.nan
    st[ic[ST_NIS_SUM]] = 0.0
    st[ic[ST_UPDATES]] = 0.0
    st[ic[ST_INIT]] = 0.0 if has_x0 else float(ic[FROM_Y])
    return 0


@jit
def _from_measurement(nx, c, ic, y):
    """x_c = (y_c, 0, ...), P_c = P0_c with the position's row and column (R_c, 0, ...)."""
    p, r = ic[NP], ic[NR]
    n = p * r
    for ch in range(p):
        R = c[ic[C_R] + ch]
        b = ic[ST_P] + ch * r * r
        for i in range(r):
            nx[HEADER + ch * r + i] = y[ch] if i == 0 else 0.0
            for j in range(r):
                if i == 0 or j == 0:
                    v = R if i == 0 and j == 0 else 0.0
                else:
                    v = c[ic[C_P0] + (ch * r + i) * n + ch * r + j]
                nx[b + i * r + j] = v
        nx[ic[ST_NU] + ch] = 0.0
        nx[ic[ST_S] + ch] = R
    nx[RESIDUAL] = 0.0
    nx[ic[ST_INIT]] = 0.0
    return 0


@jit
def _predict(nx, ic, wk, ch, h, qc):
    """x_c <- F x_c, P_c <- F P_c F' + Q over h (closed forms)."""
    r = ic[NR]
    w = ic[W_SCRATCH]
    hp = wk[w:w + 2 * r]                          # h^k / k!
    T = wk[w + 2 * r:w + 2 * r + r * r]           # F P
    hp[0] = 1.0
    for k in range(1, 2 * r):
        hp[k] = hp[k - 1] * h / k
    x0 = HEADER + ch * r
    for i in range(r):                            # ascending: x_j (j > i) still old
        acc = 0.0
        for j in range(i, r):
            acc += hp[j - i] * nx[x0 + j]
        nx[x0 + i] = acc
    b = ic[ST_P] + ch * r * r
    for i in range(r):
        for j in range(r):
            acc = 0.0
            for k in range(i, r):
                acc += hp[k - i] * nx[b + k * r + j]
            T[i * r + j] = acc
    for i in range(r):
        for j in range(i, r):
            acc = 0.0
            for k in range(j, r):
                acc += T[i * r + k] * hp[k - j]
            # Q_ij = qc h^m / (m a! b!) = qc (h^m / m!) binom(m - 1, a), a = r-1-i,
            # b = r-1-j, m = a + b + 1
            a = r - 1 - i
            bb = r - 1 - j
            binom = 1.0
            for k in range(1, a + 1):
                binom = binom * (bb + k) / k
            nx[b + i * r + j] = acc + qc * hp[a + bb + 1] * binom
        for j in range(i):
            nx[b + i * r + j] = nx[b + j * r + i]


@jit
def _correct(nx, c, ic, wk, ch, y):
    """The measurement update of output ch (Joseph form); its NIS term."""
    r = ic[NR]
    w = ic[W_SCRATCH]
    T = wk[w + 2 * r:w + 2 * r + r * r]
    K = wk[w + 2 * r + r * r:w + 2 * r + r * r + r]
    R = c[ic[C_R] + ch]
    x0 = HEADER + ch * r
    b = ic[ST_P] + ch * r * r
    s = nx[b] + R
    nu = y[ch] - nx[x0]
    for i in range(r):
        K[i] = nx[b + i * r] / s
    for i in range(r):
        nx[x0 + i] += K[i] * nu
    # T = (I - K e1') P, then P = T (I - K e1')' + R K K'
    for i in range(r):
        for j in range(r):
            T[i * r + j] = nx[b + i * r + j] - K[i] * nx[b + j]
    for i in range(r):
        for j in range(r):
            nx[b + i * r + j] = T[i * r + j] - T[i * r] * K[j] + R * K[i] * K[j]
    for i in range(r):
        for j in range(i + 1, r):
            v = 0.5 * (nx[b + i * r + j] + nx[b + j * r + i])
            nx[b + i * r + j] = v
            nx[b + j * r + i] = v
    nx[ic[ST_NU] + ch] = nu
    nx[ic[ST_S] + ch] = s
    return nu * nu / s


@jit
def _take(nx, c, ic, wk, h, y):
    """Predict over h (none for h = 0) and correct with y, in the candidate."""
    p, r = ic[NP], ic[NR]
    nis = 0.0
    res = 0.0
    for ch in range(p):
        if h > 0.0:
            _predict(nx, ic, wk, ch, h, c[ic[C_QC] + ch])
        nis += _correct(nx, c, ic, wk, ch, y)
        nu = nx[ic[ST_NU] + ch]
        res += nu * nu
    acc = nis
    for i in range(HEADER, HEADER + p * r):
        acc += nx[i] * 0.0
    for i in range(ic[ST_P], ic[ST_P] + p * r * r):
        acc += nx[i] * 0.0
    if not math.isfinite(acc):
        return _NON_FINITE
    nx[HEALTH] = nis
    nx[RESIDUAL] = math.sqrt(res)
    nx[ic[ST_NIS_SUM]] += nis
    nx[ic[ST_UPDATES]] += 1.0
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _take(nx, c, ic, wk, b, y)
    if op == J.FIRST:
        if st[ic[ST_INIT]] > 0.0:
            return _from_measurement(nx, c, ic, y)
        return _take(nx, c, ic, wk, 0.0, y)
    if op == J.RESTART:
        return _restart(st, c, ic, y, a > 0.0)
    return 0
