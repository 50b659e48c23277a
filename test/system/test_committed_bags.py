"""Replay every committed bag through every committed DC-motor config (what fto-report runs)
and hold each pair to the numbers the README and the issue state.

Bounds, per (bag, params): the largest |truth - estimate| of (q_dot, current) from the
settle time on (guaranteed time + 10 ms, or 0.11 s without a guarantee).  Measured values
are in the README's main-job table; each bound leaves room for machine differences only,
except where a theorem gives the bound (said below).
"""
from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from fto_ros.cli import report
from fto_ros.runner.plant_files import params_files

ROOT = Path(__file__).resolve().parents[2]
replay = importlib.import_module("fto_ros.replay.replay").replay

PAIRS, _ = report.plan(ROOT / "bags", ROOT / "config")

#: (bag, params stem) -> (max |err q_dot|, max |err current|) after the settle time
BOUNDS = {
    # Theorem 1: exact after tau; the bar is 1e-3 (measured 1.1e-4, 2.1e-5: the
    # first-order hold of q between 1 kHz samples)
    ("dc_motor_nominal", "dc_motor_single_delay"): (1e-3, 1e-3),
    # noise gain 113 (diagnostics) x |noise| <= ~4 sigma = 4e-3 -> 0.45 rad/s, plus the
    # uncertainty terms (measured 0.34, 0.064)
    ("dc_motor_noisy", "dc_motor_single_delay"): (0.6, 0.15),
    # sampled form, 1-2 ms gaps (measured 0.018, 0.0033)
    ("dc_motor_sampled", "dc_motor_single_delay_sampled"): (0.05, 0.01),
    # steady-state Kalman (measured 1.7e-3, 2.8e-4 / 0.10, 0.019 / 7.4e-3, 0.135)
    ("dc_motor_nominal", "dc_motor_luenberger"): (5e-3, 1e-3),
    ("dc_motor_noisy", "dc_motor_luenberger"): (0.3, 0.05),
    ("dc_motor_sampled", "dc_motor_luenberger"): (0.03, 0.4),
    # newton_inversion, third-order differentiator on q: a transient after every voltage
    # step (the third derivative of q jumps by 1800), measured 0.026, 0.44 / 0.18, 0.66 / 0.031, 0.45
    ("dc_motor_nominal", "dc_motor_newton"): (0.06, 0.9),
    ("dc_motor_noisy", "dc_motor_newton"): (0.4, 1.3),
    ("dc_motor_sampled", "dc_motor_newton"): (0.07, 0.9),
    # hosm (Fridman, Levant & Davila) with the load torque as unknown input: exact in finite
    # time (measured 6.1e-6, 8.9e-7 with or without the load); the noisy and sampled bags as
    # for the others (measured 0.34, 0.20 / 3.2e-3, 0.135: the input changes between the
    # sparse samples)
    ("dc_motor_nominal", "dc_motor_hosm"): (1e-4, 1e-4),
    ("dc_motor_load", "dc_motor_hosm"): (1e-4, 1e-4),
    ("dc_motor_noisy", "dc_motor_hosm"): (0.6, 0.4),
    ("dc_motor_sampled", "dc_motor_hosm"): (0.01, 0.3),
    # the unknown load torque biases every observer that does not estimate it (measured
    # 0.074, 6.0e-3 / 0.093, 0.011 / 0.026, 0.99; poles 1.65, 30.6)
    ("dc_motor_load", "dc_motor_single_delay"): (0.15, 0.015),
    ("dc_motor_load", "dc_motor_luenberger"): (0.2, 0.03),
    ("dc_motor_load", "dc_motor_newton"): (0.06, 2.0),
    ("dc_motor_load", "dc_motor_luenberger_poles"): (5.0, 60.0),
    # the continuous-discrete EKF with the Kalman baseline's noise settings: on par with it
    # (measured 5.9e-7, 1.3e-7 / 0.104, 0.019 / 7.4e-3, 0.135 / 0.089, 0.010)
    ("dc_motor_nominal", "dc_motor_ekf"): (1e-5, 1e-5),
    ("dc_motor_noisy", "dc_motor_ekf"): (0.3, 0.05),
    ("dc_motor_sampled", "dc_motor_ekf"): (0.03, 0.4),
    ("dc_motor_load", "dc_motor_ekf"): (0.2, 0.03),
    # acquire (single_delay) then track (the Kalman filter of dc_motor_luenberger): on par
    # with the tracker (measured 1.5e-5, 2.8e-6 / 0.104, 0.019 / 7.3e-3, 0.135 / 0.089, 0.010)
    ("dc_motor_nominal", "dc_motor_acquire_track"): (1e-4, 1e-4),
    ("dc_motor_noisy", "dc_motor_acquire_track"): (0.3, 0.05),
    ("dc_motor_sampled", "dc_motor_acquire_track"): (0.03, 0.4),
    ("dc_motor_load", "dc_motor_acquire_track"): (0.2, 0.03),
    # a velocity jump of 4 rad/s at 2.5 s (a collision): every observer's largest error is
    # the jump itself (measured q_dot 3.98-4.06; current: single_delay 0.19, the Kalman
    # filters 0.38-0.40, hosm 1.29, newton 3.21, poles 53); test_track.py checks how fast
    # each is back
    ("dc_motor_collision", "dc_motor_single_delay"): (5.0, 0.5),
    ("dc_motor_collision", "dc_motor_luenberger"): (5.0, 1.0),
    ("dc_motor_collision", "dc_motor_acquire_track"): (5.0, 1.0),
    ("dc_motor_collision", "dc_motor_ekf"): (5.0, 1.0),
    ("dc_motor_collision", "dc_motor_hosm"): (5.0, 3.0),
    ("dc_motor_collision", "dc_motor_newton"): (5.0, 6.0),
    ("dc_motor_collision", "dc_motor_luenberger_poles"): (5.0, 80.0),
    # pole placement peaks (measured 1.64, 30): bounded, and shown as the bad example
    ("dc_motor_nominal", "dc_motor_luenberger_poles"): (5.0, 60.0),
    ("dc_motor_noisy", "dc_motor_luenberger_poles"): (5.0, 60.0),
    ("dc_motor_sampled", "dc_motor_luenberger_poles"): (5.0, 60.0),
}


