"""The external-torque node (nodes/torque_node.py) and its loop (runner/torque_loop.py).

Offline: the loop over junk (a NaN or huge joint, a missing or duplicated joint, a short
effort array, bad stamps) refuses and counts per joint, never mis-assigns, and restarts
after a refused sample; reordered names give the same estimates bit for bit.

Live (over DDS, the node as a subprocess as a user starts it): the node's external torques
equal the loop's offline on the same messages (bags/arm7_contact_link6 from 4.5 s to 6.2 s,
names reversed on every other message, a NaN joint and a missing joint injected); the contact
at 6.0 s is published on ~/collision within 10 ms of its start (the issue's target), as the
offline loop finds it, and nothing fires before; refusals exit 2 with one line; the launch
file starts the node under the real `ros2 launch`.
"""
from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from fto_ros.cli.simulate_arm import read_arm_bag
from fto_ros.core.reasons import CODE
from fto_ros.runner.torque_loop import TorqueLoop
from fto_ros.runner.torque_settings import build

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "urdf" / "arm7.urdf"
JOINTS = [f"joint_a{i}" for i in range(1, 8)]
BAG = ROOT / "bags" / "arm7_contact_link6"
CONTACT_T = 6.0                      # the bag's contact (metadata: 45 N on link_6 at 6 s)
T0, T1 = 4.5, 6.2                    # the slice the live test publishes
BASE_NS = 1_000_000_000              # stamps: 1 s + the bag's time
PARAMS = {"plant.urdf": str(URDF), "collision.calibration": 0.5}


@pytest.fixture(scope="module")
def arm_run():
    run, _ = read_arm_bag(BAG)
    return run


def _messages(run):
    """(stamp ns, names, positions, efforts) of the slice, with the injected junk."""
    out = []
    for k in np.flatnonzero((run.t >= T0 - 1e-9) & (run.t <= T1 + 1e-9)):
        q, tau = run.q_measured[k].copy(), run.tau[k].copy()
        names = list(JOINTS)
        if k % 2:                                     # reordered names
            names, q, tau = names[::-1], q[::-1], tau[::-1]
        t = run.t[k]
        if abs(t - 4.6) < 5e-4:                       # a NaN joint
            q[names.index("joint_a3")] = math.nan
        if abs(t - 4.7) < 5e-4:                       # a missing joint
            i = names.index("joint_a5")
            names, q, tau = names[:i] + names[i + 1:], np.delete(q, i), np.delete(tau, i)
        out.append((BASE_NS + int(round(t * 1e9)), names, q, tau))
    return out


def _offline(messages, params=PARAMS):
    loop = TorqueLoop(build(params))
    est, hits = {}, []
    for ns, names, q, tau in messages:
        res = loop.process(ns, names, q, tau)
        if res is not None and res.tau_ext is not None:
            est[ns] = res.tau_ext.copy()
        if res is not None and res.collision is not None:
            hits.append((ns, tuple(JOINTS[i] for i in res.collision.joints)))
    return loop, est, hits


# ------------------------------------------------------------------------------- offline
def test_reordered_names_give_the_same_estimates_bit_for_bit(arm_run):
    k = np.flatnonzero(arm_run.t >= T0)[:120]
    msgs = [(BASE_NS + int(round(arm_run.t[i] * 1e9)), JOINTS, arm_run.q_measured[i],
             arm_run.tau[i]) for i in k]
    perm = [3, 0, 6, 1, 5, 2, 4]
    shuffled = [(ns, [n[i] for i in perm], q[perm], tau[perm]) for ns, n, q, tau in msgs]
    _, a, _ = _offline(msgs)
    _, b, _ = _offline(shuffled)
    assert a and a.keys() == b.keys()
    assert all(np.array_equal(a[s], b[s]) for s in a)


