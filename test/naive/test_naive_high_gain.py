"""Naive reference of ``high_gain`` (docs/high_gain.md; the textbook constant-gain high-gain
observer with the model term at clipped estimates, Khalil's practice), against the package
through the runner at every sample, from its transient on:
config/van_der_pol_high_gain.yaml (x_hat(0) = (10, -10), L = 20, M = 5, model_input
measured, alpha the binomial default).

    xh_i' = xh_{i+1} + alpha_i L^(i+1) (y - xh_0)                           i < n
    xh_n' = f_n(y, sat_M(xh_1), .., sat_M(xh_n)) + alpha_n L^(n+1) (y - xh_0)

alpha_i the coefficients of (s + 1)^(n+1) after the leading one (every error pole at -L).
The reference integrates this ODE (Radau, rtol 1e-12) driven by the plant's exact
continuous output (naive_chain.vdp_output).

Tolerance: the package samples y at 1 kHz, interpolates it (the quadratic through the last
three samples), solves the linear part exactly and the model term by Heun: a second-order
scheme, held by naive_chain.richardson to its own Richardson estimate from a run at twice
the rate (x 1.25 for the O(h^3) rest), with the order checked.
"""
from __future__ import annotations

from math import comb

import numpy as np
from scipy.integrate import solve_ivp

import naive_chain as CH

FAMILY = "high_gain"
FORMS = ("measured",)


def f_n(y, x1):
    return (1 - y * y) * x1 - y


class Reference:
    def __init__(self, t0, x0_hat, L, M, t_end):
        self.sol_y = CH.vdp_output(t_end)
        self.t0 = t0
        n = len(x0_hat) - 1
        g = [comb(n + 1, i + 1) * L ** (i + 1) for i in range(n + 1)]
        y = lambda s: self.sol_y(s - t0)[0]

        def rhs(s, z):
            e = y(s) - z[0]
            return [z[1] + g[0] * e, f_n(y(s), np.clip(z[1], -M, M)) + g[1] * e]
        self.sol = solve_ivp(rhs, (t0, t0 + t_end), x0_hat, method="Radau", rtol=1e-12,
                             atol=1e-12, dense_output=True)

    def output(self, t):
        return self.sol_y(np.asarray(t) - self.t0)[0]

    def __call__(self, t):
        return self.sol.sol(np.asarray(t)).T


def test_high_gain_matches_its_naive_reference():
    flat = CH.NS.flat_params("van_der_pol_high_gain")
    L, M = flat["high_gain.L"], flat["high_gain.saturation"]
    assert (L, M) == (20.0, 5.0) and not flat.get("high_gain.alpha")
    ref = Reference(0.5, flat["observer.initial_estimate"], L, M, 0.31)
    # the clipping is active in the transient (|xh_1| > M), then not
    assert np.abs(ref(np.array([0.51]))[0, 1]) > M
    CH.richardson("high_gain (van der Pol)", flat, ref, 0.5, 301, 1000)