def test_every_pair_has_a_bound():
    assert {(p.bag.name, p.config.stem) for p in PAIRS} == set(BOUNDS)


@pytest.mark.parametrize("pair", PAIRS, ids=lambda p: f"{p.bag.name}-{p.config.stem}")
def test_committed_bag_replays_within_bounds(pair, tmp_path):
    m = replay(pair.bag, pair.params, tmp_path / "out", progress=False, plot=False)
    assert m["samples_rejected"] == 0 and m["restarts"] == 0
    assert m["samples_accepted"] == m["sample_count"] > 1000
    err = m["errors"]["per_state"]
    got = (err["q_dot"]["max_abs_after_settle"], err["current"]["max_abs_after_settle"])
    bound = BOUNDS[(pair.bag.name, pair.config.stem)]
    assert got[0] <= bound[0] and got[1] <= bound[1], (got, bound)
    if pair.config.stem == "dc_motor_single_delay" and pair.bag.name == "dc_motor_nominal":
        # exact at the guaranteed time, not later
        assert m["convergence_time_s"] == pytest.approx(0.1, abs=1e-9)
        assert err["q"]["max_abs"] == 0.0   # q is the measurement itself


EXAMPLES = report.plan_examples(ROOT / "bags", ROOT / "config")

#: (bag, params stem) -> bound on the largest |truth - estimate| over every state after the
#: settle time (the config's metrics.settle_time, or the replay's default)
EXAMPLE_BOUNDS = {
    # Holloway & Krstic: exact at T, then window after window (mode restart).  The floor is
    # the simulator's tolerance (measured 4.2e-12 double integrator, 6.6e-10 third order)
    ("double_integrator", "double_integrator_prescribed_time"): 1e-8,
    ("third_order", "third_order_prescribed_time"): 1e-8,
    # Fridman, Levant & Davila from 5 s on.  Example 1 carries the paper's output noise 0.1:
    # the states are noise-limited (measured x4 1.7; docs/hosm.md explains the paper's 0.2);
    # Example 2's zero-dynamics coordinates converge only asymptotically (measured x5 1.4)
    ("fld_example1", "fld_example1_hosm"): 3.0,
    ("fld_example2", "fld_example2_hosm"): 3.0,
    # Possieri, Vidano & Novara, example (22), from 2 s on.  Noiseless: the discretisation
    # level (measured 4.0e-5; the issue says about 1e-4); the notch costs phase at the
    # signal's frequencies (1.6e-2); (21) cannot be filtered (0.18)
    ("possieri_example", "possieri_example_newton"): 2e-4,
    ("possieri_example", "possieri_example_newton_notch"): 0.04,
    ("possieri_example", "possieri_example_newton_ndim"): 0.4,
    # 0.01 sin 48t: (11) with the notch beats (21) (measured 0.29 against 0.65; 0.56 unfiltered)
    ("possieri_example_sinusoid", "possieri_example_newton"): 1.2,
    ("possieri_example_sinusoid", "possieri_example_newton_notch"): 0.5,
    ("possieri_example_sinusoid", "possieri_example_newton_ndim"): 1.3,
    # sigma 0.32 on y, about y's own size (measured 2.2, 1.6, 2.3)
    ("possieri_example_white_noise", "possieri_example_newton"): 5.0,
    ("possieri_example_white_noise", "possieri_example_newton_notch"): 4.0,
    ("possieri_example_white_noise", "possieri_example_newton_ndim"): 5.0,
    # Astolfi & Praly, asymptotic: from 1 s on.  cubic_escape ends 54 ms before the escape,
    # |x1| ~ 1e5 there: the absolute x1 error is the 1 kHz sampling floor (measured 0.31,
    # relative 6.4e-4; test_global_norm holds the relative error); the saturated
    # constant-gain observer loses the estimate once |x| > M = 10 (measured 14.2)
    ("cubic_escape", "cubic_escape_global_norm"): 0.6,
    ("cubic_escape", "cubic_escape_high_gain"): 30.0,
    # the EKF baseline (plant files + *_ekf.yaml): measured 0.071 (cubic_escape, 54 ms before
    # the escape), 8.0e-7, 3.3e-3, 0.21 (Example 1's noise), 0.074 (Example 2's zero
    # dynamics), 1.8e-3, 2.1e-3, 0.050 (possieri: noiseless, sinusoid, white noise), 6.6e-7
    ("cubic_escape", "cubic_escape_ekf"): 0.3,
    ("double_integrator", "double_integrator_ekf"): 1e-5,
    ("third_order", "third_order_ekf"): 0.02,
    ("fld_example1", "fld_example1_ekf"): 1.0,
    ("fld_example2", "fld_example2_ekf"): 0.3,
    ("possieri_example", "possieri_example_ekf"): 0.01,
    ("possieri_example_sinusoid", "possieri_example_ekf"): 0.01,
    ("possieri_example_white_noise", "possieri_example_ekf"): 0.2,
    ("van_der_pol", "van_der_pol_ekf"): 1e-5,
    # the nonlinear mass-spring-damper (config/msd_plant.yaml), 10 um sensor noise, from 1 s
    # on; bags/msd without, bags/msd_disturbed with the unknown force d (only hosm models
    # it: the others are biased).  Measured (largest error, always v): single_delay 1.3e-3 /
    # 0.068, prescribed_time 2.3e-4 / 0.45, hosm 5.5e-3 / 5.5e-3, luenberger 0.032 / 0.034,
    # newton_inversion 0.025 / 0.025, ekf 0.055 / 0.056, high_gain 9.1e-5 / 0.15,
    # global_norm 0.11 / 0.11 (its gains, a_i = c_i gamma_hat(w), amplify the noise)
    ("msd", "msd_single_delay"): 0.01,
    ("msd_disturbed", "msd_single_delay"): 0.2,
    ("msd", "msd_prescribed_time"): 2e-3,
    ("msd_disturbed", "msd_prescribed_time"): 1.0,
    ("msd", "msd_hosm"): 0.02,
    ("msd_disturbed", "msd_hosm"): 0.02,
    ("msd", "msd_luenberger"): 0.1,
    ("msd_disturbed", "msd_luenberger"): 0.1,
    ("msd", "msd_newton"): 0.1,
    ("msd_disturbed", "msd_newton"): 0.1,
    ("msd", "msd_ekf"): 0.15,
    ("msd_disturbed", "msd_ekf"): 0.15,
    ("msd", "msd_high_gain"): 1e-3,
    ("msd_disturbed", "msd_high_gain"): 0.4,
    ("msd", "msd_global_norm"): 0.3,
    ("msd_disturbed", "msd_global_norm"): 0.3,
    ("msd", "msd_acquire_track"): 0.15,
    ("msd_disturbed", "msd_acquire_track"): 0.15,
    # the model-free joint_kalman (230 Hz, tuned by fto-tune), alone and acquired by hosm:
    # the largest error is v (measured 0.0229, 0.0213 both; RMS 0.0062)
    ("msd", "msd_joint_kalman"): 0.035,
    ("msd_disturbed", "msd_joint_kalman"): 0.035,
    ("msd", "msd_track_joint_kalman"): 0.035,
    ("msd_disturbed", "msd_track_joint_kalman"): 0.035,
    # from x_hat(0) = (10, -10), x(0) = (2, 0) (measured 1.2e-7, 5.4e-7)
    ("van_der_pol", "van_der_pol_global_norm"): 1e-5,
    ("van_der_pol", "van_der_pol_high_gain"): 1e-5,
}


