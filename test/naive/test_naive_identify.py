"""fto-identify's window form (fto_ros/arm/identify.py) against the naive direct-form least
squares of naive_identify.py on the same noise-free recording of the test arm: the two
routes (positions only and the kernel's integration by parts, against finite-difference
accelerations and Pinocchio's regressor) give the same scales and friction."""
from __future__ import annotations

import numpy as np

import identify_data as D
from fto_ros.arm.identify import Spec, identify
from naive_identify import fit_scales_and_friction


def test_window_fit_matches_its_naive_reference():
    rec = D.record(D.true_model(scale=D.SCALE), duration=3.0, seed=8, noise=0.0)
    scales, viscous, coulomb = fit_scales_and_friction(D.TEXT, rec.t, rec.q, rec.tau,
                                                        D.ARMATURE, D.WIDTH)
    r = identify(D.prior(), rec.t, rec.q, rec.tau,
                 spec=Spec(inertia="scale", encoder_noise=1e-9, ratio=1e9))
    got = {u.name: v for u, v in zip(r.unknowns, r.value)}
    window = np.array([[got[f"scale l{i}"] for i in (1, 2, 3)],
                       [got[f"viscous j{i}"] for i in (1, 2, 3)],
                       [got[f"coulomb j{i}"] for i in (1, 2, 3)]])
    naive = np.array([scales, viscous, coulomb])
    # both near the truth (the recording is exact), and nearer each other than either's
    # own discretisation (the naive one's O(h^2) differences)
    truth = np.array([[D.SCALE[f"l{i}"] for i in (1, 2, 3)], D.VISCOUS, D.COULOMB])
    np.testing.assert_allclose(naive, truth, rtol=3e-4)
    np.testing.assert_allclose(window, truth, rtol=2e-4)
    np.testing.assert_allclose(window, naive, rtol=3e-4)
