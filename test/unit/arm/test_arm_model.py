"""Arms from their URDF (fto_ros.arm, fto_ros.models.arm, fto-simulate --urdf): dynamics
against hand-computed cases, the wrench and a frame's pose, refusals, reproducibility (the
estimators: test/unit/observers/test_external_torque*.py). ROS-free."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from two_processes import assert_bitwise_equal, run_twice

from fto_ros.core.errors import ConfigError
from fto_ros.models.arm import ArmSettings, Contact, simulate_arm
from fto_ros.arm import load_model
from fto_ros.arm.source import MAX_URDF_BYTES

ROOT = Path(__file__).resolve().parents[3]
URDF = ROOT / "urdf" / "arm7.urdf"
JOINTS = [f"joint_a{i}" for i in range(1, 8)]
G = 9.81


def link(name, m, com, inertia):
    ixx, iyy, izz = inertia
    return (f'<link name="{name}"><inertial><origin xyz="{com[0]} {com[1]} {com[2]}"/>'
            f'<mass value="{m}"/><inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" '
            f'izz="{izz}"/></inertial></link>')


def joint(name, parent, child, xyz, axis, kind="revolute"):
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>'
            f'<limit lower="-3" upper="3" effort="100" velocity="5"/></joint>')


# a pendulum about y, its centre of mass l below the axis: M = I + m l^2, g = m g l sin q
# (inertias that a rigid body can have: the URDF physics checks refuse others)
M1, L1, I1 = 2.0, 0.4, 0.03
PENDULUM = ('<robot name="p"><link name="base"/>' + joint("j", "base", "bob", "0 0 0", "0 1 0")
            + link("bob", M1, (0, 0, -L1), (0.02, I1, 0.02)) + "</robot>")


def planar(m1=1.5, m2=0.8, l1=0.5, c1=0.25, c2=0.2, i1=0.02, i2=0.01):
    """Two links in the horizontal plane (joints about z, no gravity torque)."""
    return ('<robot name="two"><link name="base"/>' + joint("j1", "base", "l1", "0 0 0", "0 0 1")
            + link("l1", m1, (c1, 0, 0), (i1, i1, i1))
            + joint("j2", "l1", "l2", f"{l1} 0 0", "0 0 1")
            + link("l2", m2, (c2, 0, 0), (i2, i2, i2)) + "</robot>")


def test_pendulum_mass_gravity_and_no_coriolis():
    m = load_model(["j"], robot_description=PENDULUM, coulomb_friction=[0.0],
                   viscous_friction=[0.0])
    for q, v in ((0.3, 1.2), (-1.1, -0.4), (2.0, 3.0)):
        assert m.mass_matrix([q])[0, 0] == pytest.approx(I1 + M1 * L1 ** 2, rel=1e-12)
        assert m.gravity([q])[0] == pytest.approx(M1 * G * L1 * math.sin(q), rel=1e-9)
        assert m.coriolis([q], [v])[0] == pytest.approx(0.0, abs=1e-12)
        a = m.forward_dynamics([q], [v], [0.5])[0]
        assert a == pytest.approx((0.5 - M1 * G * L1 * math.sin(q)) / (I1 + M1 * L1 ** 2), rel=1e-9)
        assert m.inverse_dynamics([q], [v], [a])[0] == pytest.approx(0.5, rel=1e-9)
    armed = load_model(["j"], robot_description=PENDULUM.replace(
        '<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics damping="0" armature="0.2"/>'))
    assert armed.armature.tolist() == [0.2]
    assert armed.mass_matrix([0.3])[0, 0] == pytest.approx(I1 + M1 * L1 ** 2 + 0.2, rel=1e-12)
    with pytest.raises(ConfigError, match="armature"):
        load_model(["j"], robot_description=PENDULUM.replace(
            '<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics damping="0" armature="-1"/>'))


def test_two_link_mass_matrix_and_coriolis_are_the_textbook_ones():
    m1, m2, l1, c1, c2, i1, i2 = 1.5, 0.8, 0.5, 0.25, 0.2, 0.02, 0.01
    m = load_model(["j1", "j2"], robot_description=planar(), viscous_friction=0,
                   coulomb_friction=0)
    for q, v in (((0.2, 0.7), (1.0, -2.0)), ((-1.0, 2.5), (0.3, 0.9))):
        c = math.cos(q[1])
        M = np.array([[i1 + i2 + m1 * c1 ** 2 + m2 * (l1 ** 2 + c2 ** 2 + 2 * l1 * c2 * c),
                       i2 + m2 * (c2 ** 2 + l1 * c2 * c)],
                      [i2 + m2 * (c2 ** 2 + l1 * c2 * c), i2 + m2 * c2 ** 2]])
        hs = m2 * l1 * c2 * math.sin(q[1])
        Cv = np.array([-hs * (2 * v[0] * v[1] + v[1] ** 2), hs * v[0] ** 2])
        np.testing.assert_allclose(m.mass_matrix(q), M, rtol=1e-12)
        np.testing.assert_allclose(m.coriolis(q, v), Cv, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(m.gravity(q), 0.0, atol=1e-12)
        Mt, Md, CTv, _ = m.momentum_terms(q, v)      # Mdot = C + C^T: dM/dt by differences
        eps = 1e-6
        dM = (m.mass_matrix(np.add(q, eps * np.array(v))) -
              m.mass_matrix(np.subtract(q, eps * np.array(v)))) / (2 * eps)
        np.testing.assert_allclose(Md, dM, atol=1e-8)
        np.testing.assert_allclose(CTv, Md @ v - Cv, atol=1e-10)


def test_user_order_locking_and_friction():
    m = load_model(["j2", "j1"], robot_description=planar(), viscous_friction=[0.5, 0.1],
                   coulomb_friction=[1.0, 0.0], friction_width=0.05)
    ref = load_model(["j1", "j2"], robot_description=planar())
    q = (0.4, 0.1)
    np.testing.assert_allclose(m.mass_matrix(q[::-1]), ref.mass_matrix(q)[::-1, ::-1])
    np.testing.assert_allclose(m.friction([0.1, 2.0]), [0.05 + math.tanh(2.0), 0.2])
    locked = load_model(["j1"], robot_description=planar(), locked_joints={"j2": 0.0})
    assert locked.mass_matrix([0.3])[0, 0] == pytest.approx(ref.mass_matrix((0.3, 0.0))[0, 0])
    arm = load_model(JOINTS, urdf=URDF)
    assert arm.viscous.tolist()[:2] == [1.0, 1.0] and arm.coulomb[0] == 1.2   # the URDF's
    q = np.array([0.1, 0.5, 0.2, -1.2, 0.3, 0.8, 0.1])
    assert arm.jacobian("link_6", q).shape == (6, 7)
    w = np.array([45.0, -10.0, 5.0, 1.5, -2.0, 0.7])          # (f; m) at link_6's origin
    tau = arm.jacobian("link_6", q).T @ w
    np.testing.assert_allclose(arm.wrench("link_6", q, tau), w, atol=1e-9)
    damped = arm.wrench("link_6", q, tau, damping=1e-3)
    assert np.abs(damped - w).max() < 1e-3 * np.abs(w).max()
    assert np.abs(arm.wrench("link_6", q, tau, damping=1.0) - w).max() > 1e-3


def test_a_frames_pose_moves_as_its_jacobian_says():
    """frame_pose's origin, differentiated along each joint, is the Jacobian's linear column;
    its axes are a rotation."""
    arm = load_model(JOINTS, urdf=URDF)
    q = np.array([0.1, 0.5, 0.2, -1.2, 0.3, 0.8, 0.1])
    R, p = arm.frame_pose("link_6", q)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    J = arm.jacobian("link_6", q)
    for i in range(7):
        d = np.zeros(7)
        d[i] = 1e-6
        dp = (arm.frame_pose("link_6", q + d)[1] - arm.frame_pose("link_6", q - d)[1]) / 2e-6
        np.testing.assert_allclose(dp, J[:3, i], atol=1e-6)


@pytest.mark.parametrize("kwargs, param, words", [
    (dict(robot_description="not xml at all <"), "robot_description", "does not parse"),
    (dict(robot_description="<html/>"), "robot_description", "not <robot>"),
    (dict(robot_description="<robot name='x'><link name='a'/><joint name='j' type='revolute'>"
                            "<parent link='a'/><child link='b'/></joint></robot>"),
     "robot_description", "there is no link 'b'"),
    (dict(robot_description="\x00"), "robot_description", "NUL"),
    (dict(urdf="/nonexistent/arm.urdf"), "plant.urdf", "cannot read"),
    (dict(urdf=str(ROOT)), "plant.urdf", "not a file"),
    (dict(), "plant.urdf", "exactly one"),
])
def test_bad_urdf_sources_are_refused_in_one_line(kwargs, param, words):
    with pytest.raises(ConfigError) as err:
        load_model(["j"], **kwargs)
    assert err.value.parameter == param and words in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("joints, locked, param, words", [
    (["j1", "nope", "zz"], None, "joints", "no movable joint(s) nope, zz"),
    (["j1", "j1"], None, "joints", "twice"),
    (["j1"], {"j3": 0.0}, "plant.locked_joints", "no joint(s) j3"),
    (["j1"], {"j2": float("nan")}, "plant.locked_joints", "finite"),
    (["j1", "j2"], {"j2": 0.0}, "plant.locked_joints", "also in"),
])
def test_bad_joint_lists_are_refused_naming_them(joints, locked, param, words):
    with pytest.raises(ConfigError) as err:
        load_model(joints, robot_description=planar(), locked_joints=locked)
    assert err.value.parameter == param and words in str(err.value)


def test_a_huge_urdf_is_refused_before_parsing(tmp_path, monkeypatch):
    import fto_ros.arm.urdf as model_module

    def no_parse(*args, **kwargs):
        raise AssertionError("a URDF over the size limit was parsed")
    monkeypatch.setattr(model_module.ET, "fromstring", no_parse)
    huge = "<robot>" + " " * (50 * 1024 * 1024) + "</robot>"
    assert MAX_URDF_BYTES < len(huge)
    with pytest.raises(ConfigError, match="larger than"):
        load_model(["j"], robot_description=huge)
    path = tmp_path / "big.urdf"
    path.write_text(huge)
    with pytest.raises(ConfigError, match="larger than"):
        load_model(["j"], urdf=path)


# -- simulation ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def arm():
    return load_model(JOINTS, urdf=URDF)


@pytest.fixture(scope="module")
def clean_contact(arm):
    """Noise-free 2.2 s with a 45 N push on link 6 from 1.0 s for 1.0 s."""
    return simulate_arm(arm, ArmSettings(duration=2.2, noise=0.0, resolution=0.0,
                                         contacts=[Contact("link_6", 1.0, 1.0, (45, 0, 0))]))


def seeded_run(seed: int) -> dict[str, np.ndarray]:
    """0.2 s of the arm with noise drawn from ``seed`` (what the next test runs in two
    processes)."""
    r = simulate_arm(load_model(JOINTS, urdf=URDF), ArmSettings(duration=0.2, seed=seed))
    return {name: getattr(r, name) for name in ("q", "v", "q_measured", "tau")}


def test_simulation_is_reproducible_by_seed():
    """The same seed in two fresh processes: the same simulation, bit for bit; another seed
    another noise; the measurement on the encoder's grid."""
    a, b = run_twice("test_rigid:seeded_run", 4, path=(Path(__file__).resolve().parent,))
    assert_bitwise_equal(a, b)
    c = seeded_run(5)
    assert not np.array_equal(a["q_measured"], c["q_measured"])
    assert np.all(np.abs(a["q_measured"] / 2 ** -18 - np.round(a["q_measured"] / 2 ** -18)) < 1e-6)