#: the arm (per-joint replays, bags from fto-simulate --urdf: the URDF's rigid-body dynamics,
#: 1e-5 rad encoder noise quantised to 2^-18 rad): (position, velocity) bounds on the largest
#: |truth - estimate| over every joint after the settle time, 1.5x what was measured
#: (2026-12-02; measured per pair in the comment)
ARM_BOUNDS = {
    ('arm7_contact_link6', 'arm7_acquire_track'): (0.00018, 0.32),  # 0.000118, 0.211
    ('arm7_contact_link6', 'arm7_ekf'): (6.3e-05, 0.071),  # 4.19e-05, 0.0473
    ('arm7_contact_link6', 'arm7_hosm'): (5.9e-05, 0.055),  # 3.88e-05, 0.0364
    ('arm7_contact_link6', 'arm7_luenberger'): (7.8e-05, 0.091),  # 5.17e-05, 0.0603
    ('arm7_contact_link6', 'arm7_single_delay'): (6.5e-05, 0.41),  # 4.32e-05, 0.269
    ('arm7_contact_tool', 'arm7_acquire_track'): (0.00029, 0.56),  # 0.000189, 0.373
    ('arm7_contact_tool', 'arm7_ekf'): (6.4e-05, 0.099),  # 4.24e-05, 0.0656
    ('arm7_contact_tool', 'arm7_hosm'): (6.5e-05, 0.056),  # 4.28e-05, 0.037
    ('arm7_contact_tool', 'arm7_luenberger'): (9.9e-05, 0.12),  # 6.55e-05, 0.0752
    ('arm7_contact_tool', 'arm7_single_delay'): (6.7e-05, 0.58),  # 4.42e-05, 0.38
    ('arm7_free', 'arm7_acquire_track'): (0.00019, 0.33),  # 0.000121, 0.214
    ('arm7_free', 'arm7_ekf'): (6e-05, 0.068),  # 3.97e-05, 0.0452
    ('arm7_free', 'arm7_hosm'): (6.2e-05, 0.054),  # 4.09e-05, 0.036
    ('arm7_free', 'arm7_luenberger'): (7.9e-05, 0.079),  # 5.21e-05, 0.0522
    ('arm7_free', 'arm7_single_delay'): (6.7e-05, 0.33),  # 4.41e-05, 0.215
    # the model-free joint_kalman (60 Hz) alone and acquired by hosm (2026-12-05); the
    # contacts' acceleration steps are its largest errors
    ('arm7_free', 'arm7_joint_kalman'): (4.8e-05, 0.013),  # 3.21e-05, 0.00876
    ('arm7_free', 'arm7_track_joint_kalman'): (4.8e-05, 0.026),  # 3.21e-05, 0.0172
    ('arm7_contact_link6', 'arm7_joint_kalman'): (0.00037, 0.12),  # 0.000246, 0.0822
    ('arm7_contact_link6', 'arm7_track_joint_kalman'): (0.00035, 0.12),  # 0.000237, 0.079
    ('arm7_contact_tool', 'arm7_joint_kalman'): (0.0007, 0.24),  # 0.000467, 0.162
    ('arm7_contact_tool', 'arm7_track_joint_kalman'): (0.00069, 0.24),  # 0.000458, 0.159
}
#: the arm's external-torque families (and arm_kalman's disturbance torque): the worst joint's
#: tau_ext RMS error in free motion (replay/arm_metrics.py), 1.5x what was measured
#: (2026-12-05, measured in the comment); every contact detected within CONTACT_DELAY_MS, no
#: false alarm, an estimate on >= 99 % of the samples
TORQUE_BOUNDS = {
    ('arm7_contact_link6', 'arm7_external_torque'): 0.066,  # 0.0439
    ('arm7_contact_tool', 'arm7_external_torque'): 0.064,  # 0.0425
    ('arm7_free', 'arm7_external_torque'): 0.060,  # 0.0398
    ('arm7_contact_link6', 'arm7_momentum_observer'): 4.6,  # 3.08
    ('arm7_contact_tool', 'arm7_momentum_observer'): 4.8,  # 3.23
    ('arm7_free', 'arm7_momentum_observer'): 4.8,  # 3.18
    ('arm7_contact_link6', 'arm7_arm_kalman'): 0.31,  # 0.204
    ('arm7_contact_tool', 'arm7_arm_kalman'): 0.29,  # 0.195
    ('arm7_free', 'arm7_arm_kalman'): 0.29,  # 0.196
}
#: the issue's bar for a contact of the 10 Nm class (measured: 4-10 ms)
CONTACT_DELAY_MS = 15.0
ARM = [p for p in EXAMPLES if (p.bag.name, p.config.stem) in ARM_BOUNDS]
TORQUE = [p for p in EXAMPLES if (p.bag.name, p.config.stem) in TORQUE_BOUNDS]
EXAMPLES = [p for p in EXAMPLES if p not in ARM and p not in TORQUE]


