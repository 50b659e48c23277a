"""Naive reference of ``joint_kalman`` (docs/joint_kalman.md), every order, against the
package through the runner at every sample.

    x = (q, q', ..., q^(r-1)),  q^(r) = w,  E[w w] = qc delta;   y_k = q(t_k) + v_k,  var R

- R = encoder_noise^2 + resolution^2 / 12;
- qc from the bandwidth f as the docs define it: the -3 dB frequency of the steady-state
  filter's posterior position response at the nominal period h0.  Here: the steady state by
  iterating the Riccati recursion at h0 to its fixed point (no Riccati solver), the
  response |C (I - (I - K C) F / z)^-1 K| at z = e^{j w h0} by a complex solve per frequency,
  its -3 dB crossing by bisection on the frequency, and qc by bisection on log qc;
- every step: F = expm(A h) and Q by Van Loan (expm of [[-A, G qc G'], [0, A']] h), computed
  afresh; P = F P F' + Q; nu = y - q, s = P00 + R, K = P e1 / s; Joseph form;
- the start: q = y with variance R, the derivatives 0 with the initial covariance
  (1, 1e2, 1e4, 1e6), that sample not an update.

Tolerance 1e-10 of each state's scale.  The two qc agree to about 1e-10 relative (the
bisection stops at 1e-12, the package's own design at 1e-10), which moves the gain, hence
the estimate, by less; the float exponential's Van Loan block loses the smallest entries of Q
(h^(2r-1) qc against h qc: a relative 1e-16 of the largest), which the filter's own
covariance dominates.  Measured: 9.0e-13 (order 2), 3.8e-12 (order 3), 6.0e-12 (order 4).  A
wrong hold, step or gain moves the estimate by orders of magnitude more (> 1e-5).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

import naive_support as NS

FAMILY = "joint_kalman"
FORMS = ("order 2", "order 3", "order 4")
TOL = 1e-10


def chain(r: int, h: float, qc: float):
    """(F, Q) of the chain over h: expm and Van Loan."""
    A = np.diag(np.ones(r - 1), 1)
    G = np.zeros((r, r))
    G[-1, -1] = qc
    E = expm(np.block([[-A, G], [np.zeros((r, r)), A.T]]) * h)
    F = E[r:, r:].T
    return F, F @ E[:r, r:]


def steady_gain(r: int, h0: float, qc: float, R: float) -> np.ndarray:
    """K of the Riccati recursion's fixed point at the period h0."""
    F, Q = chain(r, h0, qc)
    P = np.eye(r)
    for _ in range(200000):
        post = P - np.outer(P[:, 0], P[0, :]) / (P[0, 0] + R)
        nxt = F @ post @ F.T + Q
        if np.allclose(nxt, P, rtol=1e-14, atol=0):
            P = nxt
            break
        P = nxt
    return P[:, 0] / (P[0, 0] + R)


def minus3db(r, h0, qc, R):
    """The -3 dB frequency of the steady-state posterior position response."""
    F, _ = chain(r, h0, qc)
    K = steady_gain(r, h0, qc, R)
    M = (np.eye(r) - np.outer(K, np.eye(r)[0])) @ F

    def gain(f):
        z = np.exp(1j * 2 * math.pi * f * h0)
        return abs(np.linalg.solve(np.eye(r) - M / z, K)[0])
    lo, hi = 1e-3, 0.5 / h0
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if gain(mid) >= 2 ** -0.5 else (lo, mid)
        if hi / lo - 1 < 1e-13:
            break
    return math.sqrt(lo * hi)


def intensity(r, f, R, h0):
    """qc of the bandwidth f: bisection on log qc (the -3 dB frequency grows with qc),
    bracketed by the docs' continuous-limit relation qc = R h0 (2 pi f / c_r)^(2r) times
    1e-3 and 1e3 (c_r < 4)."""
    lo, hi = R * h0 * (2 * math.pi * f / 4) ** (2 * r) * 1e-3, \
        R * h0 * (2 * math.pi * f / 2) ** (2 * r) * 1e3
    assert minus3db(r, h0, lo, R) < f < minus3db(r, h0, hi, R)
    for _ in range(300):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if minus3db(r, h0, mid, R) < f else (lo, mid)
        if hi / lo - 1 < 1e-12:
            break
    return math.sqrt(lo * hi)


def reference(t, y, r, qc, R):
    P = np.diag([R, 1e2, 1e4, 1e6][:r])
    x = np.zeros(r)
    x[0] = y[0]
    out = [x.copy()]
    for h, yk in zip(NS.steps(t), y[1:]):
        F, Q = chain(r, h, qc)
        x, P = F @ x, F @ P @ F.T + Q
        s = P[0, 0] + R
        K = P[:, 0] / s
        x = x + K * (yk - x[0])
        L = np.eye(r) - np.outer(K, np.eye(r)[0])
        P = L @ P @ L.T + R * np.outer(K, K)
        out.append(x.copy())
    return np.array(out)


@pytest.mark.parametrize("order,bandwidth", [(2, 230.0), (3, 60.0), (4, 40.0)])
def test_joint_kalman_matches_its_naive_reference(order, bandwidth):
    # irregular stamps 0.8-1.3 ms apart, a smooth motion with reversals, noise and
    # quantisation as an encoder's
    t = NS.times(0.5, 800, 1000, jitter_us=(-200, 0, 0, 300), seed=order)
    rng = np.random.default_rng(order)
    res = 2.0 ** -18
    y = 0.3 * np.sin(2.0 * t) + 0.1 * np.cos(5.3 * t) + 1e-5 * rng.standard_normal(t.size)
    y = np.round(y / res) * res
    flat = NS.flat_params("msd_plant", "msd_joint_kalman", joint_kalman__order=order,
                          joint_kalman__bandwidth=[bandwidth],
                          joint_kalman__resolution=[res])
    R = flat["joint_kalman.encoder_noise"][0] ** 2 + res ** 2 / 12
    qc = intensity(order, bandwidth, R, flat["joint_kalman.sample_period"])
    ref = reference(t, y, order, qc, R)
    est, _, _ = NS.run(flat, t, y[:, None])
    NS.assert_close(f"joint_kalman (order {order})", est, ref, TOL)
    # the run moves: the velocity swings by more than 0.5
    assert np.ptp(ref[:, 1]) > 0.5


def test_the_naive_design_is_what_the_docs_say():
    """The continuous-limit relation of the docs, qc = R h0 (2 pi f / c_r)^(2r), within
    1 % of the naive bisection at f h0 = 1e-3 (c_r from the docs)."""
    R, h0, f = 1e-10, 1e-3, 1.0
    for r, c in ((2, 2.0582), (3, 2.8312), (4, 3.6548)):
        closed = R * h0 * (2 * math.pi * f / c) ** (2 * r)
        assert abs(intensity(r, f, R, h0) / closed - 1) < 0.01
