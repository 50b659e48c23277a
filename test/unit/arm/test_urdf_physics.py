"""A URDF is validated as physics before anything uses it (fto_ros/arm/urdf.py; issue 28
item 4, F10-F15): every refusal is one ConfigError line naming the source's parameter and
the link or joint. urdfdom (so Pinocchio) drops a NaN or inf mass silently, so the XML is
read here, not through Pinocchio."""
from __future__ import annotations

import math

import numpy as np
import pytest

from arm_urdfs import inertial, joint, link
from fto_ros.arm.model import load_model
from fto_ros.arm.urdf import TRIANGLE_TOLERANCE
from fto_ros.core.errors import ConfigError

def two_links(m1="2.0", m2="1.0", i2=(0.01, 0.012, 0.015), axis="0 1 0", dyn="",
              off=(0, 0, 0), l2=None) -> str:
    """base -> j1 -> l1 -> j2 -> l2, masses and l2's inertia as given (text)."""
    ixx, iyy, izz = i2
    body2 = l2 if l2 is not None else (
        f'<inertial><origin xyz="0 0 0.1"/><mass value="{m2}"/><inertia ixx="{ixx}" '
        f'ixy="{off[0]}" ixz="{off[1]}" iyy="{iyy}" iyz="{off[2]}" izz="{izz}"/></inertial>')
    return ('<robot name="r">' + link("base")
            + f'<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
              f'<axis xyz="0 0 1"/>{dyn}</joint>'
            + link("l1", f'<inertial><mass value="{m1}"/><inertia ixx="0.01" ixy="0" ixz="0" '
                         f'iyy="0.01" iyz="0" izz="0.01"/></inertial>')
            + f'<joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>'
              f'<origin xyz="0 0 0.3"/><axis xyz="{axis}"/></joint>'
            + link("l2", body2) + "</robot>")


def test_the_good_one_loads():
    m = load_model(None, robot_description=two_links())
    assert m.joints == ("j1", "j2") and np.all(np.isfinite(m.mass_matrix([0.1, 0.2])))


def refused(text: str, *words: str):
    with pytest.raises(ConfigError) as err:
        load_model(None, robot_description=text)
    msg = str(err.value)
    assert err.value.parameter == "robot_description" and "\n" not in msg, msg
    assert all(w in msg for w in words), msg
    return msg


@pytest.mark.parametrize("mass", ["-1", "0", "nan", "NaN", "inf", "-inf", "1e400", "abc", ""])
def test_a_mass_that_is_not_finite_and_positive(mass):
    refused(two_links(m2=mass), "link 'l2'", "mass must be a finite number > 0")
    refused(two_links(m1=mass), "link 'l1'", "mass")


def test_a_massless_frame_is_accepted_and_a_massless_body_refused():
    """Mass 0 with a zero inertia tensor is a frame (as if it had no <inertial>); mass 0 with
    any other tensor is refused naming the link."""
    frame = '<inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>'
    text = ('<robot name="r">' + link("base", frame) + joint("j1", "revolute", "base", "l1")
            + link("l1", inertial(1.0, (0, 0, 0.1))) + "</robot>")
    m = load_model(None, robot_description=text)
    assert m.robot.links["base"] is None and m.mass_matrix([0.3])[0, 0] > 0
    refused(text.replace('ixx="0"', 'ixx="0.01"'), "link 'base'", "non-zero inertia tensor")


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_a_floating_or_planar_joint_is_fixed_at_its_neutral_pose_with_a_note(kind):
    """A mobile base under the arm: its joint is read as fixed at its origin, and said."""
    base = structure(link("world"), link("base"), L1,
                     joint("base_joint", kind, "world", "base"),
                     joint("j1", "revolute", "base", "l1"))
    m = load_model(None, robot_description=base)
    assert m.joints == ("j1",) and m.robot.joint("base_joint").kind == "fixed"
    assert any("base_joint" in n and kind in n and "fixed" in n for n in m.robot.notes)
    plain = structure(link("base"), L1, joint("j1", "revolute", "base", "l1"))
    assert np.allclose(m.mass_matrix([0.4]), load_model(None, robot_description=plain)
                       .mass_matrix([0.4]))


