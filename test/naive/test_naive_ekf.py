"""Naive reference of ``ekf`` (docs/ekf.md; the textbook continuous-discrete extended
Kalman filter), against the package through the runner at every sample.

    x' = f(x, u) + w,  E[w w'] = Qc delta;     y_k = h(x_k) + v_k,  E[v v'] = R

- prediction over each sample interval, in k = ceil(h / max_step) equal sub-steps, each
  the local linearisation at the sub-step's start with the input held (u of the previous
  sample): A = df/dx,
      x+ = x + (int_0^dt e^{A s} ds) f(x, u)     (expm of [[A, f], [0, 0]] dt)
      P+ = Phi P Phi' + Qd,  Phi = e^{A dt},  Qd = int_0^dt e^{A s} Qc e^{A' s} ds
                                                 (Van Loan: expm of [[-A, Qc], [0, A']] dt)
- correction: nu = y - h(x), S = H P H' + R, K = P H' S^-1, x += K nu,
  P = (I - K H) P (I - K H)' + K R K' (Joseph);
- the start (initial_state: measurement): x = H^+ y for the linear h = q here (the
  docs' Gauss-Newton from 0 stops after one step), P = H^+ R H^+' + N P0 N', N = I - H^+ H;
  that sample is not an update.

Tolerance 1e-10 of each state's scale: both sides do the same exact arithmetic up to
rounding (the exponentials are accurate to |M dt| n eps ~ 1e-14 at |M dt| <= 0.25, the
Van Loan blocks are built differently here, the mean increment from its own exponential),
and the filter is a contraction on its estimate error while P is at its steady state, so
rounding does not accumulate beyond the 500 samples' sum (< 1e-11).  The gain K = P H' / S
is a ratio of quantities of R's size (1e-6): its relative rounding is a few eps whatever R.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

import naive_ekf as NE
import naive_plants as NP
import naive_support as NS

FAMILY = "ekf"
FORMS = ("ekf",)
TOL = 1e-10


@pytest.mark.parametrize("max_step", [0.01, 0.0004])
def test_ekf_matches_its_naive_reference(max_step):
    # irregular stamps 0.8-1.3 ms apart; max_step 0.4 ms splits each into 2-4 sub-steps
    t = NS.times(0.5, 500, 1000, jitter_us=(-200, 0, 0, 300), seed=5)
    t, x, y, u = NP.dc_motor_stream(t)
    flat = NS.flat_params("dc_motor_plant", "dc_motor_ekf", ekf__max_step=max_step)
    Qc = np.diag(flat["ekf.process_noise"])
    R = np.diag(flat["ekf.measurement_noise"])
    P0 = np.diag(flat["ekf.initial_covariance"])
    H = np.array([[1.0, 0.0, 0.0]])
    ref = NE.ekf_reference(t, y, u, Qc, R, P0, max_step, NE.dc_f, NE.dc_jacobian, H)
    est, _, _ = NS.run(flat, t, y, u)
    NS.assert_close(f"ekf (max_step {max_step})", est, ref, TOL)
    assert np.abs(ref[:, 1] - ref[0, 1]).max() > 1.0       # a transient from q_dot = 0


def test_the_naive_prediction_is_the_exact_step_of_a_linear_plant():
    """On x' = A x + b (affine), the linearised step is exact: against expm of the whole
    affine system, and the covariance against a fine quadrature of its integral."""
    A = np.array([[0.0, 1.0], [-4.0, -0.4]])
    b = np.array([0.3, -1.0])
    x0, P0, Qc, dt = np.array([1.0, -2.0]), np.diag([0.5, 0.2]), np.diag([0.0, 0.3]), 0.05
    x1, P1 = NE.predict(x0, P0, None, dt, Qc, lambda x, u: A @ x + b, lambda x, u: A)
    Maff = np.zeros((3, 3))
    Maff[:2, :2], Maff[:2, 2] = A, b
    assert np.allclose(x1, (expm(Maff * dt) @ np.append(x0, 1.0))[:2], rtol=1e-13, atol=1e-14)
    s = np.linspace(0.0, dt, 4001)
    Qd = np.trapezoid([expm(A * si) @ Qc @ expm(A * si).T for si in s], s, axis=0)
    Phi = expm(A * dt)
    assert np.allclose(P1, Phi @ P0 @ Phi.T + Qd, rtol=1e-6, atol=1e-12)