def test_every_example_pair_has_a_bound():
    assert {(p.bag.name, p.config.stem) for p in EXAMPLES} == set(EXAMPLE_BOUNDS)
    assert {(p.bag.name, p.config.stem) for p in ARM} == set(ARM_BOUNDS)
    assert {(p.bag.name, p.config.stem) for p in TORQUE} == set(TORQUE_BOUNDS)


@pytest.mark.parametrize("pair", TORQUE, ids=lambda p: f"{p.bag.name}-{p.config.stem}")
def test_arm_torque_replays_within_bounds(pair, tmp_path):
    m = replay(pair.bag, pair.params, tmp_path / "out", progress=False, plot=False)
    assert m["samples_rejected"] == 0 and m["samples_accepted"] == m["sample_count"] > 1000
    a = m["arm"]
    assert a["free_rms_worst_Nm"] <= TORQUE_BOUNDS[(pair.bag.name, pair.config.stem)], a
    assert a["false_alarms"] == 0 and a["estimate_fraction"] >= 0.99, a
    assert len(a["contacts"]) == (0 if pair.bag.name == "arm7_free" else 1), a["contacts"]
    for c in a["contacts"]:
        assert c["delay_ms"] is not None and c["delay_ms"] <= CONTACT_DELAY_MS, c


