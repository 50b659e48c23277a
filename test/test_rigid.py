"""Arms from their URDF (fto_ros.arm, fto_ros.models.arm, fto-simulate --urdf): dynamics
against hand-computed cases, refusals, the estimators' claims, collision detection on the
committed bags, reproducibility (junk into the new inputs: test_faults_arm.py). ROS-free."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.differentiator import Differentiator
from fto_ros.core.errors import ConfigError
from fto_ros.models.arm import ArmSettings, Contact, simulate_arm
from fto_ros.arm import load_model, steps
from fto_ros.arm.collision import CollisionDetector, detection_time, threshold_sigmas
from fto_ros.arm.external_torque import WindowEstimator, run_over
from fto_ros.arm.source import MAX_URDF_BYTES

ROOT = Path(__file__).resolve().parents[1]
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
    f = np.array([45.0, -10.0, 5.0])
    tau = arm.jacobian("link_6", q)[:3].T @ f
    np.testing.assert_allclose(arm.wrench("link_6", q, tau, force_only=True), [*f, 0, 0, 0],
                               atol=1e-9)
    np.testing.assert_allclose(arm.jacobian("link_6", q).T @ arm.wrench("link_6", q, tau), tau,
                               atol=1e-9)


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
    (["j1", "nope", "zz"], None, "plant.joints", "no movable joint(s) nope, zz"),
    (["j1", "j1"], None, "plant.joints", "twice"),
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


def test_simulation_is_reproducible_by_seed(arm):
    a, b, c = (simulate_arm(arm, ArmSettings(duration=0.2, seed=s)) for s in (4, 4, 5))
    for name in ("q", "v", "q_measured", "tau"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.q_measured, c.q_measured)
    assert np.all(np.abs(a.q_measured / 2 ** -18 - np.round(a.q_measured / 2 ** -18)) < 1e-6)


def run(est, r):
    return run_over(est, r.t, r.q_measured, r.tau)


def test_window_estimate_is_exact_after_its_window_without_noise(arm, clean_contact):
    """tau_ext_hat(t) = the kernel's average of the true tau_ext over [t - T, t] from t = T
    after the restart, contact onset included (errors: quadrature and velocity terms)."""
    r = clean_contact
    est = WindowEstimator(arm, window=0.03)
    E, V = run(est, r)
    W = est.samples
    weights = np.diff(steps.kernel(np.arange(W + 1) / W, -1))
    avg = np.full_like(E, np.nan)
    for k in range(W, r.t.size):
        avg[k] = weights @ r.tau_ext[k - 1 - np.arange(W)]
    assert np.all(np.isnan(E[:W])) and np.all(np.isfinite(E[W:]))
    err = np.abs(E - avg)[W + 1:]
    assert err.max() < 0.1                  # measured 0.056 (the onset of 28.6 Nm), 1e-3 before
    assert np.abs(E - avg)[(r.t > 0.05) & (r.t < 1.0)].max() < 5e-3
    assert est.step_response(0.03) == 1.0 and est.step_response(0.015) == pytest.approx(0.5)
    # the differentiator's velocities (the small velocity terms' provisional values and the
    # published velocity) in free motion; it lags the contact's acceleration jumps
    assert np.sqrt(np.mean((V - r.v)[(r.t > 0.05) & (r.t < 1.0)] ** 2)) < 1e-3


def test_momentum_observer_is_a_first_order_filter_of_tau_ext(arm, clean_contact):
    """The GMO step on the true velocities: r' = K (tau_ext - r)."""
    r = clean_contact
    K = 50.0
    state, ref = steps.gmo_init(7), np.zeros(7)
    worst = 0.0
    for k in range(r.t.size):
        q, v = r.q[k], r.v[k]
        M, _, CTv, g = arm.momentum_terms(q, v)
        state = steps.gmo_step(state, np.full(7, K), 1e-3, q, r.tau[k], M @ v,
                               CTv - g - arm.friction(v))
        if k:
            ref = ref + (1 - math.exp(-K * 1e-3)) * (r.tau_ext[k - 1] - ref)
            worst = max(worst, np.abs(steps.gmo_output(state, 7) - ref).max())
        if r.t[k] == pytest.approx(1.0 + 1 / K):
            assert steps.gmo_output(state, 7)[1] / r.tau_ext[k, 1] == \
                pytest.approx(1 - math.exp(-1), abs=0.03)
    assert worst < 0.02 * np.abs(r.tau_ext).max()


