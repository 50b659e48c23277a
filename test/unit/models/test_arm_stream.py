"""A real arm's stream (fto_ros.models.arm_stream) and the simulator's reading of a URDF
(fto_ros.models.arm_urdf): jittered instants, stamp errors, lost messages, the effort
meanings, the trunk, mimic joints, the model error."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.models import arm_stream
from fto_ros.models.arm_urdf import COM_LENGTH, perturbed, trunk, urdf_joints, without_mimic
from fto_ros.arm import load_model

ROOT = Path(__file__).resolve().parents[3]
PANDA = ROOT / "urdf" / "panda_gripper.urdf"
ARM = [f"panda_joint{i}" for i in range(1, 8)]
FINGERS = ["panda_finger_joint1", "panda_finger_joint2"]


def test_sampling_instants_jitter_around_the_grid_uniformly():
    N, h, J = 200_001, 1e-3, 50e-6
    t = arm_stream.sample_instants(N, h, J, seed=3)
    u = t - np.arange(N) * h
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    assert np.abs(u).max() <= J and np.abs(u).max() > 0.999 * J
    sd = J / np.sqrt(3)                                   # uniform on [-J, J]
    assert abs(u[1:].mean()) < 4 * sd / np.sqrt(N)
    assert u[1:].std() == pytest.approx(sd, rel=0.01)
    assert abs(np.corrcoef(u[1:-1], u[2:])[0, 1]) < 0.01           # independent
    np.testing.assert_array_equal(arm_stream.sample_instants(10, h, 0.0, 3), np.arange(10) * h)
    np.testing.assert_array_equal(t, arm_stream.sample_instants(N, h, J, seed=3))
    with pytest.raises(ConfigError, match="half the period"):
        arm_stream.sample_instants(10, h, 0.5 * h, 3)


def test_header_stamps_carry_the_stamp_noise_only():
    t = arm_stream.sample_instants(100_001, 1e-3, 50e-6, seed=1)
    exact = arm_stream.header_stamps(t, 0.0, seed=1)
    np.testing.assert_array_equal(exact, np.round(t * 1e9).astype(np.int64))
    noisy = arm_stream.header_stamps(t, 20e-6, seed=1)
    e = (noisy - exact)[1:] * 1e-9
    assert np.abs(e).max() <= 20e-6 + 1e-9
    assert e.std() == pytest.approx(20e-6 / np.sqrt(3), rel=0.02)


@pytest.mark.parametrize("p, burst", [(0.002, 1), (0.01, 5)])
def test_lost_fraction_and_runs(p, burst):
    N = 1_000_000
    lost = arm_stream.lost_messages(N, p, burst, seed=5)
    frac = lost.mean()
    edges = np.diff(np.r_[0, lost.astype(int), 0])
    runs = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    # runs of length uniform in 1..burst: the fraction's standard deviation is about
    # sqrt(runs) * mean length / N
    sd = np.sqrt(runs.size) * runs.mean() / N
    assert abs(frac - p) < 5 * sd, (frac, p)
    if burst == 1:
        assert runs.max() == 1
    else:
        assert runs.max() <= burst and runs.min() == 1
        assert runs.mean() == pytest.approx((1 + burst) / 2, rel=0.05)
    assert not arm_stream.lost_messages(1000, 0.0, 1, seed=5).any()
    with pytest.raises(ConfigError, match="probability"):
        arm_stream.lost_messages(10, 1.0, 1, seed=5)


def test_effort_meanings_satisfy_their_identities():
    rng = np.random.default_rng(0)
    tau, g, f = (rng.normal(size=(50, 7)) * 10 for _ in range(3))
    kt, gear = rng.uniform(0.05, 0.2, 7), rng.uniform(50, 160, 7)
    E = lambda kind, **kw: arm_stream.effort(kind, tau, g, f, 1, **kw)   # noqa: E731
    np.testing.assert_array_equal(E("commanded"), tau)
    np.testing.assert_allclose(E("commanded_no_gravity") + g, tau, rtol=0, atol=1e-12)
    np.testing.assert_allclose(E("measured") + f, tau, rtol=0, atol=1e-12)
    np.testing.assert_allclose(E("current", kt=kt, gear=gear) * kt * gear, tau, rtol=1e-14)
    big = np.zeros((20000, 2))
    noisy = arm_stream.effort("measured", big, big, big, 2, torque_noise=0.3)
    assert noisy.std() == pytest.approx(0.3, rel=0.02)
    amps = arm_stream.effort("current", big, big, big, 2, current_noise=0.05)
    assert amps.std() == pytest.approx(0.05, rel=0.02)
    with pytest.raises(ConfigError, match="one of"):
        E("torque")
    with pytest.raises(ConfigError, match="kt and gear"):
        E("current", kt=0.0)


def test_the_panda_urdf_its_trunk_and_its_mimic_finger():
    text = PANDA.read_text()
    joints = urdf_joints(text)
    assert trunk(joints) == ARM
    assert joints["panda_finger_joint2"].mimic == ("panda_finger_joint1", 1.0, 0.0)
    assert (joints["panda_finger_joint1"].lower, joints["panda_finger_joint1"].upper) == (0.0, 0.04)
    assert "<mimic" in text and "<mimic" not in without_mimic(text)
    assert "<dynamics" not in text                        # no friction in a real URDF
    model = load_model(ARM + FINGERS, robot_description=without_mimic(text))
    q = np.array([0, 0.5, 0, -1.2, 0, 0.8, 0, 0.02, 0.02])
    M = model.mass_matrix(q)
    assert 0.004 < M[6, 6] < 0.01 and np.all(model.armature == 0)   # light distal links
    np.testing.assert_array_equal(model.effort_limit, [87] * 4 + [12] * 3 + [100] * 2)
    # a chain without a branch: every movable joint is the trunk
    chain = urdf_joints((ROOT / "urdf" / "arm7.urdf").read_text())
    assert trunk(chain) == [f"joint_a{i}" for i in range(1, 8)]


def test_a_mimic_of_an_unknown_joint_is_refused():
    text = PANDA.read_text().replace('mimic joint="panda_finger_joint1"', 'mimic joint="nope"')
    with pytest.raises(ConfigError, match="mimics 'nope'"):
        urdf_joints(text)


def test_model_error_stays_within_its_bound_and_is_reproducible():
    text = PANDA.read_text()
    E = 0.05
    a, rec = perturbed(text, E, seed=4)
    b, rec_b = perturbed(text, E, seed=4)
    _, rec_c = perturbed(text, E, seed=5)
    assert a == b and rec == rec_b and rec != rec_c
    assert len(rec) == 11                                  # every link with an inertial
    for link, r in rec.items():
        assert 1 - E <= r["mass_scale"] <= 1 + E and 1 - E <= r["inertia_scale"] <= 1 + E
        assert max(abs(x) for x in r["com_shift"]) <= E * COM_LENGTH
    scales = np.array([[r["mass_scale"], r["inertia_scale"]] for r in rec.values()])
    assert np.abs(scales - 1).max() > 0.5 * E              # the bound is used
    nominal, true = (load_model(ARM + FINGERS, robot_description=without_mimic(x))
                     for x in (text, a))
    q = np.array([0, 0.5, 0, -1.2, 0, 0.8, 0, 0.02, 0.02])
    rel = np.abs(true.mass_matrix(q) - nominal.mass_matrix(q)).max() / np.abs(
        nominal.mass_matrix(q)).max()
    assert 1e-3 < rel < 3 * E
    same, _ = perturbed(text, 0.0, seed=4)
    zero = load_model(ARM + FINGERS, robot_description=without_mimic(same))
    np.testing.assert_allclose(zero.mass_matrix(q), nominal.mass_matrix(q), rtol=1e-14)
    with pytest.raises(ConfigError, match="model_error"):
        perturbed(text, 1.0, seed=4)
