"""Collision detection on external-torque estimates: per-joint thresholds from the residual's
noise level and a false-alarm bound, hysteresis, the guaranteed detection time (ROS-free).

**Threshold.** In free motion the estimate of joint i is noise of standard deviation sigma_i
(measured over a calibration window at start-up, or given). The window estimator's noise
follows the configuration (its gain is ||a|| ||M_i,:(q)||); divided by that gain (``scale``)
the residual is stationary, of the encoder's noise level, and sigma_i is calibrated on it. One test per joint and sample
fails with probability ``2 Q(z)`` for a Gaussian residual, whatever the correlation between
samples, so by the union bound a run of an hour at ``rate`` with n joints raises at most
``3600 rate n 2 Q(z)`` false alarms on average: ``z = Q^-1(bound / (2 3600 rate n))``
(1e-2 per hour, 7 joints at 1 kHz: z = 6.44). The window test of docs/track.md sums
chi-square terms of independent innovations; an external-torque estimate is a filtered,
strongly correlated signal, for which the union bound holds and the chi-square sum does not.
sigma_i is taken at its upper confidence bound: the calibration's sample RMS over
``chi2.ppf(confidence, nu) / nu``, with nu the calibration's effective number of independent
samples (Bartlett: N / sum of the squared autocorrelations).

**Hysteresis.** A joint fires when |tau_ext_i| > theta_i = z sigma_i; it stays in contact
until |tau_ext_i| < ``release`` theta_i for ``hold`` s, then it is armed again.

**Detection time.** For an estimator whose response to a step of size Delta is
Delta F(elapsed) (the window estimator: F = K(elapsed / T)), a step with |Delta_i| above
theta_i is detected on joint i within F^-1((theta_i + z_miss sigma_i) / |Delta_i|) with
probability at least 1 - miss (:func:`detection_time`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2, norm


def threshold_sigmas(false_alarms_per_hour: float, rate: float, n_joints: int) -> float:
    """z such that n joints tested at ``rate`` give at most ``false_alarms_per_hour``."""
    if not (false_alarms_per_hour > 0 and rate > 0 and n_joints >= 1):
        raise ValueError("false_alarms_per_hour, rate and n_joints must be > 0")
    return float(norm.isf(false_alarms_per_hour / (2 * 3600 * rate * n_joints)))


def effective_samples(x: np.ndarray, max_lag: int = 500) -> float:
    """Bartlett's effective number of independent samples of a correlated series x."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    N = x.size
    var = x @ x / N
    if var == 0 or N < 4:
        return float(N)
    total = 1.0
    for k in range(1, min(max_lag, N // 4)):
        rho = (x[:-k] @ x[k:]) / (N * var)
        total += 2 * rho * rho
    return N / total


def calibrated_sigma(samples: np.ndarray, confidence: float = 1e-3) -> np.ndarray:
    """Per column, the upper confidence bound of the residual's standard deviation."""
    samples = np.atleast_2d(np.asarray(samples, dtype=float))
    rms = np.sqrt(np.mean(samples ** 2, axis=0))
    nu = np.array([effective_samples(col) for col in samples.T])
    return rms * np.sqrt(nu / chi2.ppf(confidence, nu))


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


@dataclass
class Collision:
    """A detection: the time and the joints that fired at it."""
    t: float
    joints: tuple[int, ...]


class CollisionDetector:
    """Per-joint detection on an external-torque estimate (module doc).

    Args:
        n: joints. rate: samples per second (for the bound).
        false_alarms_per_hour: the bound. sigma: the residual's noise level per joint, or
        None to measure it over the first ``calibration`` s of estimates (no contact then).
        release, hold: the hysteresis."""

    def __init__(self, n: int, rate: float = 1000.0, false_alarms_per_hour: float = 1e-2,
                 sigma=None, calibration: float = 2.0, release: float = 0.5, hold: float = 0.05,
                 confidence: float = 1e-3):
        if not (0 < release < 1 and hold >= 0 and calibration > 0):
            raise ValueError("release in (0, 1), hold >= 0, calibration > 0")
        self.n, self.rate = int(n), float(rate)
        self.z = threshold_sigmas(false_alarms_per_hour, rate, n)
        self.false_alarms_per_hour = false_alarms_per_hour
        self.release, self.hold, self.confidence = release, hold, confidence
        self._cal_n = max(8, int(round(calibration * rate)))
        self._cal: list[np.ndarray] = []
        self.sigma = None
        if sigma is not None:
            s = np.broadcast_to(np.asarray(sigma, dtype=float), (self.n,)).copy()
            if not np.all(np.isfinite(s) & (s > 0)):
                raise ValueError(f"sigma: must be finite and > 0, got {sigma!r}")
            self.sigma = s
        self.in_contact = np.zeros(self.n, dtype=bool)
        self._quiet_since = np.full(self.n, math.nan)
        self.detections: list[Collision] = []

    @property
    def threshold(self) -> np.ndarray | None:
        return None if self.sigma is None else self.z * self.sigma

    def update(self, t: float, tau_ext, scale=None) -> Collision | None:
        """Test one estimate; returns the joints that fired now (None: none did).

        ``scale``: the estimate's noise gain per joint at this sample (e.g.
        ``WindowEstimator.noise_gain(q)``, which follows M(q)); the residual is divided by
        it, so sigma and the thresholds are in its units (for the window estimator: radians
        of encoder noise) and the threshold in torque is ``threshold * scale``."""
        r = np.abs(np.asarray(tau_ext, dtype=float).reshape(self.n))
        if scale is not None:
            r = r / np.asarray(scale, dtype=float).reshape(self.n)
        if not np.all(np.isfinite(r)):
            return None
        if self.sigma is None:
            self._cal.append(r.copy())
            if len(self._cal) >= self._cal_n:
                self.sigma = np.maximum(calibrated_sigma(np.array(self._cal), self.confidence),
                                        1e-12)
                self._cal = []
            return None
        theta = self.threshold
        quiet = r < self.release * theta
        for i in np.flatnonzero(self.in_contact):
            if not quiet[i]:
                self._quiet_since[i] = math.nan
            elif math.isnan(self._quiet_since[i]):
                self._quiet_since[i] = t
            elif t - self._quiet_since[i] >= self.hold:
                self.in_contact[i] = False
                self._quiet_since[i] = math.nan
        fired = np.flatnonzero(~self.in_contact & (r > theta))
        if fired.size == 0:
            return None
        self.in_contact[fired] = True
        event = Collision(float(t), tuple(int(i) for i in fired))
        self.detections.append(event)
        return event