def test_collision_detected_on_the_committed_bag_within_10_ms():
    from fto_ros.cli.simulate_arm import read_arm_bag
    r, meta = read_arm_bag(ROOT / "bags" / "arm7_contact_link6")
    assert meta["contacts"][0]["link"] == "link_6" and r.q.shape == (10001, 7)
    model = load_model(JOINTS, urdf=URDF)
    est = WindowEstimator(model, window=0.03)
    det = CollisionDetector(7, calibration=2.0)
    events = []
    for k in range(r.t.size):
        out = est.update(r.t[k], r.q_measured[k], r.tau[k])
        if out is not None and r.t[k] >= 0.5:
            ev = det.update(r.t[k], out, est.noise_gain(r.q_measured[k]))
            if ev:
                events.append(ev)
        if r.t[k] > 6.5:
            break
    assert det.z == pytest.approx(threshold_sigmas(1e-2, 1000, 7)) and det.z > 6
    # every detection is during the contact (6.0-6.08 s) or its release; joint_a2 (28.6 Nm)
    # fires within 10 ms, and within the guaranteed time for its size
    assert events and all(6.0 < ev.t < 6.2 for ev in events) and events[0].t <= 6.010
    t2 = min(ev.t for ev in events if 1 in ev.joints)
    gain = est.noise_gain(r.q_measured[6000])[1]
    dt = detection_time(est.step_response, 28.5, det.threshold[1] * gain, det.sigma[1] * gain)
    assert t2 - 6.0 <= dt + 1e-3 and dt < 0.01


def test_no_detection_on_the_contact_free_bag():
    from fto_ros.cli.simulate_arm import read_arm_bag
    r, _ = read_arm_bag(ROOT / "bags" / "arm7_free")
    est = WindowEstimator(load_model(JOINTS, urdf=URDF), window=0.03)
    det = CollisionDetector(7, calibration=2.0)
    for k in range(r.t.size):
        out = est.update(r.t[k], r.q_measured[k], r.tau[k])
        if out is not None and r.t[k] >= 0.5:
            assert det.update(r.t[k], out, est.noise_gain(r.q_measured[k])) is None
    # calibrated in radians of encoder noise: the encoder's 1e-5, at its upper bound
    assert np.all((det.sigma > 0.95e-5) & (det.sigma < 1.25e-5))


def test_detector_rearms_after_the_contact():
    det = CollisionDetector(1, sigma=[1.0], hold=0.01)
    th = det.threshold[0]
    seq = [0.0] * 5 + [2 * th] * 5 + [0.0] * 20 + [2 * th]
    events = [det.update(k * 1e-3, [x]) for k, x in enumerate(seq)]
    fired = [k for k, e in enumerate(events) if e]
    assert fired == [5, 30]


# -- steps: reuse of the differentiator, junk -----------------------------------------------
def test_red_step_is_the_package_differentiator():
    rng = np.random.default_rng(0)
    c = steps.red_consts(2, 20.0, 2.0)
    d = Differentiator(2, 20.0, channels=3, rho=2.0)
    f = rng.standard_normal(3)
    d.reset(f)
    s = steps.red_init(c, f)
    for k in range(200):
        f = np.sin(0.01 * k + np.arange(3)) + 1e-4 * rng.standard_normal(3)
        ref = d.update(1e-3, f)
        s = steps.red_step(s, c, 1e-3, f)
        np.testing.assert_allclose(steps.red_output(s, c, 3), ref, rtol=1e-12, atol=1e-12)


def test_window_step_never_writes_its_input_state(arm):
    c = steps.window_consts(7, 8, 1e-3, arm.viscous)
    s = steps.window_init(c)
    s[:] = np.arange(s.size)
    before = s.copy()
    M = np.eye(7)
    bad = [dict(y=np.full(7, np.nan)), dict(u=np.full(7, np.inf)), dict(h=2e-3), dict(h=-1.0),
           dict(M=np.full((7, 7), np.nan))]
    for b in bad:
        args = dict(h=1e-3, y=np.zeros(7), u=np.zeros(7), M=M, Mdot=M, phi=np.zeros(7)) | b
        with pytest.raises(ValueError):
            steps.window_step(s, c, args["h"], args["y"], args["u"], args["M"], args["Mdot"],
                              args["phi"])
    np.testing.assert_array_equal(s, before)


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


def test_the_main_jobs_torque_table_compares_the_three_estimators(tmp_path):
    """fto-report's arm table (cli/torque_table.py) on the contact-free bag: a row per
    estimator, this package's window quieter in free motion than the momentum observer,
    no false alarm."""
    from fto_ros.cli.torque_table import MAIN_JOB, table
    (tmp_path / "arm7_free").symlink_to(ROOT / "bags" / "arm7_free")
    text = table(tmp_path, ROOT / "urdf" / "arm7.urdf")
    rows = [line.split(" | ") for line in text.splitlines()[2:]]
    assert [r[0].lstrip("| ") for r in rows] == list(MAIN_JOB)
    rms = {r[0].lstrip("| "): float(r[3]) for r in rows}
    window, gmo = list(MAIN_JOB)[:2]
    assert rms[window] < 0.5 * rms[gmo]
    assert all(r[6].rstrip(" |") == "0" for r in rows)
    assert table(tmp_path / "none", ROOT / "urdf" / "arm7.urdf") is None