def test_every_mass_zero():
    text = ('<robot name="r">' + link("base") + joint("j1", "revolute", "base", "l1")
            + link("l1") + "</robot>")
    refused(text, "every link's mass is zero")
    # a joint that moves nothing (its links massless) and has no armature
    text = ('<robot name="r">' + link("base") + joint("j1", "revolute", "base", "l1")
            + link("l1", inertial(1.0, (0, 0, 0.1))) + joint("j2", "revolute", "l1", "l2")
            + link("l2") + "</robot>")
    refused(text, "j2 move no mass")
    armed = text.replace('</joint><link name="l2"', '<dynamics damping="0" armature="0.1"/>'
                                                   '</joint><link name="l2"')
    assert load_model(None, robot_description=armed).armature.tolist() == [0.0, 0.1]


@pytest.mark.parametrize("i2, off, words", [
    (("nan", 0.01, 0.01), (0, 0, 0), "the inertia ixx must be finite"),
    ((0.01, "inf", 0.01), (0, 0, 0), "the inertia iyy must be finite"),
    ((0.01, 0.01, 0.01), ("nan", 0, 0), "the inertia ixy must be finite"),
    ((0.01, 0.01, "x"), (0, 0, 0), "izz as a number"),
    ((-0.01, 0.01, 0.01), (0, 0, 0), "not positive definite"),
    ((0.01, 0.01, 0.0), (0, 0, 0), "not positive definite"),
    ((0.0, 0.0, 0.0), (0, 0, 0), "not positive definite"),
    ((0.01, 0.01, 0.01), (0.02, 0, 0), "not positive definite"),       # products too large
    ((0.01, 0.03, 0.01), (0, 0, 0), "triangle inequality"),
    ((0.01, 0.01, 0.0201), (0, 0, 0), "triangle inequality"),
])
def test_an_inertia_no_rigid_body_has(i2, off, words):
    refused(two_links(i2=i2, off=off), "link 'l2'", words)


def test_the_triangle_tolerance_is_for_rounding_only():
    edge = 0.02 * (1 + 0.5 * TRIANGLE_TOLERANCE)          # a flat plate, rounded up
    load_model(None, robot_description=two_links(i2=(0.01, 0.01, edge)))
    refused(two_links(i2=(0.01, 0.01, 0.02 * (1 + 2 * TRIANGLE_TOLERANCE))), "triangle")
    # a rotated tensor is judged by its principal moments: a plate tilted by rpy is fine
    R = np.array([[math.cos(0.4), -math.sin(0.4), 0], [math.sin(0.4), math.cos(0.4), 0],
                  [0, 0, 1]])
    I = R @ np.diag([0.01, 0.02, 0.03]) @ R.T
    load_model(None, robot_description=two_links(i2=(I[0, 0], I[1, 1], I[2, 2]),
                                                  off=(I[0, 1], I[0, 2], I[1, 2])))


@pytest.mark.parametrize("axis, words", [
    ("0 0 0", "joint 'j2': the axis is zero"),
    ("0 nan 1", "joint 'j2' <axis>: xyz must be 3 finite numbers"),
    ("0 1", "joint 'j2' <axis>: xyz must be 3"),
    ("1e400 0 0", "xyz must be 3 finite numbers"),
])
def test_a_joint_axis_that_is_zero_or_not_numbers(axis, words):
    refused(two_links(axis=axis), words)


def test_an_axis_is_normalised():
    a = load_model(None, robot_description=two_links(axis="0 2 0"))
    b = load_model(None, robot_description=two_links(axis="0 1 0"))
    np.testing.assert_allclose(a.mass_matrix([0.3, 0.4]), b.mass_matrix([0.3, 0.4]), rtol=1e-15)


@pytest.mark.parametrize("dyn, words", [
    ('<dynamics damping="-1"/>', "joint 'j1': damping must be a finite number >= 0"),
    ('<dynamics damping="nan"/>', "damping must be a finite number >= 0"),
    ('<dynamics damping="0" friction="-0.5"/>', "joint 'j1': friction must be"),
    ('<dynamics damping="0" friction="inf"/>', "friction must be a finite number"),
    ('<dynamics damping="0" armature="-1"/>', "joint 'j1': armature must be"),
    ('<limit effort="-3" lower="0" upper="1" velocity="1"/>', "joint 'j1': effort must be"),
    ('<limit effort="3" lower="nan" upper="1" velocity="1"/>', "joint 'j1': lower must be"),
])
def test_joint_dynamics_that_are_not_physical(dyn, words):
    refused(two_links(dyn=dyn), words)


