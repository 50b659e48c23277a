"""Per-sample kernel of the continuous-discrete EKF (protocol: observers/kernel.py).

A sample interval h is predicted in k = min(MAX_SUBSTEPS, ceil(h / sub_step)) equal
sub-steps, each one matrix exponential of the Van Loan block matrix linearised at its start
(adapter.py has the filter), then corrected with the sample (Joseph form, NIS).  The first
sample after a restart is a correction only, or (``initial_state: measurement``, no explicit
initial estimate) the start from the state consistent with it: Gauss-Newton on h(x, u) = y
from x = 0 (x += H^+ (y - h), at most INIT_ITERATIONS steps), P = H^+ R H^+' + N P0 N'
with N = I - H^+ H (the measurement's variance in the measured directions, P0 in the
others); where h is not finite or the residual did not shrink, the correction from zero.  The arithmetic is the numpy code's, in its
order: the numpy path (FTO_ROS_NUMBA=0) runs this code with scipy's expm; compiled, the
exponential is core/linalg.py's ``expm`` (scipy's algorithm, not bit for bit with it) and
the products numba's (BLAS).

State:   header | x (n) | P (n x n) | u of the last sample (m) | innovation nu (p) |
         S (p x p) | sum of the NIS since the restart | updates since the restart |
         1 when the next first sample starts from the state consistent with it, else 0
         (st[HEALTH] is the NIS of the last update, nan before one)
Consts:  header | sub_step | Qc (n x n) | R (p x p) | P0 (n x n)
Ints:    header | n, p, m, foh, then the state offsets of P, u, nu, S, the NIS sum, the
         update count, the start flag; then 1 for initial_state: measurement
Work:    none (the temporaries are new arrays, as in the exponential)
Models:  [f(x, u) (n) then df/dx (n x n, row-major), h(x, u) (p) then dh/dx (p x n)]
"""
from __future__ import annotations

import math

import numpy as np

from ...core import jit as J
from ...core.jit import jit
from ...core.linalg import dot, expm, finite, inv, mul, mulv, norm, vmul
from ...core.reasons import CODE
from ..kernel import C_HEADER, HEADER, HEALTH, IC_HEADER, RESIDUAL

(N, P, M, FOH, ST_P, ST_U, ST_NU, ST_S, ST_NIS_SUM, ST_UPDATES, ST_INIT,
 FROM_Y) = range(IC_HEADER, IC_HEADER + 12)
SUB_STEP = C_HEADER
#: most sub-steps one sample interval is split into
MAX_SUBSTEPS = 100
#: most Gauss-Newton steps of the start from the first measurement
INIT_ITERATIONS = 20
_NON_FINITE_MODEL = CODE["non_finite_model"]
_NON_FINITE = CODE["non_finite_estimate"]
_SINGULAR_S = CODE["singular_innovation_covariance"]


def layout(n: int, p: int, m: int) -> tuple[list[int], int]:
    """(the state offsets after the header ints n, p, m, foh, state size)."""
    o = HEADER + n
    offs = []
    for width in (n * n, m, p, p * p, 1, 1, 1):
        offs.append(o)
        o += width
    return offs, o


@jit
def _consts(c, ic):
    n, p = ic[N], ic[P]
    o = C_HEADER + 1
    Qc = c[o:o + n * n].reshape(n, n)
    o += n * n
    R = c[o:o + p * p].reshape(p, p)
    o += p * p
    P0 = c[o:o + n * n].reshape(n, n)
    return Qc, R, P0


@jit
def _restart(st, c, ic, x0, has_x0):
    n = ic[N]
    Qc, R, P0 = _consts(c, ic)
    for i in range(n):
        st[HEADER + i] = x0[i] if has_x0 else 0.0
    st[ic[ST_P]:ic[ST_P] + n * n] = P0.ravel()
    st[HEALTH] = math.nan
    st[RESIDUAL] = math.nan
    st[ic[ST_NIS_SUM]] = 0.0
    st[ic[ST_UPDATES]] = 0.0
    st[ic[ST_INIT]] = 0.0 if has_x0 else float(ic[FROM_Y])
    return 0


@jit
def _store(nx, ic, x, Pm, u, nu, S):
    """x, P, u, the innovation, S and the output residual |nu| into the candidate."""
    n, p, m = ic[N], ic[P], ic[M]
    nx[HEADER:HEADER + n] = x
    nx[ic[ST_P]:ic[ST_P] + n * n] = Pm.ravel()
    nx[ic[ST_U]:ic[ST_U] + m] = u
    nx[ic[ST_NU]:ic[ST_NU] + p] = nu
    nx[ic[ST_S]:ic[ST_S] + p * p] = S.ravel()
    nx[RESIDUAL] = norm(nu)


