"""Naive reference of ``global_norm`` (Astolfi & Praly 2005, the full-order observer (85)
with the norm estimator (11) and the gains (79)), against the package through the runner at
every sample, from its transient on: config/van_der_pol_global_norm.yaml (x_hat(0) =
(10, -10), w0 = 1, gamma_1 = y^2, gamma_hat = 4 + 4 w, a_i = c_i gamma_hat, c = (80, 6)).

    xh_i' = xh_{i+1} - k_i(w) (y - xh_0)          i < n
    xh_n' = -k_n(w) (y - xh_0) + gh(w) sat(f_n(y, xh_1..xh_n) / gh(w))
    w'    = -w + gamma_1(y)
    (I + L) k = (-a_0, a_1^2, ..., (-a_n)^(n+1)),  L_ij = (-a_i)^(i-j) (j < i)   (79)

with the sign of the error dynamics (80), e_i' = k_i e_0 + e_{i+1} (docs/global_norm.md: eq.
(85) prints the other sign convention).  The reference integrates this ODE (Radau,
rtol 1e-12) driven by the plant's exact continuous output (naive_chain.vdp_output).

Tolerance: the package samples y at 1 kHz and steps the observer with the gains frozen at
the step's middle, y interpolated (the quadratic through the last three samples) and the
model term by Heun: a second-order scheme.  naive_chain.richardson holds its error to its
own Richardson estimate from a run at twice the rate (x 1.25 for the O(h^3) rest) and
checks the order.  The reference's own error (rtol 1e-12) is below 1e-9 of the scale,
far under the scheme's.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

import naive_chain as CH

FAMILY = "global_norm"
FORMS = ("full",)
C = (80.0, 6.0)


def gamma_hat(w):
    return 4.0 + 4.0 * w


def gains_79(a):
    """k of (79) by forward substitution: sum_{j<i} (-a_i)^(i-j) k_j + k_i = (-a_i)^(i+1)."""
    k = np.zeros(len(a))
    for i, ai in enumerate(a):
        k[i] = (-ai) ** (i + 1) - sum((-ai) ** (i - j) * k[j] for j in range(i))
    return k


def f_n(y, x1):
    return (1 - y * y) * x1 - y


class Reference:
    def __init__(self, t0, x0_hat, w0, t_end):
        self.sol_y = CH.vdp_output(t_end)
        self.t0 = t0
        y = lambda s: self.sol_y(s - t0)[0]

        def rhs(s, z):
            x0, x1, w = z
            gh = gamma_hat(w)
            k = gains_79([C[0] * gh, C[1] * gh])
            e = y(s) - x0
            return [x1 - k[0] * e,
                    -k[1] * e + gh * np.clip(f_n(y(s), x1) / gh, -1.0, 1.0),
                    -w + y(s) ** 2]
        self.sol = solve_ivp(rhs, (t0, t0 + t_end), [*x0_hat, w0], method="Radau", rtol=1e-12,
                             atol=1e-12, dense_output=True)

    def output(self, t):
        return self.sol_y(np.asarray(t) - self.t0)[0]

    def __call__(self, t):
        return self.sol.sol(np.asarray(t))[:2].T


def test_global_norm_matches_its_naive_reference():
    flat = CH.NS.flat_params("van_der_pol_global_norm")
    assert list(flat["global_norm.c"]) == list(C) and flat["global_norm.form"] == "full"
    ref = Reference(0.5, flat["observer.initial_estimate"], flat["global_norm.w0"], 0.31)
    CH.richardson("global_norm (van der Pol)", flat, ref, 0.5, 301, 1000)


def test_the_naive_gains_make_the_frozen_error_matrix_hurwitz():
    """(79) for n_states 2: k = (-a0, a1 (a1 - a0)), the error matrix [[k0, 1], [k1, 0]]
    has eigenvalues -a1 and -(a0 - a1) (docs/global_norm.md)."""
    a0, a1 = 640.0, 48.0
    k = gains_79([a0, a1])
    assert np.allclose(k, [-a0, a1 * (a1 - a0)])
    eig = np.sort(np.linalg.eigvals(np.array([[k[0], 1.0], [k[1], 0.0]])).real)
    assert np.allclose(eig, np.sort([-a1, -(a0 - a1)]))