@pytest.mark.parametrize("junk, reason", [
    ("nan_position", "measurement_non_finite"), ("huge_position", "measurement_implausible"),
    ("inf_effort", "input_non_finite"), ("missing", "joint_states_joint_missing"),
    ("duplicate", "joint_states_duplicate_joint"), ("short_effort", "joint_states_effort_missing"),
])
def test_a_junk_joint_is_refused_counted_per_joint_and_restarts(arm_run, junk, reason):
    """The sample is refused with the joint's reason, counted on that joint only; the
    estimators restart at the next good sample (a gap), no estimate is NaN, and an estimate
    is back one window later."""
    loop = TorqueLoop(build(PARAMS))
    W = loop.est.samples
    k0 = int(np.flatnonzero(arm_run.t >= T0)[0])
    bad_at = W + 20
    published = []
    for j in range(3 * W):
        k = k0 + j
        names, q, tau = list(JOINTS), list(arm_run.q_measured[k]), list(arm_run.tau[k])
        if j == bad_at:
            if junk == "nan_position":
                q[2] = math.nan
            elif junk == "huge_position":
                q[2] = 1e300
            elif junk == "inf_effort":
                tau[2] = math.inf
            elif junk == "missing":
                del names[2], q[2], tau[2]
            elif junk == "duplicate":
                names[4] = names[2]
            elif junk == "short_effort":
                tau = tau[:-1]
        res = loop.process(BASE_NS + int(round(arm_run.t[k] * 1e9)), names, q, tau)
        if j == bad_at:
            assert res is None
        elif res is not None and res.tau_ext is not None:
            assert np.all(np.isfinite(res.tau_ext))
            published.append(j)
    assert loop.rejected == {reason: 1}
    counted = [sum(c.values()) for c in loop.joint_rejected]
    if junk == "short_effort":        # the field is unusable for every joint
        assert counted == [1] * 7
    elif junk == "duplicate":         # joint_a3 named twice, joint_a5 missing
        assert counted[2] == 1 and counted[4] == 1 and sum(counted) == 2
    else:
        assert counted[2] == 1 and sum(counted) == 1
    assert dict(loop.restarts) == {"gap": 1}
    assert bad_at - 1 in published and bad_at + 1 not in published
    assert bad_at + 1 + W in published                  # back one window after the restart


def test_bad_stamps_are_refused_and_a_jump_back_restarts(arm_run):
    loop = TorqueLoop(build(PARAMS))
    k0 = int(np.flatnonzero(arm_run.t >= T0)[0])
    msg = lambda k: (JOINTS, arm_run.q_measured[k], arm_run.tau[k])  # noqa: E731
    ns = lambda k: BASE_NS + int(round(arm_run.t[k] * 1e9))  # noqa: E731
    assert loop.process(0, *msg(k0)) is None
    assert loop.process(ns(k0), *msg(k0)) is not None
    assert loop.process(ns(k0), *msg(k0)) is None                       # repeated
    assert loop.process(ns(k0) - 1000, *msg(k0)) is None                # backwards
    assert loop.process(ns(k0) + 100_000, *msg(k0)) is None             # too close
    assert loop.process(ns(k0) - 2 * BASE_NS // 3, *msg(k0 + 1)) is not None   # jump back
    assert loop.rejected == {"zero_stamp": 1, "repeated_stamp": 1, "stamp_backwards": 1,
                             "stamp_too_close": 1}
    assert loop.restarts == {"time_jump": 1}
    assert CODE["stamp_too_close"]


def test_offline_detects_the_contact_within_10_ms(arm_run):
    loop, est, hits = _offline(_messages(arm_run))
    assert hits, "no detection"
    first = (hits[0][0] - BASE_NS) * 1e-9
    assert CONTACT_T <= first <= CONTACT_T + 0.010, hits
    assert loop.rejected == {"measurement_non_finite": 1, "joint_states_joint_missing": 1}


def test_wrench_at_the_contact_link_is_the_bags_force(arm_run):
    """wrench.link = link_6 (force only): T after the 45 N push along x starts, the wrench
    through the Jacobian is that force within 2 %; before it, within 0.2 N of zero."""
    loop = TorqueLoop(build(dict(PARAMS, **{"wrench.link": "link_6", "wrench.force_only": True})))
    got = {}
    for k in range(int(np.searchsorted(arm_run.t, 5.0)), int(np.searchsorted(arm_run.t, 6.075))):
        res = loop.process(BASE_NS + int(round(arm_run.t[k] * 1e9)), JOINTS,
                           arm_run.q_measured[k], arm_run.tau[k])
        got[round(arm_run.t[k], 3)] = res.wrench
    assert np.max(np.abs(got[5.9])) < 0.2
    assert np.allclose(got[6.07][:3], [45.0, 0.0, 0.0], atol=0.02 * 45) and not got[6.07][3:].any()


def test_a_wrench_link_the_urdf_has_not_is_refused_by_name():
    from fto_ros.core.errors import ConfigError
    with pytest.raises(ConfigError, match="parameter 'wrench.link': the URDF has no link"):
        build(dict(PARAMS, **{"wrench.link": "link_9"}))


def test_compiled_steps_equal_the_numpy_steps(arm_run):
    """The window estimator through steps_compiled (numba) and through steps (numpy) on 1.5 s
    of the contact bag around the contact: the same estimates up to rounding."""
    from fto_ros.core import jit
    from fto_ros.arm.external_torque import WindowEstimator, run_over
    if not jit.ENABLED:
        pytest.skip("numba is off (FTO_ROS_NUMBA=0): the compiled steps are the numpy ones")
    model = build(PARAMS).model
    sl = slice(int(np.searchsorted(arm_run.t, 5.0)), int(np.searchsorted(arm_run.t, 6.5)))
    args = (arm_run.t[sl], arm_run.q_measured[sl], arm_run.tau[sl])
    Ec, Vc = run_over(WindowEstimator(model, compiled=True), *args)
    En, Vn = run_over(WindowEstimator(model, compiled=False), *args)
    assert np.array_equal(np.isnan(Ec), np.isnan(En)) and np.isfinite(Ec[-1]).all()
    assert np.nanmax(np.abs(Ec - En)) <= 1e-9 and np.max(np.abs(Vc - Vn)) <= 1e-10
    assert np.nanmax(np.abs(En)) > 10                       # the contact is in the slice


# ---------------------------------------------------------------------------------- live
rclpy = pytest.importorskip("rclpy")
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from test_node_live import NodeProcess, _domain, _hold, _ros_env  # noqa: E402

NODE = "/external_torque_node"
MODULE = "fto_ros.nodes.torque_node"
START_S = 60


class Driver:
    """The test's rclpy node: publishes the arm's JointState, collects the outputs."""

    def __init__(self, domain: int):
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.domain = domain
        _hold(domain, 1)
        self.node = rclpy.create_node("fto_test_torque_driver", context=self.ctx)
        self.lock = threading.Lock()
        self.torque, self.collision, self.status = {}, [], {}
        rel = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(JointState, "/external_torque", self._on_torque, rel)
        self.node.create_subscription(JointState, NODE + "/collision", self._on_collision, rel)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)
        self.pub = self.node.create_publisher(JointState, "/joint_states", rel)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # shutdown while spinning
            pass

    @staticmethod
    def _ns(msg) -> int:
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def _on_torque(self, msg):
        with self.lock:
            self.torque[self._ns(msg)] = (list(msg.name), np.array(msg.effort))

    def _on_collision(self, msg):
        with self.lock:
            self.collision.append((self._ns(msg), tuple(msg.name), np.array(msg.effort)))

    def _on_diag(self, msg):
        with self.lock:
            for st in msg.status:
                if st.hardware_id == "external_torque_node":
                    self.status[st.name] = {kv.key: kv.value for kv in st.values}

    def wait_for(self, cond, timeout: float, what: str, node: NodeProcess):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                value = cond()
            if value:
                return value
            node.check_alive()
            time.sleep(0.05)
        with self.lock:
            last = {k: v for k, v in self.status.items() if k.endswith("external torque")}
        pytest.fail(f"timed out waiting for {what} (last status: {last}):\n{node.log()[-3000:]}")

    def publish(self, ns, names, q, tau):
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
        msg.name, msg.position, msg.effort = list(names), [float(x) for x in q], \
            [float(x) for x in tau]
        self.pub.publish(msg)

    def close(self):
        self.executor.shutdown(timeout_sec=2)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        self.thread.join(5)
        _hold(self.domain, -1)


