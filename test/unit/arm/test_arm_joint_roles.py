"""Which joints an arm model uses (fto_ros/arm/model.py, arm/urdf.py): the default chain,
passive joints whose positions come per call, <mimic> joints following theirs, the
refusals; payloads at run time, against Pinocchio's own frames and inertias."""
from __future__ import annotations

import numpy as np
import pytest

from arm_urdfs import chain, gripper_arm, inertial, joint, link
from fto_ros.arm.model import load_model
from fto_ros.arm.pin_reference import PinocchioReference
from fto_ros.core.errors import ConfigError

ARM = [f"joint_{i}" for i in range(1, 6)]


def test_the_default_is_the_arms_chain_never_the_fingers():
    m = load_model([], robot_description=gripper_arm(0, camera=False))
    assert m.joints == tuple(ARM)
    assert m.passive_joints == ("finger_1",) and m.passive_default.tolist() == [0.0]
    assert m.mimic == {"finger_2": ("finger_1", -1.0, 0.01)}
    assert load_model(None, robot_description=gripper_arm(0, camera=False)).joints == tuple(ARM)
    # a movable side branch (the camera's pan on link_2) leaves only the joints on every path
    assert load_model([], robot_description=gripper_arm(0)).joints == ("joint_1", "joint_2")
    # two arms on one base: no common chain, so every movable joint that is no mimic
    two = ('<robot name="two">' + link("base", inertial(1.0))
           + "".join(joint(f"{s}{i}", "revolute", "base" if i == 1 else f"{s}l{i - 1}",
                           f"{s}l{i}", (0, 0, 0.1)) + link(f"{s}l{i}", inertial(1.0, (0, 0, .05)))
                     for s in "ab" for i in (1, 2)) + "</robot>")
    assert load_model([], robot_description=two).joints == ("a1", "a2", "b1", "b2")
    assert load_model([], robot_description=chain(3)).joints == ("j1", "j2", "j3")


def test_mimic_joints_follow_their_parent():
    text = gripper_arm(4, multiplier=-0.5, offset=0.02)
    m = load_model(["joint_1", "finger_1", "joint_2", "joint_3", "joint_4", "joint_5"],
                   robot_description=text)
    q, v = np.arange(1.0, 7.0) / 10, np.arange(-3.0, 3.0)
    qf, vf = m.full_state(q, v)
    names = m.moving_joints
    f1, f2 = names.index("finger_1"), names.index("finger_2")
    assert qf[f2] == -0.5 * q[1] + 0.02 and vf[f2] == -0.5 * v[1] and qf[f1] == q[1]
    assert qf[names.index("pan")] == 0.0 and vf[names.index("pan")] == 0.0   # passive
    G = m.velocity_map
    assert G[f2, 1] == -0.5 and G[f1, 1] == 1.0 and np.count_nonzero(G) == 7
    # a mimic of a passive joint follows its position, with no velocity
    p = load_model(ARM, robot_description=text)
    qf, vf = p.full_state(np.zeros(5), np.ones(5), passive=[0.03, 0.2])
    assert qf[names.index("finger_2")] == -0.5 * 0.03 + 0.02 and vf[names.index("finger_2")] == 0
    # locking both fingers, consistently (as a user locked each finger by hand before)
    both = load_model(ARM, robot_description=text, locked_joints={"finger_1": 0.03,
                                                                  "finger_2": 0.005})
    assert both.passive_joints == ("finger_1", "pan") and both.passive_default[0] == 0.03


@pytest.mark.parametrize("joints, locked, param, words", [
    (["joint_1", "finger_2"], None, "joints", "finger_2 follows finger_1"),
    (ARM, {"finger_2": 0.02}, "plant.locked_joints", "finger_2 follows finger_1 (<mimic>): "
                                                     "it can be locked only where finger_1 "
                                                     "puts it (0.01)"),
    (["joint_1", "finger_1"], {"finger_2": 0.01}, "plant.locked_joints",
     "only where finger_1 puts it (finger_1 moves)"),
    (ARM + ["tcp_joint"], None, "joints", "tcp_joint (a fixed joint)"),
    (ARM, {"finger_1": float("inf")}, "plant.locked_joints", "finger_1: the position"),
    (ARM, {"joint_1": 0.0}, "plant.locked_joints", "joint_1 are also in joints"),
])
def test_joint_lists_are_refused_naming_the_joints(joints, locked, param, words):
    with pytest.raises(ConfigError) as err:
        load_model(joints, robot_description=gripper_arm(0), locked_joints=locked)
    assert err.value.parameter == param and words in str(err.value), str(err.value)


