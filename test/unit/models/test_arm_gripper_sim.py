"""The simulated arm with a gripper (fto_ros.models.arm, .arm_plant): integration accuracy,
the fingers and their mimic relation, jittered control instants, velocity reversals, the
controller on the nominal model while the true arm differs."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fto_ros.models.arm import ArmSettings, Contact, Gripper, simulate_arm
from fto_ros.models.arm_urdf import perturbed, without_mimic
from fto_ros.arm import load_model

ROOT = Path(__file__).resolve().parents[3]
TEXT = (ROOT / "urdf" / "panda_gripper.urdf").read_text()
ARM = [f"panda_joint{i}" for i in range(1, 8)]
F1, F2 = "panda_finger_joint1", "panda_finger_joint2"
GRIPPER = Gripper({F1: (0.0, 0.04)}, {F2: (F1, 1.0, 0.0)})


def model(text=TEXT, friction=0.0):
    fr = [friction] * 7 + [0.0, 0.0]
    return load_model(ARM + [F1, F2], robot_description=without_mimic(text),
                      viscous_friction=fr, coulomb_friction=fr)


def test_rk4_at_4_khz_is_the_truth_against_a_4x_smaller_step():
    """Noise-free (the closed loop is then smooth in the state), with the Coulomb friction's
    steep tanh on every joint (1 Nm, w = 0.02 rad/s), jittered instants, the fingers moving,
    a 20 N push with a 10 ms ramp and a 50 N step between two sample instants: 16 kHz
    against 4 kHz. Measured: 1.2e-9 rad, 1.1e-6 rad/s on the arm, 3.3e-6 m/s on a finger
    (a contact's force switched on at a stage of the step before it: 7e-4 rad/s)."""
    m = model(friction=1.0)
    contacts = [Contact("panda_hand", 0.5, 0.1, (0.0, 20.0, 0.0), 0.01),
                Contact("panda_link4", 0.8003, 0.1, (0.0, 50.0, 0.0))]      # a step
    runs = [simulate_arm(m, ArmSettings(duration=1.3, substeps=s, noise=0.0, resolution=0.0,
                                        jitter=50e-6, gripper_period=0.8, contacts=contacts),
                         driven=ARM, gripper=GRIPPER) for s in (4, 16)]
    a, b = runs
    np.testing.assert_array_equal(a.t, b.t)
    assert np.abs(a.q - b.q).max() < 1e-8
    assert np.abs(a.v - b.v).max() < 1e-5
    assert np.abs(a.tau_ext).max() > 5                      # the push happened
    assert np.abs(a.v[:, 6]).max() > 0.3                     # joint 7 moved through v = 0


def test_the_fingers_move_follow_their_mimic_and_act_on_the_arm():
    text = TEXT.replace('multiplier="1" offset="0"', 'multiplier="0.5" offset="0.002"')
    grip = Gripper({F1: (0.0, 0.04)}, {F2: (F1, 0.5, 0.002)})
    m = model(text)
    s = ArmSettings(duration=0.6, noise=0.0, resolution=0.0, gripper_period=0.5)
    run = simulate_arm(m, s, driven=ARM, gripper=grip)
    f1, f2 = run.names.index(F1), run.names.index(F2)
    assert run.names == tuple(ARM + [F1, F2]) and list(run.driven) == list(range(7))
    # the stream's mimic finger is its parent's through the relation, exactly
    np.testing.assert_array_equal(run.q_measured[:, f2], 0.5 * run.q_measured[:, f1] + 0.002)
    # the true fingers: on the trajectory 10 % .. 90 % of the range, the mimic within microns
    assert run.q[:, f1].min() == pytest.approx(0.004, abs=2e-5)
    assert run.q[:, f1].max() == pytest.approx(0.036, abs=2e-5)
    assert np.abs(run.q[:, f2] - (0.5 * run.q[:, f1] + 0.002)).max() < 2e-5
    assert np.all(run.tau[:, f1] == 0) and np.all(run.gravity[:, f1] == 0)
    # still fingers: the arm moves differently (the fingers' motion acts through M(q))
    still = simulate_arm(m, ArmSettings(duration=0.6, noise=0.0, resolution=0.0),
                         driven=ARM, gripper=grip)
    assert np.abs(still.q[:, f1] - 0.004).max() < 5e-6           # the drive holds it
    assert 1e-9 < np.abs(still.q[:, :7] - run.q[:, :7]).max() < 1e-3


def test_the_controller_runs_at_the_jittered_instants_on_the_nominal_model():
    nominal = model()
    true_text, _ = perturbed(TEXT, 0.05, seed=2)
    true = model(true_text, friction=0.8)
    s = ArmSettings(duration=0.3, jitter=50e-6, seed=6)
    run = simulate_arm(true, s, driven=ARM, gripper=GRIPPER, nominal=nominal)
    u = run.t - np.arange(run.t.size) * 1e-3
    assert np.abs(u).max() <= 50e-6 and u.std() > 20e-6
    # gravity compensation from the nominal model at the measurement, friction the true one's
    for k in (0, 100, 299):
        np.testing.assert_allclose(run.gravity[k, :7], nominal.gravity(run.q_measured[k])[:7],
                                   rtol=1e-12)
        np.testing.assert_allclose(run.friction[k, :7], true.friction(run.v[k])[:7], rtol=1e-12)
    assert np.abs(true.gravity(run.q[100]) - nominal.gravity(run.q[100])).max() > 0.05


def test_every_joint_reverses_its_velocity():
    """The default trajectory, 1 - cos with periods up to 5 s: every joint's velocity
    changes sign within 2.6 s (RK4 at one step per sample is enough to see it)."""
    run = simulate_arm(model(), ArmSettings(duration=2.6, substeps=1, noise=0.0, resolution=0.0),
                       driven=ARM, gripper=GRIPPER)
    v = run.v[200:, :7]
    assert np.all(v.max(axis=0) > 0.05) and np.all(v.min(axis=0) < -0.01), (v.max(0), v.min(0))
