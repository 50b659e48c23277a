"""The node's ROS interface over DDS: stamped, named estimates; labelled arrays; set_state
(service and topic); refusals that name the parameter; the managed (lifecycle) node driven
through the lifecycle_msgs services.  Processes as in test/support/live_node.py (LOCALHOST
discovery, a domain id of the test's own)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rclpy")
from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

import domains  # noqa: E402
import live_node as L  # noqa: E402
import processes  # noqa: E402
from live_node import NODE, ROOT, Driver, NodeProcess  # noqa: E402

#: live DDS nodes: scripts/run-tests runs these after the rest, one at a time
pytestmark = pytest.mark.live


@pytest.fixture(scope="module")
def plant():
    return L.simulate(1.5)


def _stamped(driver):
    got = []
    qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)

    def cb(m):
        with driver.lock:
            got.append(m)
    driver.node.create_subscription(JointState, NODE + "/state_estimate_stamped", cb, qos)
    return got


def _set_state_request(**values) -> SetParameters.Request:
    req = SetParameters.Request()
    req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
    return req


@pytest.mark.slow
def test_stamped_named_estimates_and_set_state(tmp_path, plant):
    def edit(p):
        p["source"] = "joint_states"
        p["joint_states"].update(input_joints=["joint1"], input_field="effort")
        p["diagnostics"].update(period=0.2, expected_rate=0.0)
        p["output"] = {"frame_id": "motor_link"}
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "iface", edit))
    driver = Driver(domain)
    labels: list = []
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    driver.node.create_subscription(Float64MultiArray, NODE + "/state_estimate",
                                    lambda m: labels.append([(d.label, d.size) for d in m.layout.dim]),
                                    qos)
    stamped = _stamped(driver)
    try:
        driver.wait_connected(node, [driver.pub_js], outputs=("estimated_joint_states",))
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/state_estimate_stamped"), 20,
                        "the stamped publisher", node)
        ts, x, v = plant
        import time
        base_ns = time.time_ns() - 10 * 10**9
        sent = {}
        for k in range(300):
            ns = base_ns + k * 10**6
            m = JointState(name=["joint1"])
            m.header.stamp.sec, m.header.stamp.nanosec = ns // 10**9, ns % 10**9
            m.position, m.velocity, m.effort = [x[k, 0]], [0.0], [v[k]]
            driver.pub_js.publish(m)
            sent[ns] = k
            time.sleep(0.001)
        driver.wait_for(lambda: len(stamped) > 100, 15, "stamped estimates", node)
        # every sample taken before set_state: one still queued would start the restarted
        # observer before the one below (a race on a loaded machine: 2 of 4 runs failed)
        driver.wait_quiet(node, "messages received: joint_states")
        with driver.lock:
            got = list(stamped)
        for m in got:
            ns = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            assert ns in sent, "the stamp is the measurement's own"
            assert list(m.name) == ["q", "q_dot", "current"] and m.header.frame_id == "motor_link"
            assert len(m.position) == 3 and not m.velocity and not m.effort
            assert np.all(np.isfinite(m.position))
        assert labels and labels[-1] == [("q", 1), ("q_dot", 1), ("current", 1)]

        # set_state, service form: one parameter per state ...
        res = driver.call(SetParameters, NODE + "/set_state",
                          _set_state_request(q=0.1, q_dot=-2.0, current=0.5)).results
        assert len(res) == 3 and all(r.successful for r in res), res
        st = driver.status_where(lambda s: L.count(s, "restarts: set_state") == 1, 10,
                                 "the set_state restart counted", node)
        assert st is not None
        # ... or one double_array; refused when the length or a value is wrong
        res = driver.call(SetParameters, NODE + "/set_state",
                          _set_state_request(state=[0.1, 0.0])).results
        assert not res[0].successful and "state_wrong_length" in res[0].reason, res
        res = driver.call(SetParameters, NODE + "/set_state",
                          _set_state_request(state=[0.1, float("nan"), 0.0])).results
        assert not res[0].successful and "state_non_finite" in res[0].reason, res
        res = driver.call(SetParameters, NODE + "/set_state", _set_state_request(q=1.0)).results
        assert not res[0].successful and "q_dot" in res[0].reason, res
        res = driver.call(SetParameters, NODE + "/set_state",
                          _set_state_request(state=[0.2, 1.0, -1.0])).results
        assert res[0].successful, res
        # topic form
        pub = driver.node.create_publisher(JointState, NODE + "/set_state", 10)
        driver.wait_for(lambda: pub.get_subscription_count() > 0, 10, "the set_state topic", node)
        pub.publish(JointState(name=["q", "q_dot", "current"], position=[0.3, 0.0, 0.0]))
        st = driver.status_where(lambda s: L.count(s, "restarts: set_state") == 3, 10,
                                 "three set_state restarts counted", node)
        # the next sample starts from the given state: its estimate of the unmeasured states
        k0 = 400
        ns = base_ns + k0 * 10**6
        m = JointState(name=["joint1"])
        m.header.stamp.sec, m.header.stamp.nanosec = ns // 10**9, ns % 10**9
        m.position, m.velocity, m.effort = [x[k0, 0]], [0.0], [v[k0]]
        driver.pub_js.publish(m)

        def after():
            with driver.lock:
                return next((e for e in stamped if e.header.stamp.sec * 10**9
                             + e.header.stamp.nanosec == ns), None)
        first = driver.wait_for(after, 10, "the estimate after set_state", node)
        np.testing.assert_allclose(first.position, [0.3, 0.0, 0.0], atol=1e-12)
        # an undeclared parameter is refused naming it
        r = driver.set_parameter("luenberger.polse", [1.0])
        assert not r.successful and "luenberger.polse" in r.reason, r.reason
    finally:
        driver.close()
        assert node.stop() == 0, node.log()


def _lifecycle(driver, transition: int):
    req = ChangeState.Request()
    req.transition = Transition(id=transition)
    return driver.call(ChangeState, NODE + "/change_state", req).success


def _state(driver) -> int:
    return driver.call(GetState, NODE + "/get_state", GetState.Request()).current_state.id


@pytest.mark.slow
def test_managed_node_through_the_lifecycle_services(tmp_path, plant):
    def edit(p):
        p["diagnostics"].update(period=0.2, expected_rate=0.0)
    domain = domains.take()
    params = L.params_file(tmp_path, "managed", edit)
    node = NodeProcess(tmp_path, domain, params, module="fto_ros.nodes.managed_node")
    driver = Driver(domain)
    try:
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/transition_event") > 0
                        or _has_service(driver), 30, "the lifecycle services", node)
        assert _state(driver) == State.PRIMARY_STATE_UNCONFIGURED
        assert driver.node.count_publishers(NODE + "/state_estimate") == 0    # nothing yet
        assert _lifecycle(driver, Transition.TRANSITION_CONFIGURE)
        assert _state(driver) == State.PRIMARY_STATE_INACTIVE
        assert driver.node.count_publishers(NODE + "/state_estimate") == 0    # inactive: no I/O
        assert _lifecycle(driver, Transition.TRANSITION_ACTIVATE)
        assert _state(driver) == State.PRIMARY_STATE_ACTIVE
        driver.wait_connected(node, [driver.pub_y, driver.pub_u])
        L.feed(driver, plant, 200)
        st = driver.status_where(lambda s: L.count(s, "samples accepted") >= 100, 15,
                                 "accepted samples", node)
        accepted = L.count(st, "samples accepted")
        # deactivate: no outputs, the state kept
        assert _lifecycle(driver, Transition.TRANSITION_DEACTIVATE)
        assert _state(driver) == State.PRIMARY_STATE_INACTIVE
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/state_estimate") == 0, 10,
                        "the outputs gone", node)
        n_est = len(driver.got("state_estimate"))
        L.feed(driver, plant, 50, start=200)
        assert len(driver.got("state_estimate")) == n_est
        # activate again: it goes on from where it was (no restart counted)
        assert _lifecycle(driver, Transition.TRANSITION_ACTIVATE)
        driver.wait_connected(node, [driver.pub_y, driver.pub_u])
        L.feed(driver, plant, 100, start=250)
        st = driver.status_where(lambda s: L.count(s, "samples accepted") > accepted + 50, 15,
                                 "samples after re-activation", node)
        assert not any(k.startswith("restarts:") for k in st["values"]), \
            {k: v for k, v in st["values"].items() if k.startswith(("restarts:", "rejected:"))}
        assert float(st["values"]["time since start (s)"]) > 0.2
        # cleanup and shutdown
        assert _lifecycle(driver, Transition.TRANSITION_DEACTIVATE)
        assert _lifecycle(driver, Transition.TRANSITION_CLEANUP)
        assert _state(driver) == State.PRIMARY_STATE_UNCONFIGURED
        assert _lifecycle(driver, Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
        assert _state(driver) == State.PRIMARY_STATE_FINALIZED
    finally:
        driver.close()
        node.stop()


def _has_service(driver) -> bool:
    return any(name == NODE + "/change_state" for name, _ in driver.node.get_service_names_and_types())


@pytest.mark.slow
def test_managed_node_autostart_and_a_bad_parameter(tmp_path, plant):
    """autostart configures and activates at start-up; a bad parameter fails the configure
    transition with one line naming it (exit 2 under autostart)."""
    def edit(p):
        p["autostart"] = True
        p["diagnostics"].update(period=0.2, expected_rate=0.0)
    domain = domains.take()
    params = L.params_file(tmp_path, "auto", edit)
    env = L.ros_env(domain, tmp_path)
    proc = processes.spawn([sys.executable, "-m", "fto_ros.nodes.managed_node", "--ros-args",
                            "--params-file", str(params)], domain=domain, cwd=ROOT, env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    driver = Driver(domain)
    try:
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/state_estimate") > 0, 30,
                        "the outputs of the autostarted node")
        assert _state(driver) == State.PRIMARY_STATE_ACTIVE
    finally:
        driver.close()
        processes.interrupt(proc, 15)
    bad = L.params_file(tmp_path, "bad", lambda p: (edit(p), p["luenberger"].update(poles=[1.0, 2.0, 3.0])))
    res = processes.run([sys.executable, "-m", "fto_ros.nodes.managed_node", "--ros-args",
                         "--params-file", str(bad)], cwd=ROOT, env=env, capture_output=True,
                        timeout=60)
    out = (res.stdout + res.stderr).strip()
    assert res.returncode == 2, out
    assert "luenberger.poles" in out and "Traceback" not in out, out
