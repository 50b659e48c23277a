"""Per-sample kernel of the sampled-measurement single-delay observer (Theorem 2, eq. 39;
protocol: observers/kernel.py, layout: kernel.py).

Y only at sparse instants; between them the predictor omega' = A2 xi_e - k omega + F2(omega,
u) stands in for Y and is reset to Y at each sample.  Z = [z, omega] is integrated in
sub-steps of at most ``substep`` (whole quanta), the linear part exactly (core/exact_step.py,
one cache before t0 + tau and one after: the predictor's matrices change there), F and the
delayed term by Heun's method (the end value from the exact step with them held), the input
linear from the one in force to the new one (input_hold foh, ADVANCE) or held; every
sub-step pushes dl onto the ring.  ADVANCE (every input message) integrates up to the
input's time, so a fast input is applied when it changes.

Work (after the ring): the two step caches, then the scratch (after kernel.py's part):
the sub-step count of the last call (1), [Z, v0, v1] (N + q + 2V, V = 2 n1 + q), the two
step results (N + q each), the composed steps' scratch (N + q + 2V), u at both ends of a
sub-step (m each), w (W), dl (n1), R omega (n1), y - omega (q).
"""
from __future__ import annotations

import math

from ...core import jit as J
from ...core.discretize import MAX_SUBSTEPS
from ...core.exact_step import exact_step
from ...core.jit import jit
from ...core.linalg import finite, norm
from ...core.reasons import CODE
from ...core.step_cache import cache_floats
from .. import kernel as K
from . import kernel as SD
from .kernel import (C_A, C_A_AFTER, C_B, C_B_AFTER, C_ME, C_R, FOH, M, N1, NON_FINITE,
                     NON_FINITE_TERM, Q, S_OM, S_T, S_U, S_XI, S_Y, S_Z, SUBSTEP, W_CACHE,
                     W_CACHE_AFTER, W_SCRATCH, W_SLOTS, mat, model_w, mv)

_NON_FINITE_PREDICTION = CODE["non_finite_prediction"]
_OLDER = CODE["measurement_older_than_prediction"]
_TOO_LONG = CODE["step_too_long"]
#: pushes onto the ring in one call at most: one per sub-step
PUSHES = MAX_SUBSTEPS + 2
SLOTS = 256


def cache_size(n1: int, q: int) -> int:
    """Floats of one of the two step caches."""
    nz, v = 3 * n1 + 2 * q, 2 * n1 + q
    return cache_floats(SLOTS, nz * (nz + 2 * v))


def scratch_floats(n1: int, q: int, m: int) -> int:
    nz, v, w = 3 * n1 + 2 * q, 2 * n1 + q, n1 + 2 * q
    return 1 + 2 * (nz + 2 * v) + 2 * nz + 2 * m + w + 2 * n1 + q


@jit
def _scratch(wk, ic):
    n1, q, m = ic[N1], ic[Q], ic[M]
    nz = 3 * n1 + 2 * q
    v = 2 * n1 + q
    o = ic[W_SCRATCH] + SD.common_scratch(n1, q, m)
    count = wk[o:o + 1]
    o += 1
    zc = wk[o:o + nz + 2 * v]
    o += nz + 2 * v
    zp = wk[o:o + nz]
    zn = wk[o + nz:o + 2 * nz]
    o += 2 * nz
    cs = wk[o:o + nz + 2 * v]
    o += nz + 2 * v
    ua = wk[o:o + m]
    un = wk[o + m:o + 2 * m]
    o += 2 * m
    w = wk[o:o + n1 + 2 * q]
    o += n1 + 2 * q
    dl = wk[o:o + n1]
    t1 = wk[o + n1:o + 2 * n1]
    res = wk[o + 2 * n1:o + 2 * n1 + q]
    return count, zc, zp, zn, cs, ua, un, w, dl, t1, res


