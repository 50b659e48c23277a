"""Naive reference of ``external_torque`` (docs/external_torque.md, the windowed momentum
identity (2) on the actual stamps), against the package through the runner at every sample.

    integral k(u) tau_ext(t - u) du = int k'' M q~ - int k' Mdot q~ + b int k' q~
                                      - int k tau - int k (C^T v - g - f_c tanh(v / w))

k(u) = kappa(u / T) / T, kappa(s) = 30 s^2 (1 - s)^2, T the span of the W + 1 newest samples
(their ages u_j = t - t_j, stamps in whole microseconds); q~ = q - q_newest.

- the weights: on each interval between two nodes, the cubic through the four nodes around
  it (shifted inside at the ends) times the kernel's k'', k' or k, integrated exactly as
  polynomials (numpy.polynomial: no quadrature rule); the held torque of sample j + 1 over
  [u_j, u_j+1] with K(u_j+1 / T) - K(u_j / T), K = kappa's integral;
- the velocities of the terms: the least-squares slope of the 2 m + 1 = 9 positions around
  a sample on their stamps (the first m samples of the run: the slope of the first 9), the
  robust exact differentiator's (naive_differentiator, order 2, L = 300, rho = 2) for the
  m newest;
- M, C, g from Pinocchio (naive_arm.py), Mdot = C + C^T, the URDF's friction;
- the published velocity: the differentiator's; the contact level after the calibration:
  z sigma ||A|| ||M_i,:||, sigma the residual's RMS over its ||A|| ||M_i,:|| at its upper
  confidence bound (naive_arm.levels; the autocorrelation of A on the uniform grid).

Tolerance 1e-9 of each value's scale (max(1, |value|)): the window's sum cancels terms of a
few hundred Nm (the k'' weights of about 300 times M q~) to the estimate, so rounding of
1e-16 relative in the terms leaves about 1e-13 Nm; the differentiator's step differs from
the package's by the order of its sums (1e-15 relative on velocities of 1 rad/s). A wrong
weight, sign, velocity or held torque moves the estimate by far more (1e-3 and up).
"""
from __future__ import annotations

import numpy as np
from numpy.polynomial import Polynomial as Poly

import naive_arm as NA
import naive_support as NS
from naive_differentiator import Differentiator

FAMILY = "external_torque"
FORMS = ("external_torque",)
TOL = 1e-9
W, M_C = 60, 4
KAPPA = [Poly([0, 0, 30, -60, 30]), Poly([0, 60, -180, 120]), Poly([60, -360, 360])]
KINT = Poly([0, 0, 0, 10, -15, 6])


def weights(u):
    """A, B, C (W + 1) and D (W) on the nodes u (module doc), each interval's polynomials in
    its own coordinate x = (u - u_i) / T (exact arithmetic on polynomials of moderate
    coefficients: the product in u itself would cancel digits)."""
    T = u[-1]
    A, B, C = (np.zeros(W + 1) for _ in range(3))
    for i in range(W):
        p = min(max(i - 1, 0), W - 3)
        a = u[i] / T
        nodes = u[p:p + 4] / T - a
        for m in range(4):
            others = np.delete(nodes, m)
            basis = Poly.fromroots(others) / np.prod(nodes[m] - others)
            for out, d in ((C, 0), (B, 1), (A, 2)):
                k = KAPPA[d](Poly([a, 1.0]))            # kappa^(d)(s), s = a + x
                prim = (k * basis).integ()
                out[p + m] += (prim(u[i + 1] / T - a) - prim(0.0)) / T ** d
    D = KINT(u[1:] / T) - KINT(u[:-1] / T)
    return A, B, C, D


def reference(arm, t, q, tau):
    n = q.shape[1]
    N = len(t)
    s = np.round((t - t[0]) * 1e6) * 1e-6                # the runner's model time
    red = [Differentiator(2, 300.0, 2.0) for _ in range(n)]
    v_red = np.zeros((N, n))
    for i in range(n):
        red[i].reset(q[0, i])
    for k in range(1, N):
        h = s[k] - s[k - 1]
        v_red[k] = [red[i].update(h, q[k, i])[1] for i in range(n)]
    v_c = np.full((N, n), np.nan)                        # the centred velocities
    for i in range(N):
        lo = max(i - M_C, 0) if i >= M_C else 0
        tt, qq = s[lo:lo + 2 * M_C + 1], q[lo:lo + 2 * M_C + 1]
        if len(tt) == 2 * M_C + 1:
            d = tt - tt.mean()
            v_c[i] = d @ (qq - qq.mean(axis=0)) / (d @ d)

    def terms(i, v):
        Mi, Ci = arm.M(q[i]), arm.C(q[i], v)
        return Mi, Ci + Ci.T, Ci.T @ v - arm.g(q[i]) - arm.fc * np.tanh(v / arm.width)
    final = [terms(i, v_c[i]) if np.isfinite(v_c[i]).all() else None for i in range(N)]
    E = np.full((N, n), np.nan)
    gains = np.full(N, np.nan)
    for k in range(W, N):
        js = np.arange(k, k - W - 1, -1)                 # newest first
        u = s[k] - s[js]
        A, B, C, D = weights(u)
        gains[k] = np.linalg.norm(A)
        qc = q[k]
        est = np.zeros(n)
        for j, i in enumerate(js):
            Mi, Mdi, phi = final[i] if i <= k - M_C else terms(i, v_red[i])
            qt = q[i] - qc
            est += A[j] * Mi @ qt - B[j] * Mdi @ qt + arm.b * B[j] * qt - C[j] * phi
            if j >= 1:
                est -= D[j - 1] * tau[i]
        E[k] = est
    return E, v_red, gains


def test_external_torque_matches_its_naive_reference():
    arm = NA.Arm()
    t, q, tau = NA.stream(arm, 520, gaps=(200, 201, 400))
    flat = NS.flat_params("arm7_external_torque", collision__calibration=0.2)
    est, ui, conv = NS.run(flat, t, q, tau)
    E, v_red, gains = reference(arm, t, q, tau)
    have = np.isfinite(E).all(axis=1)
    assert have.sum() > 450 and not have[:W].any()
    NS.assert_close("tau_ext", ui[have], E[have], TOL)
    NS.assert_close("velocity", est[:, 7:], v_red, TOL)
    # the contact (lower) levels after the calibration, at every sample after it
    cal = int(round(0.2 * 1000))
    first = int(np.flatnonzero(have)[0])
    scales = np.array([gains[k] * np.linalg.norm(arm.M(q[k]), axis=1) for k in range(len(t))])
    u0 = np.arange(W + 1) * 1e-3
    A0 = weights(u0)[0]
    corr = sum((A0[:-l] @ A0[l:] / (A0 @ A0)) ** 2 for l in range(1, W + 1))
    window = slice(first, first + cal)
    lower, _ = NA.levels(ui[window], scales[window], corr)
    after = np.arange(first + cal, len(t))
    got = conv[after][:, 5 + 3 + 14:5 + 3 + 21]
    NS.assert_close("lower level", got, lower * scales[after], TOL)