# -- fto-simulate --urdf ---------------------------------------------------------------------
def test_fto_simulate_urdf_writes_a_bag_that_reads_back(tmp_path, capsys):
    from fto_ros.cli.simulate import main
    from fto_ros.cli.simulate_arm import read_arm_bag
    out = tmp_path / "arm"
    assert main(["--urdf", str(URDF), "--out", str(out), "--duration", "0.2", "--seed", "7",
                 "--contact", "link_6,0.1,0.05,45,0,0"]) == 0
    r, meta = read_arm_bag(out)
    direct = simulate_arm(load_model(JOINTS, urdf=URDF), ArmSettings(
        duration=0.2, seed=7, contacts=[Contact("link_6", 0.1, 0.05, (45, 0, 0))]))
    for name in ("t", "q", "v", "q_measured", "tau", "tau_ext", "contact"):
        np.testing.assert_allclose(getattr(r, name), getattr(direct, name), rtol=0, atol=1e-9)
    assert meta["joints"] == JOINTS and meta["contacts"][0]["force"] == [45.0, 0.0, 0.0]
    assert r.contact[100, 0] == 1.0 and r.contact[99, 0] == 0.0 and r.contact[150, 0] == 0.0


@pytest.mark.parametrize("args, words", [
    (["--joints", "joint_a1,nope"], "no movable joint(s) nope"),
    (["--contact", "no_link,0.1,0.05,1,0,0"], "no link or frame"),
    (["--lock", "joint_a9=0"], "no joint(s) joint_a9"),
])
def test_fto_simulate_urdf_refuses_bad_arguments_in_one_line(tmp_path, capsys, args, words):
    from fto_ros.cli.simulate import main
    assert main(["--urdf", str(URDF), "--out", str(tmp_path / "x"), "--duration", "0.01",
                 *args]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err and not (tmp_path / "x").exists()
