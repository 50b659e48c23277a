"""The joint Kalman filter's design: the integrator chain, its exact step, and the process
noise intensity of a stated bandwidth (ROS-free, numpy/scipy, run once per configuration).

**The model.**  Per measured output (a joint's encoder), an integrator chain of order r
(2: white acceleration, 3: white jerk, 4: white snap)::

    x = (q, q', ..., q^(r-1)),   q^(r) = w(t),  E[w w] = qc delta,    y_k = q(t_k) + v_k

with the measurement variance of one sample R = encoder_noise^2 + resolution^2 / 12 (the
encoder's noise and its quantisation, uniform over one step).  Over a step h the chain is
exact in closed form (``chain_step``):

    F_ij = h^(j-i) / (j-i)!                                   (j >= i, else 0)
    Q_ij = qc h^(a+b+1) / ((a+b+1) a! b!),   a = r-1-i, b = r-1-j

(the integral of e^{A s} G qc G' e^{A's} over [0, h], G = e_r): no matrix exponential, no
step-size cache, any h.

**Bandwidth.**  ``bandwidth`` f is the -3 dB frequency of the steady-state filter's
position estimate (the posterior q_k|k) as a response to the measurement, at the nominal
period h0: |H(e^{j 2 pi f h0})| = 1/sqrt(2).  In the continuous limit (f h0 -> 0) the
steady-state filter's poles are Butterworth of radius w0 = (qc / (R h0))^(1/(2r)) (the
return-difference equality: Delta(s) Delta(-s) = (-1)^r s^(2r) + qc / (R h0), R h0 the
measurement's spectral density), the position response is H(s) = 1 - s^r / Delta(s), and
its -3 dB frequency is c_r w0 with c_2 = 2.0582, c_3 = 2.8312, c_4 = 3.6548
(:func:`butterworth_ratio`).  Hence the closed form

    qc = R h0 (2 pi f / c_r)^(2r)                                     (continuous limit)

and at the nominal rate ``process_intensity`` solves the discrete filter for the factor
mu(f h0) = qc / (closed form) that gives exactly f (mu -> 1 as f h0 -> 0; r = 3:
1.0066 at f h0 = 0.001, 1.068 at 0.01, 1.378 at 0.05).  In units where time is measured in
h0 and q in sqrt(R), the filter depends on qc h0^(2r-1) / R alone, so mu depends only on
r and f h0.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solve_discrete_are
from scipy.optimize import brentq

from ...core.errors import ConfigError

ORDERS = (2, 3, 4)
#: the highest bandwidth accepted, as a fraction of the nominal rate
MAX_BANDWIDTH_FRACTION = 0.3
_HALF = 2.0 ** -0.5
_GRID = np.geomspace(1e-7, math.pi, 600)


def chain_step(r: int, h: float, qc: float) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of the chain of order r over h with white-noise intensity qc on q^(r)."""
    F = np.zeros((r, r))
    Q = np.zeros((r, r))
    for i in range(r):
        for j in range(i, r):
            F[i, j] = h ** (j - i) / math.factorial(j - i)
    for i in range(r):
        for j in range(r):
            a, b = r - 1 - i, r - 1 - j
            Q[i, j] = qc * h ** (a + b + 1) / ((a + b + 1) * math.factorial(a) * math.factorial(b))
    return F, Q


def butterworth_ratio(r: int) -> float:
    """c_r: the -3 dB frequency of the continuous steady-state position response
    1 - s^r / Delta(s) over the Butterworth radius w0 (Delta the Butterworth polynomial)."""
    poles = [np.exp(1j * np.pi * (2 * k + r - 1) / (2 * r)) for k in range(1, r + 1)]
    D = np.real(np.poly(poles))

    def gain(x):
        return abs(1.0 - (1j * x) ** r / np.polyval(D, 1j * x)) - _HALF
    xs = np.geomspace(0.1, 20.0, 2001)
    g = np.array([gain(x) for x in xs])
    i = int(np.where(g >= 0)[0].max())
    return float(brentq(gain, xs[i], xs[i + 1], xtol=1e-14))