@jit
def _from_measurement(nx, c, ic, y, u, models):
    """Start nx from the state consistent with the first sample (the module doc); False
    (nx untouched) where that fails: the caller corrects from the restart state instead."""
    n, p, m = ic[N], ic[P], ic[M]
    Qc, R, P0 = _consts(c, ic)
    x = np.zeros(n)
    vals = np.empty(p + p * n)
    if models[1](x, u, u, vals) != 0:
        return False
    r0 = norm(y - vals[:p])
    for _ in range(INIT_ITERATIONS):
        dx = mulv(np.linalg.pinv(vals[p:].reshape(p, n)), y - vals[:p])
        x = x + dx
        if not finite(x) or models[1](x, u, u, vals) != 0:
            return False
        if norm(dx) <= 1e-12 * max(1.0, norm(x)):
            break
    nu = y - vals[:p]
    if not norm(nu) <= r0:                       # also false for nan
        return False
    H = vals[p:].reshape(p, n)
    Hp = np.linalg.pinv(H)
    Nn = np.eye(n) - mul(Hp, H)
    Pm = mul(mul(Hp, R), Hp.T) + mul(mul(Nn, P0), Nn.T)
    Pm = 0.5 * (Pm + Pm.T)
    S = mul(mul(H, Pm), H.T) + R
    if not math.isfinite(Pm.sum() + S.sum()):
        return False
    _store(nx, ic, x, Pm, u, nu, S)
    nx[ic[ST_INIT]] = 0.0
    return True


@jit
def _predict(x, Pm, u, dt, Qc, models, vals):
    """(True, x, P) after one linearised exact sub-step of length dt from (x, P); (False,
    ...) when the model is not finite there.  (The models take no y: u stands in.)"""
    n = x.shape[0]
    models[0](x, u, u, vals)
    A = vals[n:].reshape(n, n)
    Mb = np.zeros((2 * n + 1, 2 * n + 1))
    Mb[1:n + 1, n + 1:] = Qc
    Mb[0, n + 1:] = vals[:n]
    Mb[1:n + 1, 1:n + 1] = -A
    Mb[n + 1:, n + 1:] = A.T
    if not math.isfinite(Mb.sum()):
        return False, x, Pm
    E = expm(Mb * dt)
    Phi = E[n + 1:, n + 1:].T
    Qd = mul(Phi, E[1:n + 1, n + 1:])
    return True, x + E[0, n + 1:], mul(mul(Phi, Pm), Phi.T) + 0.5 * (Qd + Qd.T)


@jit
def _take(st, nx, c, ic, h, y, u, models):
    """Predict over h (none for h = 0) and correct with (y, u) into nx."""
    n, p, m = ic[N], ic[P], ic[M]
    Qc, R, P0 = _consts(c, ic)
    x = st[HEADER:HEADER + n].copy()
    Pm = st[ic[ST_P]:ic[ST_P] + n * n].reshape(n, n).copy()
    if h > 0.0:
        u0 = st[ic[ST_U]:ic[ST_U] + m]
        held = 0.5 * (u0 + u) if ic[FOH] else u0.copy()
        k = min(MAX_SUBSTEPS, max(1, math.ceil(h / c[SUB_STEP] - 1e-9)))
        vals = np.empty(n + n * n)
        for _ in range(k):
            ok, x, Pm = _predict(x, Pm, held, h / k, Qc, models, vals)
            if not ok:
                return _NON_FINITE_MODEL
    vals = np.empty(p + p * n)
    if models[1](x, u, u, vals) != 0:
        return _NON_FINITE_MODEL
    nu = y - vals[:p]
    H = vals[p:].reshape(p, n)
    PHt = mul(Pm, H.T)
    S = mul(H, PHt) + R
    if not finite(S.ravel()):
        return _NON_FINITE
    Si = np.empty((p, p))
    if not inv(S, Si):
        return _SINGULAR_S
    K = mul(PHt, Si)
    nis = dot(vmul(nu, Si), nu)
    x = x + mulv(K, nu)
    IKH = np.eye(n) - mul(K, H)
    Pm = mul(mul(IKH, Pm), IKH.T) + mul(mul(K, R), K.T)
    Pm = 0.5 * (Pm + Pm.T)
    if not math.isfinite(x.sum() + Pm.sum() + nis):      # one check for all
        return _NON_FINITE
    _store(nx, ic, x, Pm, u, nu, S)
    nx[HEALTH] = nis
    nx[ic[ST_NIS_SUM]] += nis
    nx[ic[ST_UPDATES]] += 1.0
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _take(st, nx, c, ic, b, y, u, models)
    if op == J.FIRST:
        if st[ic[ST_INIT]] > 0.0 and _from_measurement(nx, c, ic, y, u, models):
            return 0
        return _take(st, nx, c, ic, 0.0, y, u, models)
    if op == J.RESTART:
        return _restart(st, c, ic, y, a > 0.0)
    return 0
