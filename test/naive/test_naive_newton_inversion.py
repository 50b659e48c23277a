"""Naive reference of ``newton_inversion`` (Possieri, Vidano & Novara 2020, the filtered
observer (11)), against the package through the runner at every sample, from x_hat = 0 on:
the DC motor in its original coordinates (config/dc_motor_plant.yaml +
config/dc_motor_newton.yaml; the load torque 0).

    O(x) = (q, q_dot, b1 I - a1 sin q - a2 q_dot)   the observability map (y, y', y''),
    J = dO/dx,  G = dO/du_e u_e^(1,n) = 0 (O does not depend on V: no input differentiator)
    eta = (y, y', y'', y''')  Levant's differentiator of order n = 3 on y
                              (naive_differentiator.py, L and rho from the config)
    (11g)  x_hat' = J^-1 (mu |eta~|^alpha sign(eta~) + eta^(1,n) - G),  eta~ = eta^(0,n-1) - O(x_hat)

discretised as docs/newton_inversion.md says, per sample (the differentiator first):
1. feed-forward: x_p = x + J_prev^-1 (h (eta^(1,n)_prev + eta^(1,n)) / 2 - h G_prev)
   (J_prev, G_prev: the map at the previous x_p);
2. the finite-time part by backward Euler: eta~ = eta^(0,n-1) - O(x_p),
   eta~+ = sign(eta~) max(|eta~| - t, 0) entry-wise with t = h mu |eta~+|_2^alpha (the root
   by brentq);
3. one Newton step with J(x_p): x_hat = x_p + J(x_p)^-1 (eta~ - eta~+).
The first sample starts the differentiator at (y_0, 0, 0, 0) and publishes x_hat(0) = 0.

Tolerance 1e-8 of each state's scale, from the differentiator's conditioning: the estimate
is O^-1 of its estimates (the current through eta_2: I = (eta_2 + a1 sin q + a2 q_dot) / b1),
and two implementations of it that round differently differ through the matched gains,
which depend on the innovation e = y - z_0 as |e|^(-1/N): their relative rounding is
eps |y| / (N |e|), 5e-8 at the scheme's own error level |e| ~ h^N L = 1e-9 (N = 4,
L = 1000), on a correction that is about a tenth of eta_2 there; ~5e-9, doubled for the
Newton step's J^-1 (cond(J) = 2 near q = 0): 1e-8.  Measured: 9e-13 (the transient's |e|
is far above that level).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

import naive_differentiator as ND
import naive_plants as NP
import naive_support as NS

FAMILY = "newton_inversion"
FORMS = ("filtered",)
TOL = 1e-8
DC = NP.DC


def obs_map(x):
    """(O, J) of the DC motor (G = 0)."""
    q, qd, i = x
    O = np.array([q, qd, DC["b1"] * i - DC["a1"] * np.sin(q) - DC["a2"] * qd])
    J = np.array([[1.0, 0, 0], [0, 1.0, 0], [-DC["a1"] * np.cos(q), -DC["a2"], DC["b1"]]])
    return O, J


def implicit_flow(e, c, alpha):
    """Backward Euler of e' = -mu |e|_2^alpha sign(e) over h, c = h mu."""
    a = np.abs(e)
    if a.max() == 0.0:
        return np.zeros_like(e)

    def phi(t):
        return t - c * np.linalg.norm(np.maximum(a - t, 0.0)) ** alpha
    if phi(a.max()) <= 0.0:                       # the flow reaches 0 within the step
        return np.zeros_like(e)
    t = brentq(phi, 0.0, a.max(), xtol=1e-300, rtol=4 * NS.EPS, maxiter=500)
    return np.sign(e) * np.maximum(a - t, 0.0)


def reference(t, y, L, rho, mu, alpha):
    n = 3
    diff = ND.Differentiator(n, L, rho)
    eta = diff.reset(y[0, 0])
    x = np.zeros(n)
    O, J = obs_map(x)
    out = [x]
    for k, h in enumerate(NS.steps(t)):
        eta_prev = eta
        eta = diff.update(h, y[k + 1, 0])
        xp = x + np.linalg.solve(J, 0.5 * h * (eta_prev[1:] + eta[1:]))
        O, J = obs_map(xp)
        e = eta[:n] - O
        x = xp + np.linalg.solve(J, e - implicit_flow(e, h * mu, alpha))
        out.append(x)
    return np.array(out)


def test_newton_inversion_matches_its_naive_reference():
    flat = NS.flat_params("dc_motor_plant", "dc_motor_newton")
    assert (flat["newton_inversion.variant"], flat["newton_inversion.scheme"]) == \
        ("filtered", "eigenvalue_matched")
    assert not flat.get("newton_inversion.delay") and not flat.get("newton_inversion.filter_numerator")
    L, rho = flat["newton_inversion.L"], flat["newton_inversion.rho"]
    mu, alpha = flat["newton_inversion.mu"], flat["newton_inversion.alpha"]
    t = NS.times(0.5, 400, 1000, jitter_us=(-100, 0, 150), seed=11)
    t, x, y, u = NP.dc_motor_stream(t)
    ref = reference(t, y, L, rho, mu, alpha)
    est, _, _ = NS.run(flat, t, y, u)
    NS.assert_close("newton_inversion (DC motor)", est, ref, TOL)
    assert np.abs(ref[3] - x[3]).max() > 1.0              # the transient from x_hat = 0