@pytest.mark.parametrize("pair", ARM, ids=lambda p: f"{p.bag.name}-{p.config.stem}")
def test_arm_replays_within_bounds_on_every_joint(pair, tmp_path):
    bound = ARM_BOUNDS[(pair.bag.name, pair.config.stem)]
    m = replay(pair.bag, pair.params, tmp_path / "out", progress=False, plot=False)
    assert m["samples_rejected"] == 0 and m["samples_accepted"] == m["sample_count"] > 1000
    joints = m["joint_errors"]["per_joint"]
    assert len(joints) == 7
    for name, e in joints.items():
        got = (e["per_state"]["position"]["max_abs_after_settle"],
               e["per_state"]["velocity"]["max_abs_after_settle"])
        assert got[0] <= bound[0] and got[1] <= bound[1], (name, got, bound)


@pytest.mark.parametrize("pair", EXAMPLES, ids=lambda p: f"{p.bag.name}-{p.config.stem}")
def test_example_replays_within_bounds(pair, tmp_path):
    bound = EXAMPLE_BOUNDS[(pair.bag.name, pair.config.stem)]
    m = replay(pair.bag, pair.params, tmp_path / "out", progress=False, plot=False)
    assert m["samples_rejected"] == 0 and m["samples_accepted"] == m["sample_count"] > 1000
    worst = max(e["max_abs_after_settle"] for e in m["errors"]["per_state"].values())
    assert worst < bound, m["errors"]["per_state"]


def test_load_torque_identified_on_the_load_bag(tmp_path):
    """hosm identifies the unknown load torque (measured max error 4.8e-4 after 0.11 s,
    the torque itself swings by several units)."""
    m = replay(ROOT / "bags" / "dc_motor_load", params_files(ROOT / "config" / "dc_motor_hosm.yaml"),
               tmp_path / "out", progress=False)
    ui = m["unknown_input_errors"]["per_state"]
    (name, err), = ui.items()
    assert err["max_abs"] > 1.0                       # it starts far off
    assert err["max_abs_after_settle"] < 2e-3, ui