@jit
def _u_at(u0, u_end, held, t, s0, s_end, out):
    """The input at t: held, or linear from u0 at s0 to u_end at s_end."""
    if held:
        out[:] = u0
        return
    f = (t - s0) / (s_end - s0)
    for j in range(out.shape[0]):
        out[j] = u0[j] + (u_end[j] - u0[j]) * f


@jit
def _v(st, nx, c, ic, wk, omega, u, s, after, v, models):
    """v = [F1(omega, u), F2(omega, u), dl(s - tau) (0 before t0 + tau)]; the model's code."""
    nf = ic[N1] + ic[Q]
    if models[0](st, omega, u, v[:nf]) != 0:
        return NON_FINITE_TERM
    if after:
        SD.delayed(nx, c, ic, wk, s, v[nf:])
    else:
        v[nf:] = 0.0
    return 0


@jit
def _xi_e(nx, c, ic, wk, s, omega, dl, t1):
    """xi_e at s from the candidate's z and omega: Me z + R omega + dl(s - tau) from t0 + tau
    on (and the health |dl|), xh1 before; whether it is finite."""
    n1, q = ic[N1], ic[Q]
    N = 3 * n1 + q
    xi = nx[ic[S_XI]:ic[S_XI] + n1]
    z = nx[ic[S_Z]:ic[S_Z] + N]
    if not SD.converged(c, s):
        xi[:] = z[:n1]
        return finite(xi)
    SD.delayed(nx, c, ic, wk, s, dl)
    nx[K.HEALTH] = norm(dl)
    mv(mat(c, ic[C_ME], n1, N), z, xi)
    mv(mat(c, ic[C_R], n1, q), omega, t1)
    for i in range(n1):
        xi[i] = xi[i] + t1[i] + dl[i]
    return finite(xi)


@jit
def _integrate(st, nx, c, ic, wk, s_end, u_end, models):
    """The candidate's Z = [z, omega] and xi_e from the committed ones (at model time st's s,
    input st's u) to s_end, the input linear to u_end; 0 or a rejection code."""
    n1, q, m = ic[N1], ic[Q], ic[M]
    N = 3 * n1 + q
    nz = N + q
    v = 2 * n1 + q
    count, zc, zp, zn, cs, ua, un, w, dl, t1, res = _scratch(wk, ic)
    s0 = st[ic[S_T]]
    u0 = st[ic[S_U]:ic[S_U] + m]
    held = SD.same(u_end, u0)
    Z = nx[ic[S_Z]:ic[S_Z] + nz]             # z and omega are adjacent in the state
    v0 = zc[nz:nz + v]
    v1 = zc[nz + v:]
    # sub-steps of whole quanta, so the exact steps come from cached matrices; none when an
    # input at the measurement's time already moved the prediction on
    q0 = K.quanta(s0)
    qs = K.quanta(s_end) - q0
    steps = 0 if qs <= 0 else max(1, math.ceil(qs * K.STEP_QUANTUM / c[SUBSTEP] - 1e-9))
    count[0] = steps
    s = s0
    for i in range(steps):
        s_next = (q0 + round((i + 1) * qs / steps)) * K.STEP_QUANTUM if i + 1 < steps else s_end
        after = SD.converged(c, s)
        if after:
            A = mat(c, ic[C_A_AFTER], nz, nz)
            B = mat(c, ic[C_B_AFTER], nz, v)
            cache = ic[W_CACHE_AFTER]
        else:
            A = mat(c, ic[C_A], nz, nz)
            B = mat(c, ic[C_B], nz, v)
            cache = ic[W_CACHE]
        _u_at(u0, u_end, held, s, s0, s_end, ua)
        zc[:nz] = Z
        if _v(st, nx, c, ic, wk, Z[N:], ua, s, after, v0, models) != 0:
            return NON_FINITE_TERM
        v1[:] = v0
        exact_step(A, B, zc, s_next - s, wk, cache, ic[W_SLOTS], zp, cs)
        if not finite(zp):
            return _NON_FINITE_PREDICTION
        _u_at(u0, u_end, held, s_next, s0, s_end, un)
        if SD.converged(c, s_next) == after:
            # Heun: F and the delayed term at the predicted end, the step again
            if _v(st, nx, c, ic, wk, zp[N:], un, s_next, after, v1, models) != 0:
                return NON_FINITE_TERM
            exact_step(A, B, zc, s_next - s, wk, cache, ic[W_SLOTS], zn, cs)
            Z[:] = zn
        else:
            Z[:] = zp
        if not finite(Z):
            return _NON_FINITE_PREDICTION
        if model_w(models, st, Z[N:], un, w, q) != 0:
            return NON_FINITE_TERM
        SD.push(st, nx, c, ic, wk, s_next, Z[:N], w)
        s = s_next
    if not _xi_e(nx, c, ic, wk, s_end, Z[N:], dl, t1):
        return _NON_FINITE_PREDICTION
    return 0


