"""Naive reference of ``prescribed_time`` (Holloway & Krstic 2019) against the package
through the runner at every sample: Example 1, the double integrator
(config/double_integrator_plant.yaml + double_integrator_prescribed_time.yaml, T shortened
to 0.5 s so that 1.3 windows take 650 samples; mode restart).

The observer (7), x_hat' = A x_hat - a y + b u + g(t - t0, T) (y - x_hat_1), with the gains
(22)-(23) from the recursion (18)-(21) for p_bar (for n = 2 the paper's own g1, g2 of
Example 1, checked below), is a linear ODE driven by y and u; the plant, x' = A x - a y + b u
with y = x_1, is driven by the same u.  Their difference e = x - x_hat obeys the error
system (8)-(9), e' = A e - g(t - t0, T) e_1, which the reference integrates as the ODE it
is (scipy's Radau, stiff: the gains grow like (T - t)^-n, rtol 1e-12) over each window and
publishes x_hat = x - e at the samples, x the plant's exact state (u held: x1 + x2 h +
u h^2 / 2).  The window starts at the first sample with x_hat = 0 (the paper's Example 1)
and, in mode restart, again at its end T from the estimate there.  The gains are infinite
at T itself: the sample at T takes e at T (1 - 1e-9), where e = O((T - t)^2) (measured
8e-4 (T - t)^2 / (1 ms)^2 here): 2e-16.

For n = 2 the package's step is the exact solution of (7) for this y (docs/prescribed_time.md:
the residual of the double integrator is linear in time between samples), so the two
differ by rounding and the reference's integration error only.  Tolerance 1e-9 of each
state's scale: Radau's local error control at rtol 1e-12 relative to |e| (at most 36, the
state's scale 40), over one window of a contracting system (the error dynamics only
decay: the global error is not more than the sum of the local ones, < 1e3 steps x 1e-12).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import naive_support as NS

FAMILY = "prescribed_time"
FORMS = ("restart",)
TOL = 1e-9
T_WINDOW = 0.5


def p_bar(n: int, m: int, T: float) -> np.ndarray:
    """p_bar (1-based in the paper, 0-based here) by (18)-(21)."""
    P = np.zeros((n + 2, n + 2))
    for i in range(1, n + 1):
        P[i, i] = 1.0
    for j in range(n, 1, -1):                        # (21): the last row
        P[n, j - 1] = -(2 * n + m - j) / T * P[n, j]
    for i in range(n - 1, 0, -1):                    # (20), from the rows below
        for j in range(i, 1, -1):
            P[i, j - 1] = -(n + m + i - j) / T * P[i, j] + P[i + 1, j]
    return P


def gains(mu1: float, n: int, m: int, T: float, l, P=None) -> np.ndarray:
    """g_1..g_n by (22)-(23) at mu_1 = T / (T + t0 - t) (P: p_bar, when computed already)."""
    P = p_bar(n, m, T) if P is None else P
    g = np.zeros(n + 1)
    for i in range(1, n + 1):
        if i < n:
            lead = ((n + m + i - 1) / T * P[i, 1] - P[i + 1, 1]) * mu1 ** i
        else:
            lead = (2 * n + m - 1) / T * P[n, 1] * mu1 ** n
        g[i] = l[i - 1] + lead - sum(g[j] * P[i, j] * mu1 ** (i - j) for j in range(1, i))
    return g[1:]


def double_integrator(t, x0, u):
    """The plant x1' = x2, x2' = u at the stamps, u held (exact)."""
    x = [np.asarray(x0, float)]
    for k, h in enumerate(NS.steps(t)):
        x1, x2 = x[-1]
        x.append(np.array([x1 + x2 * h + u[k, 0] * h * h / 2, x2 + u[k, 0] * h]))
    return np.array(x)


def reference(t, x, T, m, l):
    """x_hat at every stamp (the module doc): x - e, e the error system (8)-(9) over each
    window."""
    n = 2
    s_us = np.round((t - t[0]) * 1e6).astype(np.int64)
    T_us = round(T * 1e6)
    P = p_bar(n, m, T)

    def jac(s, e):
        g = gains(T / (T - s), n, m, T, l, P)
        return np.array([[-g[0], 1.0], [-g[1], 0.0]])
    out = np.empty_like(x)
    start, e0 = 0, x[0] - np.zeros(n)                 # x_hat = 0 at the first sample
    while start < len(t):
        stop = start + int(np.searchsorted(s_us[start:] - s_us[start], T_us, side="right"))
        ts = (s_us[start:stop] - s_us[start]) * 1e-6
        ts[ts >= T] = T * (1 - 1e-9)                  # the sample at T itself
        sol = solve_ivp(lambda s, e: jac(s, e) @ e, (0.0, ts[-1]), e0, method="Radau", jac=jac,
                        t_eval=ts, rtol=1e-12, atol=1e-12 * np.abs(x).max())
        out[start:stop] = x[start:stop] - sol.y.T
        if stop < len(t) and ts[-1] < T * (1 - 2e-9):
            raise AssertionError("a window ended before T")
        # mode restart: the next window starts at the sample at T, from its estimate
        start, e0 = stop - 1, sol.y[:, -1]
        if stop == len(t):
            break
    return out


def test_prescribed_time_matches_its_naive_reference():
    T, m, l = T_WINDOW, 1, [1.0, 1.0]
    t = NS.times(0.5, 651, 1000)
    u = (np.sin(10 * t) + np.cos(t))[:, None]          # Example 1's input, held at 1 kHz
    x = double_integrator(t, [20.0, 1.0], u)
    flat = NS.flat_params("double_integrator_prescribed_time",
                          prescribed_time__T=T)
    assert (flat["prescribed_time.m"], list(flat["prescribed_time.l"])) == (m, l)
    assert flat["prescribed_time.mode"] == "restart"
    ref = reference(t, x, T, m, l)
    est, _, _ = NS.run(flat, t, x[:, :1], u)
    NS.assert_close("prescribed_time (Example 1, T = 0.5 s)", est, ref, TOL)
    # the transient is compared: the error is O(1) for most of the first window, exact at T
    assert np.abs(ref[100] - x[100]).max() > 1.0
    assert np.abs(ref[500] - x[500]).max() < 1e-9 * np.abs(x).max()


@pytest.mark.parametrize("m", [1, 2, 5])
def test_the_gain_recursion_gives_example_1s_gains(m):
    """(18)-(23) for n = 2 against the paper's closed form of Example 1."""
    T, l1, l2 = 5.0, 1.0, 1.0
    for mu in (1.0, 3.0, 1e3):
        g1 = l1 + 2 * (m + 2) / T * mu
        g2 = l2 + l1 * (m + 2) / T * mu + (m + 1) * (m + 2) / T ** 2 * mu ** 2
        assert np.allclose(gains(mu, 2, m, T, [l1, l2]), [g1, g2], rtol=1e-14)
