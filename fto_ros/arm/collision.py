"""The design side of collision detection on external-torque estimates (ROS-free): the
threshold for a false-alarm bound and the guaranteed detection time. The detection itself
runs in the estimators' compiled kernels (:mod:`.detect`).

**Threshold.** In free motion the estimate of joint i is noise of standard deviation sigma_i
(in radians of encoder noise once divided by the estimator's noise scale, which follows
M(q)). One test per joint and sample fails with probability ``2 Q(z)`` for a Gaussian
residual, whatever the correlation between samples, so by the union bound a run of an hour
at ``rate`` with n joints raises at most ``3600 rate n 2 Q(z)`` false alarms on average:
``z = Q^-1(bound / (2 3600 rate n))`` (1e-2 per hour, 7 joints at 1 kHz: z = 6.26).

**Detection time.** For an estimator whose response to a step of size Delta is
Delta F(elapsed) (the window estimator: F = K(elapsed / T); the momentum observer:
1 - exp(-K_O elapsed)), a step with |Delta_i| above theta_i is detected on joint i within
F^-1((theta_i + z_miss sigma_i) / |Delta_i|) with probability at least 1 - miss
(:func:`detection_time`).
"""
from __future__ import annotations

import math

from scipy.stats import norm

from ..core.errors import ConfigError


def threshold_sigmas(false_alarms_per_hour: float, rate: float, n_joints: int) -> float:
    """z such that n joints tested at ``rate`` give at most ``false_alarms_per_hour``."""
    if not (false_alarms_per_hour > 0 and rate > 0 and n_joints >= 1):
        raise ConfigError("collision.false_alarms_per_hour", "the bound, the rate and the "
                          "number of joints must be > 0")
    return float(norm.isf(false_alarms_per_hour / (2 * 3600 * rate * n_joints)))


def detection_time(step_response, size: float, threshold: float, sigma: float,
                   miss: float = 1e-3, horizon: float = 1.0) -> float:
    """Smallest elapsed time after which a step of ``size`` is seen above ``threshold`` with
    probability at least 1 - miss (inf if never within ``horizon`` s)."""
    need = (threshold + norm.isf(miss) * sigma) / abs(size)
    if need >= step_response(horizon):
        return math.inf
    lo, hi = 0.0, horizon
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if step_response(mid) < need else (lo, mid)
    return hi