def _node(tmp_path, domain, *params: str) -> NodeProcess:
    args = [a for p in params for a in ("-p", p)]
    return NodeProcess(tmp_path, domain, None, *args, module=MODULE)


@pytest.mark.live
def test_live_estimates_equal_offline_and_the_contact_is_published(tmp_path, arm_run):
    """Every published tau_ext equals the offline loop's on the same messages (to 1e-9 Nm);
    ~/collision fires within 10 ms of the contact's start, on the joints and at the stamp
    the offline loop finds, never before; /diagnostics counts the junk per joint."""
    messages = _messages(arm_run)
    loop, offline, hits = _offline(messages)
    domain = _domain(225)
    node = _node(tmp_path, domain, f"plant.urdf:={URDF}", "collision.calibration:=0.5",
                 "diagnostics.period:=0.2")
    driver = Driver(domain)
    try:
        driver.wait_for(lambda: driver.pub.get_subscription_count() > 0 and driver.status,
                        START_S, "the node's subscription and /diagnostics", node)
        for i, m in enumerate(messages):
            driver.publish(*m)
            if i % 10 == 9:
                # ~200 messages/s: the stamps, not the pace, are the node's time, and a
                # best-effort input on a loaded machine loses nothing at that pace
                time.sleep(0.05)
        summary = f"{NODE.lstrip('/')}: external torque"
        done = driver.wait_for(
            lambda: driver.status.get(summary, {}).get("accepted") == str(loop.accepted)
            and len(driver.torque) >= len(offline) and driver.status, 30,
            f"{loop.accepted} samples accepted", node)
        assert done
        with driver.lock:
            torque, collision = dict(driver.torque), list(driver.collision)
            status = dict(driver.status)
    finally:
        driver.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.log(), node.log()
    assert torque.keys() == offline.keys()
    worst = max(float(np.max(np.abs(torque[s][1] - offline[s]))) for s in offline)
    assert worst <= 1e-9, worst
    assert all(torque[s][0] == JOINTS for s in torque)
    assert [(s, names) for s, names, _ in collision] == hits
    first = (collision[0][0] - BASE_NS) * 1e-9
    assert CONTACT_T <= first <= CONTACT_T + 0.010, collision
    values = status[f"{NODE.lstrip('/')}: external torque"]
    assert values["rejected.measurement_non_finite"] == "1"
    assert values["rejected.joint_states_joint_missing"] == "1"
    assert status[f"{NODE.lstrip('/')}: joint_a3"]["rejected.measurement_non_finite"] == "1"
    assert status[f"{NODE.lstrip('/')}: joint_a5"]["rejected.joint_states_joint_missing"] == "1"
    a2 = status[f"{NODE.lstrip('/')}: joint_a2"]
    assert float(a2["threshold_Nm"]) > 0 and 0 < float(a2["guaranteed_detection_ms"]) < 60