def structure(*parts) -> str:
    return '<robot name="r">' + "".join(parts) + "</robot>"


L1 = link("l1", inertial(1.0, (0, 0, 0.1)))
L2 = link("l2", inertial(1.0, (0, 0, 0.1)))


@pytest.mark.parametrize("text, words", [
    (structure(link("base"), L1, L2, joint("j1", "revolute", "base", "l1")),
     "2 root links"),
    (structure(link("base"), L1, joint("j1", "revolute", "base", "l1"),
               joint("j2", "revolute", "base", "l1")), "link 'l1' is the child of two joints"),
    (structure(link("base"), L1, L2, joint("j0", "revolute", "base", "l1"),
               joint("j1", "revolute", "l2", "l1")), "child of two joints"),
    (structure(link("base"), L1, L2, joint("j1", "revolute", "l1", "l2"),
               joint("j2", "revolute", "l2", "l1")), "not a tree"),
    (structure(link("base"), L1, L1, joint("j1", "revolute", "base", "l1")),
     "link 'l1' is defined twice"),
    (structure(link("base"), L1, L2, joint("j1", "revolute", "base", "l1"),
               joint("j1", "revolute", "l1", "l2")), "joint 'j1' is defined twice"),
    (structure(link("base"), L1, joint("j1", "revolute", "base", "nowhere")),
     "joint 'j1': there is no link 'nowhere'"),
    (structure(link("base"), L1, joint("j1", "screw", "base", "l1")), "unknown type 'screw'"),
    (structure(link("base"), L1, L2, joint("j1", "revolute", "base", "l1"),
               joint("j2", "revolute", "l1", "l2", extra='<mimic joint="nope"/>')),
     "joint 'j2': <mimic joint='nope'> is not a movable joint"),
    (structure(link("base"), L1, L2, joint("j1", "fixed", "base", "l1"),
               joint("j2", "revolute", "l1", "l2", extra='<mimic joint="j1"/>')),
     "<mimic joint='j1'> is not a movable joint"),
    (structure(link("base"), L1, L2, joint("j1", "revolute", "base", "l1"),
               joint("j2", "fixed", "l1", "l2", extra='<mimic joint="j1"/>')),
     "joint 'j2': a <mimic> needs a movable joint"),
    (structure(link("base"), L1, L2,
               joint("j1", "revolute", "base", "l1", extra='<mimic joint="j2"/>'),
               joint("j2", "revolute", "l1", "l2", extra='<mimic joint="j1"/>')),
     "<mimic> chain is a cycle"),
    (structure(link("base"), L1, joint("j1", "revolute", "base", "l1",
                                       extra='<mimic joint="j1" multiplier="nan"/>')),
     "joint 'j1': multiplier must be a finite number"),
])
def test_structures_that_are_no_arm(text, words):
    refused(text, words)


def test_the_joint_cap_and_the_windows_memory():
    """F16: more joints than configure in about 2 s and 200 MB are refused before anything
    is built; so is a window estimator whose ring would outgrow its budget."""
    from arm_families import observer
    from arm_urdfs import chain
    from fto_ros.arm.urdf import MAX_JOINTS
    from fto_ros.observers.external_torque import kernel
    from fto_ros.observers.external_torque.adapter import MAX_WINDOW_BYTES
    assert load_model(None, robot_description=chain(MAX_JOINTS)).n == MAX_JOINTS
    refused(chain(MAX_JOINTS + 1), f"{MAX_JOINTS + 1} joints: more than the {MAX_JOINTS}")
    text = chain(60)
    slot = kernel.slot_offsets(60, 0)[-1]
    W = MAX_WINDOW_BYTES // (8 * slot) - 1                   # the longest that fits
    assert observer("external_torque", text=text, external_torque__window=(W - 1) * 1e-3)
    with pytest.raises(ConfigError, match="MiB, more than the 64 MiB") as err:
        observer("external_torque", text=text, external_torque__window=(W + 1) * 1e-3)
    assert err.value.parameter == "external_torque.window"
