"""Plants in observability form with one output y = x0 (config/van_der_pol_plant.yaml), the
continuous output the references are driven by, and the Richardson comparison of a
second-order scheme with an ODE reference, for global_norm and high_gain.

``vdp_output(t_end)``: Van der Pol, x0' = x1, x1' = (1 - x0^2) x1 - x0 from x(0) = (2, 0)
(bags/van_der_pol), as a dense solution (DOP853, rtol 1e-13): y(t) = x0(t) at any t.

``richardson(name, flat, ref, t0, n, period_us)``: the package on the stamps t0 + k h
(h = period_us) and on the stamps twice as dense; its error against the reference at the
common stamps must be within 1.25 x 4/3 |x_h - x_h/2| (its own Richardson estimate of a
second-order error: e(h) = C h^2 + O(h^3)) and shrink at least 3x when h halves.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

import naive_support as NS


def vdp_output(t_end: float):
    sol = solve_ivp(lambda s, x: [x[1], (1 - x[0] ** 2) * x[1] - x[0]], (0.0, t_end),
                    [2.0, 0.0], method="DOP853", rtol=1e-13, atol=1e-13, dense_output=True)
    return sol.sol


def richardson(name: str, flat: dict, ref, t0: float, n: int, period_us: int) -> float:
    """See the module doc; ``ref(t)`` is the reference's estimate at the stamps t,
    ``ref.output(t)`` the plant's output there.  Returns the error at h."""
    errs, est = [], {}
    for div in (1, 2):
        t = NS.times(t0, (n - 1) * div + 1, period_us // div)
        y = ref.output(t)[:, None]
        est[div] = NS.run(flat, t, y)[0][::div]
    t = NS.times(t0, n, period_us)
    ref = ref(t)
    rich = 4.0 / 3.0 * NS.deviation(est[1], est[2])[0]
    err = NS.assert_close(f"{name} (h = {period_us} us)", est[1], ref, 1.25 * rich)
    err2 = NS.deviation(est[2], ref)[0]
    print(f"h/2: {err2:.3g}; the package's own estimate of its error at h {rich:.3g}")
    assert err / err2 >= 3.0, f"{name}: not second order in the step: {err:.3g}, {err2:.3g}"
    return err