BAD_URDF = ('<robot name="r"><link name="a"/><joint name="j" type="revolute">'
            '<parent link="a"/><child link="nowhere"/><axis xyz="0 0 1"/>'
            '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>')


@pytest.mark.live
@pytest.mark.parametrize("params, names", [
    (("plant.urdf:={bad}",), "'plant.urdf': joint 'j': there is no link"),
    ((f"plant.urdf:={URDF}", "plant.joints:=[joint_a1, elbow]"), "'plant.joints'"),
    (("robot_description:=this is not xml",), "'robot_description': not a URDF"),
], ids=["urdf_refused", "joints_it_has_not", "robot_description_not_xml"])
def test_refusals_exit_2_with_one_line(tmp_path, params, names):
    import subprocess
    import sys
    bad = tmp_path / "bad.urdf"
    bad.write_text(BAD_URDF)
    args = [a for p in params for a in ("-p", p.format(bad=bad))]
    res = subprocess.run([sys.executable, "-m", MODULE, "--ros-args", *args], cwd=ROOT,
                         env=_ros_env(_domain(226), tmp_path), capture_output=True, text=True,
                         timeout=120)
    lines = [ln for ln in (res.stdout + res.stderr).splitlines() if ln.strip()]
    assert res.returncode == 2, lines
    assert len(lines) == 1 and names in lines[0] and "bad parameter" in lines[0], lines


@pytest.mark.live
@pytest.mark.slow
def test_launch_file_starts_the_node_under_ros2_launch(tmp_path):
    import ros2_cli
    ros2_cli.ros2_command()
    prefix = ros2_cli.ament_prefix(tmp_path / "prefix")
    domain = _domain(227)
    env = ros2_cli.env_for(_ros_env(domain, tmp_path), prefix)
    launch = NodeProcess(tmp_path, domain, None, env=env, cmd=ros2_cli.argv(
        "launch", "fto_ros", "arm7_external_torque.launch.py", f"urdf:={URDF}"))
    driver = Driver(domain)
    try:
        driver.wait_for(lambda: driver.status, 90, "the node's /diagnostics", launch)
    finally:
        driver.close()
        code = launch.stop()
    log = launch.log()
    assert code == 0, log
    assert "Traceback" not in log and "[ERROR]" not in log, log


@pytest.mark.live
@pytest.mark.slow
def test_autostart_false_waits_for_ros2_lifecycle(tmp_path):
    """-p autostart:=false: the node stays unconfigured (no /diagnostics) until `ros2
    lifecycle set` configures and activates it; deactivate stops its /diagnostics."""
    import ros2_cli
    ros2_cli.ros2_command()
    domain = _domain(227)
    env = ros2_cli.env_for(_ros_env(domain, tmp_path), ros2_cli.ament_prefix(tmp_path / "p"))
    node = _node(tmp_path, domain, f"plant.urdf:={URDF}", "autostart:=false",
                 "diagnostics.period:=0.2")
    driver = Driver(domain)
    try:
        got = driver.wait_for(lambda: "unconfigured" in ros2_cli.run(
            env, "lifecycle", "get", NODE).stdout, START_S, "the unconfigured node", node)
        assert got and not driver.status
        for transition in ("configure", "activate"):
            res = ros2_cli.run(env, "lifecycle", "set", NODE, transition)
            assert "Transitioning successful" in res.stdout, res.stdout
        driver.wait_for(lambda: driver.status, 30, "/diagnostics once active", node)
        res = ros2_cli.run(env, "lifecycle", "set", NODE, "deactivate")
        assert "Transitioning successful" in res.stdout, res.stdout
        time.sleep(0.5)
        with driver.lock:
            driver.status.clear()
        time.sleep(1.0)
        with driver.lock:
            assert not driver.status
    finally:
        driver.close()
        code = node.stop()
    assert code == 0 and "Traceback" not in node.log(), node.log()
