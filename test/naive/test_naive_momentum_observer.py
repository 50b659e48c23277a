"""Naive reference of ``momentum_observer`` (docs/external_torque.md, "The baselines": the
generalized-momentum observer of De Luca et al.) on the actual stamps, against the package
through the runner at every sample.

    r_k = K (p_k - p_0 - I_k),  I_k = I_k-1 + h_k (tau_k-1 + (beta_k-1 + beta_k) / 2 + r_k-1)

p = M(q) v, beta = C(q, v)^T v - g(q) - b v - f_c tanh(v / w), v the backward difference
over the step h_k (whole microseconds); p_0 at the second sample (the first velocity),
r = 0 there, the first residual at the third. M, C, g from Pinocchio (naive_arm.py). The
contact level after the calibration: z sigma g ||M_i,:||, g the norm of the observer's
response to one unit of encoder noise (its recursion on the backward difference, per unit of
||M||, run to its end), sigma at its upper confidence bound with the effective samples of
that response's autocorrelation (naive_arm.levels).

Tolerance 1e-9 of each value's scale: the recursion is the same arithmetic in another order
(Pinocchio's terms against the compiled ones: 1e-15 relative), r = K (p - p_0 - I) cancels
momenta of a few kg m^2/s to a residual K times their difference (about 50 x 1e-15 x 5).
"""
from __future__ import annotations

import numpy as np

import naive_arm as NA
import naive_support as NS

FAMILY = "momentum_observer"
FORMS = ("momentum_observer",)
TOL = 1e-9
K = 50.0


def reference(arm, t, q, tau):
    N, n = q.shape
    s = np.round((t - t[0]) * 1e6) * 1e-6
    r = np.zeros((N, n))
    v = np.zeros((N, n))
    valid = np.zeros(N, bool)
    p0 = I = beta_prev = None
    for k in range(1, N):
        h = s[k] - s[k - 1]
        v[k] = (q[k] - q[k - 1]) / h
        Mk, Ck = arm.M(q[k]), arm.C(q[k], v[k])
        beta = Ck.T @ v[k] - arm.g(q[k]) - arm.b * v[k] - arm.fc * np.tanh(v[k] / arm.width)
        p = Mk @ v[k]
        if k == 1:
            p0, I = p, np.zeros(n)
        else:
            I = I + h * (tau[k - 1] + 0.5 * (beta_prev + beta) + r[k - 1])
            r[k] = K * (p - p0 - I)
            valid[k] = True
        beta_prev = beta
    return r, v, valid


def noise_response(h=1e-3):
    steps = int(40 / (K * h) + 10)
    e = np.zeros(steps)
    e[0] = 1.0
    P = np.diff(np.concatenate(([0.0], e))) / h
    out, integral = np.zeros(steps), 0.0
    for k in range(steps):
        if k:
            integral += h * K * out[k - 1]              # I integrates r = K out
        out[k] = P[k] - integral                      # r / K
    return out


def test_momentum_observer_matches_its_naive_reference():
    arm = NA.Arm()
    t, q, tau = NA.stream(arm, 800, gaps=(300, 650))
    flat = NS.flat_params("arm7_momentum_observer", collision__calibration=0.3)
    est, ui, conv = NS.run(flat, t, q, tau)
    r, v, valid = reference(arm, t, q, tau)
    NS.assert_close("residual", ui[valid], r[valid], TOL)
    NS.assert_close("velocity", est[:, 7:], v, TOL)
    assert np.array_equal(conv[:, 5] > 0.5, valid)
    resp = noise_response()
    gain = np.linalg.norm(resp)
    corr = sum((resp[:-l] @ resp[l:] / (resp @ resp)) ** 2 for l in range(1, min(resp.size - 1, 4000)))
    scales = np.array([K * gain * np.linalg.norm(arm.M(q[k]), axis=1) for k in range(len(t))])
    first = int(np.flatnonzero(valid)[0])
    cal = 300
    window = slice(first, first + cal)
    lower, _ = NA.levels(ui[window], scales[window], corr)
    after = np.arange(first + cal, len(t))
    NS.assert_close("lower level", conv[after][:, 22:29], lower * scales[after], TOL)
