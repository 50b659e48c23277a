"""Naive reference of ``hosm`` (Fridman, Levant & Davila 2007), against the package through
the runner at every sample: the paper's Example 1 (Section 6.1; config/fld_example1_hosm.yaml:
strongly observable, unstable, 4 states, the unknown input identified with k = 1).

    plant      x' = A x + D zeta(t),  y = C x,  zeta = cos 0.5t + 0.5 sin t + 0.5,
               x(0) = (1, 0, 1, 1)
    (11)       z' = A z + L (y - C z)                     (Luenberger part, L = (5, 5, 5, 5))
    (16)/(35)  v = the differentiator of order r + k = 5 on ytil = y - C z (|ytil^(6)| <= M)
    (14)       x_hat = z + P~^-1 (v_0..v_3),  P~ = [C (A - LC)^j], j = 0..3
    (29)       zeta_hat = (v_4 - C (A - LC)^4 P~^-1 (v_0..v_3)) / (C A^3 D)

Discretisation (docs/hosm.md): the output error ytil first-order held between samples, the
Luenberger step exact and implicit in z (z_k+1 from (I + G1 L C) z_k+1 = Phi z_k +
G0 L ytil_k + G1 L y_k+1, G0, G1 the hold matrices of expm of the augmented system); z
starts at C^+ y_0; the differentiator (naive_differentiator.py: eigenvalue-matched,
rho = 1 from the config) starts at ytil_0 = 0.

Tolerance, from the conditioning of the differentiator (docs/differentiator.md, the float
floor): the rounding of its input (eps |y|) reaches its i-th derivative of an N-chain as
about r^i (eps |y|)^((N-i)/N) (r the pole scale, 1 here), so two implementations that round
differently agree on v_i only to that: x_hat (through v_3, and P~^-1's entries up to
|A - LC|^3 ~ 1e2) to 1e2 (eps |y|)^(1/2), zeta_hat (through v_4) to (eps |y|)^(1/3), |y| <=
3 over the run: TOL_X = 2.6e-6, TOL_ZETA = 8.7e-6 of the states' scales (a bound for a
converged run, where ytil is at its rounding level; in this first second ytil is far above
it and the two agree to 1.3e-13 and 1.6e-13, measured and printed).
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm

import naive_differentiator as ND
import naive_support as NS

FAMILY = "hosm"
FORMS = ("strongly_observable+identification",)
A = np.array([[0.0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [6, 5, -5, -5]])
C = np.array([[1.0, 0, 0, 0]])
D = np.array([[0.0], [0], [0], [1]])
L = np.array([[5.0], [5], [5], [5]])
Y_MAX = 3.0
TOL_X = 1e2 * (NS.EPS * Y_MAX) ** 0.5
TOL_ZETA = (NS.EPS * Y_MAX) ** (1 / 3)


def zeta(t):
    return np.cos(0.5 * t) + 0.5 * np.sin(t) + 0.5


def plant(t):
    sol = solve_ivp(lambda s, x: A @ x + D[:, 0] * zeta(s), (t[0], t[-1]), [1.0, 0, 1, 1],
                    method="DOP853", rtol=1e-13, atol=1e-13, t_eval=t)
    return sol.y.T


def hold_matrices(Am, Bm, h):
    """(Phi, G0, G1): x(h) = Phi x0 + G0 v0 + G1 v1 for v linear from v0 to v1."""
    n, m = Bm.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n], M[:n, n:n + m], M[n:n + m, n + m:] = Am, Bm, np.eye(m)
    E = expm(M * h)
    return E[:n, :n], E[:n, n:n + m] - E[:n, n + m:] / h, E[:n, n + m:] / h


def reference(t, y, M, k, rho):
    r = 4
    Acl = A - L @ C
    P = np.vstack([C @ np.linalg.matrix_power(Acl, j) for j in range(r)])
    Pi = np.linalg.inv(P)
    G = C @ np.linalg.matrix_power(Acl, r) @ Pi
    Q = (C @ np.linalg.matrix_power(A, r - 1) @ D)[0, 0]
    diff = ND.Differentiator(r + k, M, rho)
    z = np.linalg.pinv(C) @ y[0]
    ytil = float(y[0, 0] - C[0] @ z)
    v = diff.reset(ytil)
    xs, zs = [z + Pi @ v[:r]], [(v[r] - G[0] @ v[:r]) / Q]
    for j, h in enumerate(NS.steps(t)):
        Phi, G0, G1 = hold_matrices(A, L, h)
        z = _luenberger_step(Phi, G0, G1, z, ytil, y[j + 1])
        ytil = float(y[j + 1, 0] - C[0] @ z)
        v = diff.update(h, ytil)
        xs.append(z + Pi @ v[:r])
        zs.append((v[r] - G[0] @ v[:r]) / Q)
    return np.array(xs), np.array(zs)[:, None]


def _luenberger_step(Phi, G0, G1, z, ytil, y_next):
    """z' = A z + L ytil(s), ytil linear from ytil_k to y_k+1 - C z_k+1: implicit in z_k+1
    (G0, G1: the hold matrices of the input L ytil)."""
    rhs = Phi @ z + G0[:, 0] * ytil + G1 @ y_next
    return np.linalg.solve(np.eye(len(z)) + G1 @ C, rhs)


def test_hosm_matches_its_naive_reference():
    flat = NS.flat_params("fld_example1_hosm")
    M, k, rho = flat["hosm.M"][0], flat["hosm.smoothness_order"], flat["hosm.differentiator_rho"]
    assert np.array_equal(np.reshape(flat["hosm.A"], (4, 4)), A)
    assert np.array_equal(np.reshape(flat["hosm.L"], (4, 1)), L)
    assert (M, k, rho) == (1.0, 1, 1.0) and flat["hosm.identify_unknown_input"] is not False
    t = NS.times(0.5, 1001, 1000)
    x = plant(t)
    y = x[:, :1]
    assert np.abs(y).max() <= Y_MAX
    ref_x, ref_zeta = reference(t, y, M, k, rho)
    est, ui, _ = NS.run(flat, t, y)
    transient = slice(0, 150)
    print(f"transient (first 150 ms): x_hat {NS.deviation(est[transient], ref_x[transient])[0]:.3g}"
          f", zeta {NS.deviation(ui[transient], ref_zeta[transient])[0]:.3g}")
    NS.assert_close("hosm x_hat (Example 1)", est, ref_x, TOL_X)
    NS.assert_close("hosm zeta_hat (Example 1)", ui, ref_zeta, TOL_ZETA)
    # the comparison covers the transient: the estimate is far from the state (Example 1
    # converges in ~5 s; its first second is all transient)
    assert np.abs(ref_x[5] - x[5]).max() > 0.1
