"""Contact and collision detection per joint inside an estimator's compiled state, with the
calibration that measures the residual's level and compares it with the encoder's noise
(``core.jit``; the external-torque families' kernels call these; docs/external_torque.md).

Per joint i, on an external-torque estimate r_i and its noise scale g_i (Nm per rad of
encoder noise: the estimator's gain times ||M_i,:(q)||, so r_i / g_i is stationary):

- **calibration**: over the first ``CAL_SAMPLES`` estimates (contact-free), the RMS of
  r_i / g_i (the residual's level, rad) and of the encoder's noise (the residual of a cubic
  extrapolation of the positions, rad); sigma_i = the level at its upper confidence bound
  (times ``CONF``), or the given ``collision.sigma``; factor_i = level / encoder noise, a
  model mismatch when above ``MISMATCH`` (it is ~1 for a model that fits: the residual is
  the encoder's noise through the estimator);
- **contact** (the lower level): |r_i| > lower_i = z sigma_i g_i sets the flag (an onset is
  counted); it clears once |r_i| stayed below ``RELEASE`` lower_i for ``HOLD`` s;
- **collision** (the upper level): |r_i| > upper_i (given in Nm, else ``UPPER_FACTOR``
  lower_i) latches it until :func:`clear_collisions` (the node's ``~/reset_collision``).

Constants at ``co``: [z, CONF, CAL_SAMPLES, RELEASE, HOLD, UPPER_FACTOR, MISMATCH, sigma given
(n; 0: calibrate), upper given (n; 0: the factor)]. State at ``so``: the scalars below, then
n values each of the per-joint arrays. The extras the runner publishes (at ``eo``): valid,
calibrated, mismatch, then contact (n), collision (n), lower (n), upper (n).
"""
from __future__ import annotations

import math

from ..core.jit import jit

# -- constants --------------------------------------------------------------------------
Z, CONF, CAL_SAMPLES, RELEASE, HOLD, UPPER_FACTOR, MISMATCH = range(7)
C_HEAD = 7
# -- state: scalars, then per-joint arrays --------------------------------------------------
CAL_N, ENC_N, CALIBRATED, MISMATCHED, ONSETS = range(5)
S_HEAD = 5
(CAL_SUM, ENC_SUM, SIGMA, LEVEL, ENC, CONTACT, QUIET, COLLISION, LOWER, UPPER) = range(10)
ARRAYS = 10
# -- extras ------------------------------------------------------------------------------
X_VALID, X_CALIBRATED, X_MISMATCH = 0, 1, 2
X_HEAD = 3


def consts_size(n: int) -> int:
    return C_HEAD + 2 * n


def state_size(n: int) -> int:
    return S_HEAD + ARRAYS * n


def extras_size(n: int) -> int:
    return X_HEAD + 4 * n


@jit
def _at(so, n, array, i):
    return so + S_HEAD + array * n + i


@jit
def init(st, so, c, co, n):
    """A detector that has measured nothing: thresholds from a given sigma, else none."""
    for k in range(S_HEAD + ARRAYS * n):
        st[so + k] = 0.0
    for i in range(n):
        st[_at(so, n, SIGMA, i)] = c[co + C_HEAD + i]
        st[_at(so, n, LOWER, i)] = math.inf
        st[_at(so, n, UPPER, i)] = math.inf
        st[_at(so, n, LEVEL, i)] = math.nan
        st[_at(so, n, ENC, i)] = math.nan


@jit
def restarted(st, so, n):
    """The estimator restarts: contacts are judged afresh (a restart is not a contact);
    the calibration and the latched collisions stay."""
    for i in range(n):
        st[_at(so, n, CONTACT, i)] = 0.0
        st[_at(so, n, QUIET, i)] = 0.0


@jit
def clear_collisions(st, so, n):
    for i in range(n):
        st[_at(so, n, COLLISION, i)] = 0.0


@jit
def encoder_sample(st, so, c, co, n, e):
    """One residual per joint of the encoder's noise (rad), while calibrating."""
    if st[so + CALIBRATED] > 0.0:
        return
    for i in range(n):
        st[_at(so, n, ENC_SUM, i)] += e[i] * e[i]
    st[so + ENC_N] += 1.0


@jit
def _finish_calibration(st, so, c, co, n):
    bad = 0.0
    for i in range(n):
        level = math.sqrt(st[_at(so, n, CAL_SUM, i)] / st[so + CAL_N])
        st[_at(so, n, LEVEL, i)] = level
        if c[co + C_HEAD + i] <= 0.0:
            st[_at(so, n, SIGMA, i)] = max(level * c[co + CONF], 1e-300)
        if st[so + ENC_N] > 0.0:
            enc = math.sqrt(st[_at(so, n, ENC_SUM, i)] / st[so + ENC_N])
            st[_at(so, n, ENC, i)] = enc
            if level > c[co + MISMATCH] * max(enc, 1e-300):
                bad = 1.0
    st[so + CALIBRATED] = 1.0
    st[so + MISMATCHED] = bad


@jit
def update(st, so, c, co, n, h, r, g, extra, eo):
    """One estimate r (n, Nm) with its noise scale g (n, Nm/rad), h the step since the last
    sample (s): calibration, contact and collision; the extras written."""
    if st[so + CALIBRATED] == 0.0:
        for i in range(n):
            x = r[i] / g[i]
            st[_at(so, n, CAL_SUM, i)] += x * x
        st[so + CAL_N] += 1.0
        if st[so + CAL_N] >= c[co + CAL_SAMPLES]:
            _finish_calibration(st, so, c, co, n)
    for i in range(n):
        sigma = st[_at(so, n, SIGMA, i)]
        if sigma <= 0.0:                          # not known yet: no detection
            st[_at(so, n, LOWER, i)] = math.inf
            st[_at(so, n, UPPER, i)] = math.inf
            continue
        lower = c[co + Z] * sigma * g[i]
        up = c[co + C_HEAD + n + i]
        upper = up if up > 0.0 else c[co + UPPER_FACTOR] * lower
        st[_at(so, n, LOWER, i)] = lower
        st[_at(so, n, UPPER, i)] = upper
        a = abs(r[i])
        ci = _at(so, n, CONTACT, i)
        qi = _at(so, n, QUIET, i)
        if st[ci] > 0.0:
            if a < c[co + RELEASE] * lower:
                st[qi] += h
                if st[qi] >= c[co + HOLD]:
                    st[ci] = 0.0
                    st[qi] = 0.0
            else:
                st[qi] = 0.0
        elif a > lower:
            st[ci] = 1.0
            st[qi] = 0.0
            st[so + ONSETS] += 1.0
        if a > upper:
            st[_at(so, n, COLLISION, i)] = 1.0
    write_extras(st, so, n, 1.0, extra, eo)


@jit
def write_extras(st, so, n, valid, extra, eo):
    """The published extras (module doc); thresholds not known yet are published as 0."""
    extra[eo + X_VALID] = valid
    extra[eo + X_CALIBRATED] = st[so + CALIBRATED]
    extra[eo + X_MISMATCH] = st[so + MISMATCHED]
    for i in range(n):
        extra[eo + X_HEAD + i] = st[_at(so, n, CONTACT, i)]
        extra[eo + X_HEAD + n + i] = st[_at(so, n, COLLISION, i)]
        lo = st[_at(so, n, LOWER, i)]
        up = st[_at(so, n, UPPER, i)]
        extra[eo + X_HEAD + 2 * n + i] = lo if lo < math.inf else 0.0
        extra[eo + X_HEAD + 3 * n + i] = up if up < math.inf else 0.0