@jit
def _measure(st, nx, c, ic, wk, s, y, u, models):
    """The measurement y at model time s: the prediction up to s with the input in force,
    the residual y - omega, then omega = y and xi_e from it."""
    n1, q, m = ic[N1], ic[Q], ic[M]
    s_prev = st[ic[S_T]]
    if s < s_prev:
        return _OLDER           # an input after this measurement already moved it on
    if s - s_prev > c[K.MAX_STEP]:
        return _TOO_LONG
    count, zc, zp, zn, cs, ua, un, w, dl, t1, res = _scratch(wk, ic)
    if models[0](st, y, u, w[:n1 + q]) != 0:        # omega = y must give finite terms
        return NON_FINITE_TERM
    code = _integrate(st, nx, c, ic, wk, s, st[ic[S_U]:ic[S_U] + m], models)
    if code != 0:
        return code
    omega = nx[ic[S_OM]:ic[S_OM] + q]
    for i in range(q):
        res[i] = y[i] - omega[i]
    nx[K.RESIDUAL] = norm(res)
    omega[:] = y                                    # omega(t_j) = Y(t_j)
    if not _xi_e(nx, c, ic, wk, s, omega, dl, t1):
        return NON_FINITE
    SD.trim(nx, ic)
    nx[ic[S_T]] = s
    nx[ic[S_Y]:ic[S_Y] + q] = y
    nx[ic[S_U]:ic[S_U] + m] = u
    SD.publish(nx, c, ic, wk, y)
    return 0


@jit
def _advance(st, nx, c, ic, wk, s, u, models):
    """A new input u at model time s: integrate the predictor up to s (the input held, or
    linear to u with input_hold foh) when s is ahead by at most max_step, then take u as the
    input in force.  An input stamped before the prediction changes nothing."""
    q, m = ic[Q], ic[M]
    s_prev = st[ic[S_T]]
    if s < s_prev:
        return 0
    if s_prev < s <= s_prev + c[K.MAX_STEP]:
        u_end = u if ic[FOH] else st[ic[S_U]:ic[S_U] + m]
        code = _integrate(st, nx, c, ic, wk, s, u_end, models)
        if code != 0:
            return code
        nx[ic[S_T]] = s
        SD.trim(nx, ic)
        SD.publish(nx, c, ic, wk, nx[ic[S_OM]:ic[S_OM] + q])
    nx[ic[S_U]:ic[S_U] + m] = u
    return 0


def kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The protocol's one entry (observers/kernel.py)."""
    if op == J.STEP:
        return _measure(st, nx, c, ic, wk, a, y, u, models)
    if op == J.ADVANCE:
        return _advance(st, nx, c, ic, wk, a, u, models)
    if op == J.FIRST:
        return SD.first(st, nx, c, ic, wk, y, u, models)
    if op == J.RESTART:
        return SD.restart(st, c, ic, y, a > 0.0)
    return 0


def last_substeps(wk, ic) -> int:
    """Predictor sub-steps the last call took (work memory, not state: for tests)."""
    return int(wk[ic[W_SCRATCH] + SD.common_scratch(ic[N1], ic[Q], ic[M])])
