"""Naive reference of ``arm_kalman`` (docs/arm.md, "The model-based filter"): the Kalman
filter on x = [q, v, d] written plainly from its equations, against the package through the
runner at every sample.

Over each actual step h (whole microseconds; a gap is predicted in m = ceil(h / 1.5 ms)
equal sub-steps), the torque of the last sample held:
    a = M(q)^-1 (tau - C(q, v) v - g(q) - b v - f_c tanh(v / w) + d)
    q <- q + h v + h^2/2 a,  v <- v + h a,  d <- d
    P <- F P F' + Q,   F = expm(A h),  A = [[0, I, 0], [0, 0, M^-1], [0, 0, 0]],
    Q = integral_0^h expm(A s) G S_d G' expm(A s)' ds,  G = [0; 0; I],  S_d = diag(2 sqrt(
    M_ii(0)))^2 (the default disturbance rate)       (scipy's expm and
    quadrature of the integrand here; the package has the closed forms)
then S = Pqq + R, K = P H' S^-1, x += K (y - q), P = (I - K H) P (I - K H)' + K R K'.
Start: x = [y, 0, 0], P = diag(R, 1, 100). M, C, g from Pinocchio (naive_arm.py).

Tolerance 1e-9 of each value's scale: Pinocchio's terms against the compiled ones (1e-15
relative), the quadrature of Q (Gauss-Legendre, exact for its polynomial integrand) against
the closed forms, the same filter's arithmetic in another order.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm

import naive_arm as NA
import naive_support as NS

FAMILY = "arm_kalman"
FORMS = ("arm_kalman",)
TOL = 1e-9
R = 1e-10 + 3.814697265625e-06 ** 2 / 12


def _transition(Minv, h, n, sd):
    A = np.zeros((3 * n, 3 * n))
    A[:n, n:2 * n] = np.eye(n)
    A[n:2 * n, 2 * n:] = Minv
    G = np.zeros((3 * n, n))
    G[2 * n:] = np.eye(n)
    nodes, weights = np.polynomial.legendre.leggauss(6)
    Q = np.zeros((3 * n, 3 * n))
    for x, w in zip(nodes, weights):
        s = 0.5 * h * (x + 1)
        E = expm(A * s) @ G
        Q += 0.5 * h * w * (E * sd) @ E.T
    return expm(A * h), Q


def reference(arm, t, y, tau):
    N, n = y.shape
    s = np.round((t - t[0]) * 1e6) * 1e-6
    x = np.concatenate([y[0], np.zeros(2 * n)])
    P = np.diag(np.concatenate([np.full(n, R), np.ones(n), np.full(n, 100.0)]))
    X = [x.copy()]
    H = np.hstack([np.eye(n), np.zeros((n, 2 * n))])
    sd = (2.0 * np.sqrt(np.diag(arm.M(np.zeros(n))))) ** 2    # the default rate, squared
    for k in range(1, N):
        h = s[k] - s[k - 1]
        m = max(1, int(np.ceil(h / 1.5e-3 - 1e-9)))
        for _ in range(m):
            dt = h / m
            q, v, d = x[:n], x[n:2 * n], x[2 * n:]
            M = arm.M(q)
            Minv = np.linalg.inv(M)
            rhs = tau[k - 1] - arm.C(q, v) @ v - arm.g(q) - arm.b * v \
                - arm.fc * np.tanh(v / arm.width) + d
            a = Minv @ rhs
            x = np.concatenate([q + dt * v + 0.5 * dt * dt * a, v + dt * a, d])
            F, Q = _transition(Minv, dt, n, sd)
            P = F @ P @ F.T + Q
        S = H @ P @ H.T + R * np.eye(n)
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ (y[k] - x[:n])
        I_KH = np.eye(3 * n) - K @ H
        P = I_KH @ P @ I_KH.T + R * K @ K.T
        X.append(x.copy())
    return np.array(X)


def test_arm_kalman_matches_its_naive_reference():
    arm = NA.Arm()
    t, q, tau = NA.stream(arm, 500, gaps=(200, 201, 380))
    flat = NS.flat_params("arm7_arm_kalman", arm_kalman__initial_velocity_std=1.0,
                          arm_kalman__initial_disturbance_std=10.0)
    est, ui, conv = NS.run(flat, t, q, tau)
    X = reference(arm, t, q, tau)
    n = q.shape[1]
    NS.assert_close("position", est[:, :n], X[:, :n], TOL)
    NS.assert_close("velocity", est[:, n:], X[:, n:2 * n], TOL)
    NS.assert_close("disturbance", ui, X[:, 2 * n:], TOL)
