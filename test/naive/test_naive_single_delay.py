"""Naive references of ``single_delay`` (Mazenc & Malisoff 2022), both forms, against the
package through the runner at every sample (naive_single_delay.py has the equations).

Continuous form (Theorem 1), config/dc_motor_single_delay.yaml (k = 100, tau = 0.1) and two
more tunings (k = 200, tau = 0.05; k = 100, tau = 0.02).  Both sides solve the extension (7) exactly with
(F1, F2, Y) linear between the 1 kHz samples, and read the delayed values at a sample
(tau is a whole number of periods).  Tolerance: TOL_CONT = 1e3 eps cond(S).  The estimate
(13) is a sum of terms S^-1 (...) of the extension's states, so the rounding of S, N (the
quadratures: 1e-14 relative here against the package's Gauss-Legendre) and of the
exponentials (|Az h| <= 0.4: ~1e-15 each) comes out multiplied by cond(S) (1.4e5 for
k = 100, tau = 0.1; 34 and 66 for the others) and by the size of the terms against the
estimate's scale (measured: at most 0.7x, 16x and 26x); 1e3 eps covers those sizes and a
few roundings per term.  Measured: 3.5e-12, 5.9e-14, 8.1e-14 against the bars 3e-8,
7.5e-12, 1.5e-11.

Sampled form (Theorem 2, eq. 39), config/dc_motor_single_delay_sampled.yaml on irregular
stamps 1-2 ms apart: the reference solves (39) between the samples by DOP853 at rtol 1e-11
(the delayed term from its own dense output); the package steps the predictor in sub-steps
of ``substep``, the linear part exact, F and the delayed term by Heun's method: second
order.  So the package's error is C h^2 + O(h^3), and its own runs at h and h/2 estimate it
(Richardson): e(h) ~ 4/3 |x_h - x_h/2|.  The tolerance is that estimate, times 1.25 for the
O(h^3) rest (measured: e(0.5 ms) = 4.81e-4 of the state's scale against the estimate
4.77e-4; 1.24e-4 at 0.25 ms, 3.12e-5 at 0.125 ms: ratios 3.88, 3.97; at tau = 0.02:
4.09e-3 against the estimate 5.19e-3, then 2.03e-4), and the error must shrink at least 3x when h halves (second order: 4x).  A wrong formula leaves an error
that does not shrink with h, or one far above the package's own estimate.
"""
from __future__ import annotations

import numpy as np
import pytest

import naive_plants as NP
import naive_single_delay as SD
import naive_support as NS

FAMILY = "single_delay"
FORMS = ("continuous", "sampled")


def tol_continuous(design: SD.Design) -> float:
    return 1e3 * NS.EPS * design.cond


# the committed tuning, and two where the delayed terms weigh more (e^{-k tau} = 4.5e-5,
# 4.5e-5, 0.14): a wrong delayed read shows in the last one most
@pytest.mark.parametrize("k,tau", [(100.0, 0.1), (200.0, 0.05), (100.0, 0.02)])
def test_single_delay_continuous_matches_its_naive_reference(k, tau):
    t = NS.times(0.5, round(tau * 1e3) + 60, 1000)
    t, x, y, u = NP.dc_motor_stream(t)
    flat = NS.flat_params("dc_motor_plant", "dc_motor_single_delay",
                          single_delay__k=k, single_delay__tau=tau)
    assert flat["single_delay.measurement"] == "continuous"
    design = SD.Design(k, tau)
    ref = SD.continuous_reference(design, t, y, u)
    est, _, _ = NS.run(flat, t, y, u)
    tol = tol_continuous(design)
    NS.assert_close(f"single_delay continuous (k {k}, tau {tau}, cond(S) {design.cond:.3g})",
                    est, ref, tol)
    # the transient is in the comparison: before tau the model copy, far from the truth;
    # after tau the paper's exact estimate (the 1 kHz hold of Y aside)
    lag = round(tau / 1e-3)
    assert np.abs(ref[lag - 5, 1:] - x[lag - 5, 1:]).max() > 0.1
    assert np.abs(ref[lag + 1:, 1:] - x[lag + 1:, 1:]).max() < 1e-2


@pytest.mark.parametrize("tau", [0.1, 0.02])
def test_single_delay_sampled_matches_its_naive_reference(tau):
    # irregular stamps 1-2 ms apart, as bags/dc_motor_sampled
    t = NS.times(0.5, round(tau * 700) + 50, 1000, jitter_us=(0, 250, 500, 1000), seed=7)
    t, x, y, u = NP.dc_motor_stream(t)
    ref = SD.sampled_reference(SD.Design(100.0, tau), t, y, u)
    est = {}
    for sub in (0.0005, 0.00025):
        flat = NS.flat_params("dc_motor_plant", "dc_motor_single_delay_sampled",
                              single_delay__substep=sub, single_delay__tau=tau)
        assert flat["single_delay.measurement"] == "sampled"
        est[sub] = NS.run(flat, t, y, u)[0]
    h, h2 = est[0.0005], est[0.00025]
    richardson = 4.0 / 3.0 * NS.deviation(h, h2)[0]
    err = NS.assert_close(f"single_delay sampled (tau {tau}, substep 0.5 ms)", h, ref,
                          1.25 * richardson)
    err2 = NS.deviation(h2, ref)[0]
    print(f"substep 0.25 ms: {err2:.3g}; the package's own estimate of its error {richardson:.3g}")
    assert err / err2 >= 3.0, f"not second order in the substep: {err:.3g}, {err2:.3g}"
    assert t[-1] - t[0] > tau + 0.05                 # 50 ms past tau: the estimate (13) compared