C_R = {r: butterworth_ratio(r) for r in ORDERS}


def steady_state(r: int, h: float, qc: float, R: float) -> tuple[np.ndarray, np.ndarray]:
    """(P_pred, K): the steady-state prior covariance and gain of the filter at step h."""
    F, Q = chain_step(r, h, qc)
    C = np.zeros((1, r))
    C[0, 0] = 1.0
    P = solve_discrete_are(F.T, C.T, Q, np.array([[R]]))
    P = 0.5 * (P + P.T)
    return P, P[:, 0] / (P[0, 0] + R)


def position_response(r: int, h: float, qc: float, R: float):
    """theta -> |H(e^{j theta})| of the steady-state posterior position estimate's response
    to the measurement (theta = omega h), vectorised."""
    F, _ = chain_step(r, h, qc)
    _, K = steady_state(r, h, qc, R)
    A = (np.eye(r) - np.outer(K, np.eye(r)[0])) @ F
    w, V = np.linalg.eig(A)
    cv = V[0]
    vk = np.linalg.solve(V, K)

    def gain(theta):
        z = np.exp(1j * np.atleast_1d(np.asarray(theta, dtype=float)))
        return np.abs((cv * vk / (1.0 - w / z[:, None])).sum(axis=1))
    return gain


def minus3db(r: int, h: float, qc: float, R: float) -> float:
    """The -3 dB frequency (Hz) of the steady-state position response at step h; inf when
    the response stays above 1/sqrt(2) up to the Nyquist frequency."""
    gain = position_response(r, h, qc, R)
    g = gain(_GRID)
    above = np.where(g >= _HALF)[0]
    if above.size == 0:
        return _GRID[0] / (2 * math.pi * h)
    i = int(above.max())
    if i == _GRID.size - 1:
        return math.inf
    th = brentq(lambda x: gain(x)[0] - _HALF, _GRID[i], _GRID[i + 1], xtol=1e-15)
    return th / (2 * math.pi * h)


def closed_form_intensity(r: int, bandwidth: float, R: float, h0: float) -> float:
    """qc = R h0 (2 pi f / c_r)^(2r): the continuous-limit relation."""
    return R * h0 * (2 * math.pi * bandwidth / C_R[r]) ** (2 * r)


def process_intensity(r: int, bandwidth: float, R: float, h0: float,
                      parameter: str = "joint_kalman.bandwidth") -> float:
    """qc whose steady-state filter at the nominal period h0 has its -3 dB position
    bandwidth at ``bandwidth`` (Hz), to 1e-9 relative; ConfigError naming ``parameter``
    when that bandwidth is out of reach."""
    if not 0.0 < bandwidth * h0 <= MAX_BANDWIDTH_FRACTION:
        raise ConfigError(parameter, f"{bandwidth:g} Hz: must be in (0, "
                          f"{MAX_BANDWIDTH_FRACTION / h0:g}] Hz ({MAX_BANDWIDTH_FRACTION:g} of "
                          f"the nominal rate {1 / h0:g} Hz)")
    # in units of h0 and sqrt(R) (the module doc): R = 1, h = 1
    qc = closed_form_intensity(r, bandwidth * h0, 1.0, 1.0)
    for _ in range(60):
        f3 = minus3db(r, 1.0, qc, 1.0)
        if not math.isfinite(f3) or f3 <= 0.0:
            break
        ratio = bandwidth * h0 / f3
        if abs(ratio - 1.0) < 1e-10:
            return qc * R / h0 ** (2 * r - 1)
        qc *= ratio ** (2 * r)
    raise ConfigError(parameter, f"{bandwidth:g} Hz: no process noise gives the order-{r} "
                      f"filter this bandwidth at {1 / h0:g} Hz")


def measurement_variance(noise: float, resolution: float) -> float:
    """R = noise^2 + resolution^2 / 12 (one sample)."""
    return noise * noise + resolution * resolution / 12.0
