"""Naive reference of ``luenberger`` (docs/luenberger.md; the textbook observer), both
designs, against the package through the runner at every sample.

    x_hat' = A x_hat + B u + F(y) + L (y - C x_hat)

- L by pole placement: Ackermann's formula, L = p(A) O^-1 e_n, O the observability matrix,
  p the characteristic polynomial with the given poles (single output);
- L by the steady-state Kalman filter: P the stabilising solution of the filter Riccati
  equation A P + P A' - P C' R^-1 C P + Q = 0, from the stable invariant subspace of the
  Hamiltonian [[A', -C' R^-1 C], [-Q, -A]] (eigenvectors, no Riccati solver), L = P C' R^-1;
- the start: x_hat = C^+ y at the first sample (the measured state, zeros elsewhere);
- between samples: y and F(y) linear, u held, solved exactly by one expm per step.

Tolerance 1e-10 of each state's scale.  Both sides solve the same linear ODE exactly; they
differ only by rounding, of the exponential (accurate to about |A h| n eps: 1e-14 here,
|A h| <= 0.3) and of the injection L (y - C x), a difference of terms of size |L| |y| that
the step scales by h: eps |L| |y| h per step, 1e-14 for the poles design's |L| = 1.7e5; the
closed loop A - L C is stable, so these per-step errors do not grow, and over the 600 steps
without any decay they sum to < 1e-11 (measured: 3.9e-12 poles, 8.6e-15 Kalman).  The
Kalman gain adds the conditioning of the Riccati solution from the Hamiltonian's
eigenvectors (cond of their upper block: 216, measured): 5e-14 relative on L.  A wrong
formula moves the estimate by orders of magnitude more (a sign, a factor, a hold: > 1e-4).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

import naive_plants as NP
import naive_support as NS

FAMILY = "luenberger"
FORMS = ("poles", "kalman")
TOL = 1e-10


def ackermann_gain(A, C, poles):
    """Observer gain L (n x 1) placing eig(A - L C) at ``poles``: L = p(A) O^-1 e_n."""
    n = A.shape[0]
    O = np.vstack([C @ np.linalg.matrix_power(A, i) for i in range(n)])
    coeffs = np.poly(poles)                        # s^n + c1 s^(n-1) + ... + cn
    pA = sum(c * np.linalg.matrix_power(A, n - i) for i, c in enumerate(coeffs))
    e_n = np.zeros((n, 1))
    e_n[-1, 0] = 1.0
    return pA @ np.linalg.solve(O, e_n)


def kalman_gain(A, C, Q, R):
    """Steady-state Kalman gain from the Hamiltonian's stable invariant subspace."""
    n = A.shape[0]
    Ri = np.linalg.inv(R)
    H = np.block([[A.T, -C.T @ Ri @ C], [-Q, -A]])
    w, V = np.linalg.eig(H)
    stable = V[:, w.real < 0]
    assert stable.shape[1] == n, "the Hamiltonian has no n-dimensional stable subspace"
    X1, X2 = stable[:n], stable[n:]
    P = np.real(X2 @ np.linalg.inv(X1))
    P = (P + P.T) / 2
    residual = A @ P + P @ A.T - P @ C.T @ Ri @ C @ P + Q
    assert np.abs(residual).max() <= 1e-9 * max(1.0, np.abs(P).max()), "Riccati residual"
    return P @ C.T @ Ri


def luenberger_reference(A, B, C, F, L, t, y, u):
    """x_hat at every stamp (see the module doc)."""
    n = A.shape[0]
    h = NS.steps(t)
    x = np.linalg.pinv(C) @ y[0]
    out = [x]
    Acl = A - L @ C
    Bw = np.hstack([B, np.eye(n), L])            # w = (u, F(y), y)
    for k in range(len(t) - 1):
        w0 = np.concatenate((u[k], F(y[k]), y[k]))
        w1 = np.concatenate((u[k], F(y[k + 1]), y[k + 1]))
        x = NS.linear_hold_step(Acl, Bw, x, w0, w1, h[k])
        out.append(x)
    return np.array(out)


def _gain(flat, A, C):
    if flat["luenberger.design"] == "poles":
        return ackermann_gain(A, C, flat["luenberger.poles"])
    return kalman_gain(A, C, np.diag(flat["luenberger.process_noise"]),
                       np.diag(flat["luenberger.measurement_noise"]))


@pytest.mark.parametrize("design,config", [("poles", "dc_motor_luenberger_poles"),
                                           ("kalman", "dc_motor_luenberger")])
def test_luenberger_matches_its_naive_reference(design, config):
    # irregular stamps: 0.8 to 1.3 ms apart (the step cache keyed on every size)
    t = NS.times(0.5, 600, 1000, jitter_us=(-200, 0, 0, 300), seed=3)
    t, x, y, u = NP.dc_motor_stream(t)
    flat = NS.flat_params("dc_motor_plant", config)
    assert flat["luenberger.design"] == design
    A, B, C = NP.dc_motor_linear()
    L = _gain(flat, A, C)
    assert np.max(np.linalg.eigvals(A - L @ C).real) < 0
    ref = luenberger_reference(A, B, C, NP.dc_motor_F, L, t, y, u)
    est, _, _ = NS.run(flat, t, y, u)
    NS.assert_close(f"luenberger ({design})", est, ref, TOL)
    # the run has a transient: the reference moved far from its start
    assert np.abs(ref[:, 1] - ref[0, 1]).max() > 1.0


def test_the_naive_gains_do_what_their_design_says():
    """The reference's own gains: Ackermann's L places the poles; the Kalman L is the
    steady state of the Riccati flow (integrated to convergence with expm of its
    linearisation would be circular: checked instead through P's defining equation and
    the closed loop being stable)."""
    A, B, C = NP.dc_motor_linear()
    poles = [-50.0, -60.0, -70.0]
    got = np.sort(np.linalg.eigvals(A - ackermann_gain(A, C, poles) @ C).real)
    assert np.allclose(got, np.sort(poles), rtol=1e-9)
    L = kalman_gain(A, C, np.diag([1e-6, 0.25, 0.04]), np.diag([1e-9]))
    assert np.max(np.linalg.eigvals(A - L @ C).real) < 0
    # a step of the hold integrator against a fine explicit quadrature of the same ODE
    x0, w0, w1, h = np.array([0.1, 0.2, 0.3]), np.array([1.0, 0, 2, 0, 0.5]), \
        np.array([2.0, 0, 1, 0, -0.5]), 1e-3
    Bw = np.hstack([B, np.eye(3), L])
    got = NS.linear_hold_step(A - L @ C, Bw, x0, w0, w1, h)
    s = np.linspace(0.0, h, 2001)
    Phi = [expm((A - L @ C) * (h - si)) for si in s]
    integrand = np.array([P @ Bw @ (w0 + (w1 - w0) * si / h) for P, si in zip(Phi, s)])
    want = expm((A - L @ C) * h) @ x0 + np.trapezoid(integrand, s, axis=0)
    assert np.allclose(got, want, rtol=1e-6, atol=1e-9)