def test_passive_positions_change_the_arms_inertia():
    """The fingers' positions (per call, or the locked defaults) move their masses: M, g
    and the Jacobians follow, as Pinocchio computes them."""
    text = gripper_arm(5, multiplier=1.0, offset=0.0)
    m = load_model(ARM, robot_description=text, locked_joints={"finger_1": 0.03})
    ref = PinocchioReference(m, text)
    assert m.passive_joints == ("finger_1", "pan") and m.passive_default.tolist() == [0.03, 0.0]
    q = np.array([0.3, -0.7, 1.1, 0.05, 0.4])
    closed, opened = m.mass_matrix(q), m.mass_matrix(q, passive=[0.0, 0.0])
    np.testing.assert_array_equal(closed, m.mass_matrix(q, passive=m.passive_default))
    assert np.abs(closed - opened).max() > 1e-5
    for p in ([0.0, 0.0], [0.03, 0.0], [0.04, 1.5]):
        M = ref.mass_matrix(q, p)
        np.testing.assert_allclose(m.mass_matrix(q, p), M, rtol=0, atol=1e-12 * np.abs(M).max())
        np.testing.assert_allclose(m.gravity(q, p), ref.gravity(q, p), rtol=0, atol=1e-12)


def test_a_payload_is_set_and_removed_at_run_time():
    text = gripper_arm(6, camera=False)
    m = load_model(ARM, robot_description=text)
    rows_before = m.tree.rows.copy()
    q, v = np.array([0.2, 0.9, -0.4, 0.02, 1.3]), np.array([0.5, -1.0, 0.7, 0.1, 2.0])
    before = m.momentum_terms(q, v)
    com, I = np.array([0.01, -0.02, 0.05]), np.diag([0.003, 0.004, 0.005])
    m.set_payload("tcp", 1.5, com, I)
    changed = np.flatnonzero(np.any(m.tree.rows != rows_before, axis=1))
    assert changed.tolist() == [m.tree.row_of("joint_5")]       # only the tool's body
    ref = PinocchioReference(load_model(ARM, robot_description=text), text)
    ref.add_payload("tcp", 1.5, com, I)
    for got, want in zip(m.momentum_terms(q, v), ref.momentum_terms(q, v)):
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(m.gravity(q), ref.gravity(q), rtol=0, atol=1e-12)
    m.set_payload("tcp", 2.0, com, [0.003, 0.004, 0.005, 0, 0, 0])    # replaces, six values
    assert m.mass_matrix(q)[4, 4] > before[0][4, 4]
    m.set_payload("tcp", 0.0)                                        # removes
    for got, want in zip(m.momentum_terms(q, v), before):
        np.testing.assert_array_equal(got, want)
    m.set_payload("base", 3.0)              # fixed to the world: moves nothing
    np.testing.assert_array_equal(m.mass_matrix(q), before[0])


@pytest.mark.parametrize("args, words", [
    (("nowhere", 1.0), "no link or frame"),
    (("tcp", -1.0), "finite number >= 0"),
    (("tcp", 1.0, (0, 0, float("nan"))), "centre of mass finite"),
    (("tcp", 1.0, (0, 0, 0), np.diag([0.01, 0.01, 0.03])), "triangle inequality"),
    (("tcp", 1.0, (0, 0, 0), np.diag([0.01, -0.01, 0.01])), "positive definite"),
    (("tcp", 1.0, (0, 0, 0), [[0.01, 0.001, 0], [0, 0.01, 0], [0, 0, 0.01]]), "symmetric"),
    (("tcp", "heavy"), "as numbers"),
])
def test_bad_payloads_are_refused_in_one_line(args, words):
    m = load_model(ARM, robot_description=gripper_arm(6, camera=False))
    rows = m.tree.rows.copy()
    with pytest.raises(ConfigError) as err:
        m.set_payload(*args)
    assert err.value.parameter == "payload" and words in str(err.value), str(err.value)
    np.testing.assert_array_equal(m.tree.rows, rows)
