"""Fault injection against the live node over DDS, the live families of issue 19: a second
publisher on the data topic (another robot, its clock 100 s behind) and on the float topics,
a burst of 1000 ~/reset calls, every lifecycle transition from every state, run-time
parameter values that cannot build an observer, and a stream faster than the node (lost
messages).  (Junk in the stream and a stall: test_faults_live.py.)

What must hold: the node survives, publishes nothing non-finite, accounts for every message
it received, answers every call, refuses what cannot run with a reason and runs on.  ROS
traffic stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a domain id of the
test's own)."""
from __future__ import annotations

import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from sensor_msgs.msg import JointState  # noqa: E402

import domains  # noqa: E402
import live_node as L  # noqa: E402
from faultkit import COUNTS  # noqa: E402
from live_node import NODE, ROOT, T_CONVERGED, TOL, Driver, NodeProcess  # noqa: E402

#: live DDS nodes: scripts/run-tests runs these after the rest, one at a time
pytestmark = pytest.mark.live


# ------------------------------------------------------------------- issue 19: live families
class SecondRobot:
    """Another publisher on the node's data topics (its own context and node)."""

    def __init__(self, domain: int):
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64MultiArray
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("second_robot", context=self.ctx)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_js = self.node.create_publisher(JointState, "/dc_motor/joint_states", qos)
        self.pub_y = self.node.create_publisher(Float64MultiArray, "/dc_motor/measured_output", qos)
        self.pub_u = self.node.create_publisher(Float64MultiArray, "/dc_motor/input", qos)

    def close(self):
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def _js(ns: int, q: float, v: float) -> JointState:
    m = JointState(name=["joint1"])
    m.header.stamp = L.stamp(ns)
    m.position, m.velocity, m.effort = [q], [0.0], [v]
    return m


@pytest.mark.slow
def test_a_second_source_on_the_topic_is_rejected_never_mixed(tmp_path):
    """Two robots publish the same joint on one topic, the second's clock 100 s behind.  Was:
    gap and time-jump restarts by the dozen, estimates from the other robot's data, stamps
    going backwards.  Now the first publisher seen owns the topic: the other's samples are
    rejected as 'second_source' (counted) and never reach the estimate; once the owner has
    been silent for time.max_gap, the other takes over with one restart ('source_change')."""
    def edit(p):
        p["source"] = "joint_states"
        p["joint_states"].update(input_joints=["joint1"], input_field="effort")
        p["diagnostics"].update(period=0.2, expected_rate=0.0)
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "sources", edit))
    driver = Driver(domain, outputs=("estimated_joint_states",))
    other = SecondRobot(domain)
    ts, x, v = plant = L.simulate(5.0)
    try:
        driver.wait_connected(node, [driver.pub_js, other.pub_js],
                              outputs=("estimated_joint_states",))
        base = time.time_ns() - 30 * 10**9              # robot A's clock; B's is 100 s behind
        behind = 100 * 10**9
        t0 = time.monotonic()
        sent_b = 0
        for k in range(len(ts)):
            if k < 3000:                                 # A: 0-3 s, then silent
                driver.pub_js.publish(_js(base + k * 10**6, x[k, 0], v[k]))
            if k >= 1500:                                # B: from 1.5 s on, to the end
                other.pub_js.publish(_js(base - behind + k * 10**6, x[k, 0], v[k]))
                sent_b += k < 3000
            L.pace(k, t0, 1000.0)
        last_b = base - behind + (len(ts) - 1) * 10**6
        driver.wait_for(lambda: driver.has_estimate_after(last_b - 50 * 10**6), 20,
                        "the estimates of B's last samples", node)
        st = driver.status_where(lambda s: True, 10, "a final status", node)
        node.check_alive()
        COUNTS["live_second_source"] += sent_b
        est = driver.got("estimated_joint_states")
        a_ks = [(ns - base) // 10**6 for ns, _ in est if ns > base - 10**9]
        b_ks = [(ns - base + behind) // 10**6 for ns, _ in est if ns < base - 10**9]
        print(f"two sources: {len(a_ks)} estimates from A, {len(b_ks)} from B (first k "
              f"{min(b_ks, default=None)}); " + ", ".join(
                  f"{k} {v}" for k, v in st["values"].items()
                  if k.startswith(("rejected:", "restarts:", "publishers", "messages lost"))))
        # every message B sent while A owned the topic and that arrived was rejected (a loaded
        # machine drops some of both streams: the counts are the node's own)
        received, accepted = L.count(st, "messages received: joint_states"), L.count(st, "samples accepted")
        second = L.count(st, "rejected: second_source")
        assert second > 0 and received - (accepted + second) in (0, 1), st["values"]
        assert L.count(st, "samples rejected") == second, st["values"]
        assert L.count(st, "restarts: source_change") == 1, st["values"]
        assert L.count(st, "restarts: time_jump") == 0 and L.count(st, "restarts: gap") == 0
        assert st["values"]["publishers: joint_states"] == "2"
        # never mixed: while A owned the topic no estimate came from B's samples, and A's
        # estimates never went back in time
        assert b_ks and min(b_ks) >= 3000, min(b_ks, default=None)
        assert a_ks and max(a_ks) < 3000 and a_ks == sorted(a_ks)
        # and each robot's estimate is its own plant's: the position, which one foreign
        # sample would move by ~2e-2 rad (the gain), within 1e-3 rad (q_dot and I with the
        # bounds of the other live tests need most samples; a loaded machine drops many)
        a_est = {ns: e for ns, e in est if ns > base - 10**9}
        errs = L.errors_after(a_est, base, plant, T_CONVERGED)
        assert len(errs) and errs[:, 0].max() < TOL[0], errs.max(axis=0)
        b_est = {ns + behind: e for ns, e in est if ns < base - 10**9}
        errs = L.errors_after(b_est, base, plant, min(b_ks) / 1000.0 + T_CONVERGED)
        assert len(errs) and errs[:, 0].max() < TOL[0], errs.max(axis=0)
        assert all(np.all(np.isfinite(e)) for _, e in est)
    finally:
        other.close()
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


@pytest.mark.slow
def test_a_second_source_on_the_float_topics_is_rejected(tmp_path):
    """The same on the Float64MultiArray topics (no stamps: the publishers are told apart by
    their sequence numbers): a second robot starting later, whose output is 1 rad off, is
    rejected on both topics and the estimate stays on the first robot's data."""
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "f64", lambda p: p[
        "diagnostics"].update(period=0.2, expected_rate=0.0)))
    driver = Driver(domain)
    other = SecondRobot(domain)
    ts, x, v = L.simulate(2.0)
    try:
        driver.wait_connected(node, [driver.pub_y, driver.pub_u, other.pub_y, other.pub_u])
        t0 = time.monotonic()
        sent_b = 0
        for k in range(len(ts)):
            driver.pub_u.publish(L.array([v[k]]))
            driver.pub_y.publish(L.array([x[k, 0]]))
            if k >= 500:
                other.pub_u.publish(L.array([v[k]]))
                other.pub_y.publish(L.array([x[k, 0] + 1.0]))
                sent_b += 1
            L.pace(k, t0, 500.0)
        time.sleep(1.0)                     # what the node still has queued
        st = driver.status_where(lambda s: True, 10, "a final status", node)
        COUNTS["live_second_source"] += sent_b
        received = L.count(st, "messages received: measured_output")
        second = L.count(st, "rejected: second_source")
        assert second > 0 and L.count(st, "rejected: input_second_source") > 0, st["values"]
        # every measurement is accepted or rejected with a reason (at most one in flight at
        # the status): the reasons of the measurements are those not of the input topic
        reasons = {k[len("rejected: "):]: int(v) for k, v in st["values"].items()
                   if k.startswith("rejected: ") and not k.startswith("rejected: input_")}
        print("float topics, two sources: measurement rejections", reasons)
        assert received - (L.count(st, "samples accepted") + sum(reasons.values())) in (0, 1), \
            st["values"]
        # besides the second source's, a few are timing (these topics carry no stamp: the
        # receipt time is the sample's): a measurement that overtakes the very first input
        # (sent back to back) is missing_input; one delivered late sits off the estimate by
        # its delay times the velocity and the gate calls it an outlier (4 in 3,502 seen,
        # 2026-12-02: the "2 measurements neither accepted nor rejected" of the previous
        # stop were these, which the test did not add up); two taken in one callback batch
        # can be too close
        others = {k: v for k, v in reasons.items() if k != "second_source"}
        assert set(others) <= {"missing_input", "outlier", "stamp_too_close", "repeated_stamp"} \
            and sum(others.values()) <= 10, st["values"]
        assert not any(k.startswith("restarts:") for k in st["values"]), st["values"]
        assert float(st["values"]["output residual"]) < 1e-2, st["values"]   # B's is 1 rad
        assert st["values"]["publishers: measured_output"] == "2"
    finally:
        other.close()
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


@pytest.mark.slow
def test_a_burst_of_reset_calls_is_answered_every_one(tmp_path):
    """1000 ~/reset calls at once from one client: each one answered (was: 17 of 1000, the
    service's default QoS keeps the last 10 requests).  The client keeps all its requests and
    responses too (a client with ROS's default service QoS can itself drop responses it does
    not take in time: 979 of 1000 measured)."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_srvs.srv import Trigger
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "burst", lambda p: p[
        "diagnostics"].update(period=0.2)))
    driver = Driver(domain, outputs=())
    try:
        client = driver.node.create_client(
            Trigger, NODE + "/reset",
            qos_profile=QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE))
        assert client.wait_for_service(timeout_sec=60), node.log()
        futures = [client.call_async(Trigger.Request()) for _ in range(1000)]
        driver.wait_for(lambda: all(f.done() for f in futures), 120,
                        f"the answers ({sum(f.done() for f in futures)} so far)", node)
        assert all(f.result().success for f in futures)
        COUNTS["live_service_burst"] += len(futures)
        st = driver.status_where(lambda s: L.count(s, "restarts: service") == 1000, 20,
                                 "1000 service restarts counted", node)
        assert st is not None
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


@pytest.mark.slow
def test_every_lifecycle_transition_from_every_state(tmp_path):
    """The managed node, through ~/change_state by id: from unconfigured, inactive, active and
    finalized, every transition id (and ids no state has): a valid one moves it, any other is
    refused (success false) with a log line and the node lives on.  Was: 'activate' while
    unconfigured raised RCLError out of the service (ros2/rclpy#1209) and ended the node.
    Configure after cleanup builds the observer again."""
    from lifecycle_msgs.msg import State, Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "lifecycle", lambda p: p[
        "diagnostics"].update(period=0.2)), module="fto_ros.nodes.managed_node")
    driver = Driver(domain, outputs=())
    T = Transition
    valid = {State.PRIMARY_STATE_UNCONFIGURED: {T.TRANSITION_CONFIGURE: State.PRIMARY_STATE_INACTIVE,
                                                T.TRANSITION_UNCONFIGURED_SHUTDOWN: State.PRIMARY_STATE_FINALIZED},
             State.PRIMARY_STATE_INACTIVE: {T.TRANSITION_CLEANUP: State.PRIMARY_STATE_UNCONFIGURED,
                                            T.TRANSITION_ACTIVATE: State.PRIMARY_STATE_ACTIVE,
                                            T.TRANSITION_INACTIVE_SHUTDOWN: State.PRIMARY_STATE_FINALIZED},
             State.PRIMARY_STATE_ACTIVE: {T.TRANSITION_DEACTIVATE: State.PRIMARY_STATE_INACTIVE,
                                          T.TRANSITION_ACTIVE_SHUTDOWN: State.PRIMARY_STATE_FINALIZED},
             State.PRIMARY_STATE_FINALIZED: {}}
    ids = list(range(0, 9)) + [99, 255]

    def change(tid):
        req = ChangeState.Request()
        req.transition = Transition(id=tid)
        return driver.call(ChangeState, NODE + "/change_state", req).success

    def state():
        return driver.call(GetState, NODE + "/get_state", GetState.Request()).current_state.id

    def reach(target):          # the shortest valid path (finalized is reached last)
        path = {State.PRIMARY_STATE_UNCONFIGURED: {State.PRIMARY_STATE_INACTIVE: [1], State.PRIMARY_STATE_ACTIVE: [1, 3]},
                State.PRIMARY_STATE_INACTIVE: {State.PRIMARY_STATE_UNCONFIGURED: [2], State.PRIMARY_STATE_ACTIVE: [3]},
                State.PRIMARY_STATE_ACTIVE: {State.PRIMARY_STATE_INACTIVE: [4], State.PRIMARY_STATE_UNCONFIGURED: [4, 2]}}
        for tid in path.get(state(), {}).get(target, []):
            assert change(tid), tid
        assert state() == target
    try:
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/transition_event") > 0, 60,
                        "the managed node", node)
        refused = 0
        for start in (State.PRIMARY_STATE_UNCONFIGURED, State.PRIMARY_STATE_INACTIVE,
                      State.PRIMARY_STATE_ACTIVE):
            for tid in ids:
                goal = valid[start].get(tid)
                if goal == State.PRIMARY_STATE_FINALIZED:
                    continue                     # shutdown: at the end
                reach(start)
                ok = change(tid)
                node.check_alive()
                assert ok == (goal is not None), (start, tid)
                assert state() == (goal if goal is not None else start), (start, tid)
                refused += goal is None
                COUNTS["live_lifecycle"] += 1
        reach(State.PRIMARY_STATE_ACTIVE)
        assert change(T.TRANSITION_ACTIVE_SHUTDOWN) and state() == State.PRIMARY_STATE_FINALIZED
        for tid in ids:                          # finalized: nothing is a transition
            assert not change(tid) and state() == State.PRIMARY_STATE_FINALIZED
            refused += 1
            COUNTS["live_lifecycle"] += 1
        node.check_alive()
        log = node.log()
        assert log.count("lifecycle: transition id") == refused, log
        assert "Traceback" not in log and "RCLError" not in log, log
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


#: run-time values that cannot build the DC motor's single_delay observer, or are refused by
#: its schema (nan, inf and beyond the ranges)
EXTREMES = [("single_delay.tau", v) for v in (1e6, 1e-300, 1e300, float("nan"), float("inf"), -1.0, 0.0)] \
    + [("single_delay.k", v) for v in (1e308, 1e-300, float("nan"), float("-inf"), 0.0, -5.0)] \
    + [("time.max_gap", v) for v in (float("nan"), float("inf"), 0.0, 1e300)] \
    + [("limits.estimate", v) for v in (float("nan"), 0.0)] \
    + [("outlier.window", 2 ** 62), ("single_delay.tau", 9223372036854775807)]


@pytest.mark.slow
def test_runtime_parameter_extremes_are_refused_and_the_observer_runs_on(tmp_path):
    """Was: single_delay.tau 1e6 (SVD did not converge) or k 1e308 raised LinAlgError out of the
    parameter callback and ended the node.  Each extreme through the SetParameters service is
    refused with a reason, the old observer (tau 0.1) runs on and still converges."""
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, ROOT / "config" / "dc_motor_plant.yaml",
                       "--params-file", str(ROOT / "config" / "dc_motor_single_delay.yaml"),
                       "-p", "diagnostics.period:=0.2", "-p", "diagnostics.expected_rate:=0.0")
    driver = Driver(domain)
    try:
        driver.wait_connected(node, [driver.pub_y, driver.pub_u])
        for name, value in EXTREMES:
            res = driver.set_parameter(name, value)
            node.check_alive()
            assert not res.successful and res.reason, (name, value, res)
            COUNTS["live_param_extreme"] += 1
        plant = L.simulate(1.0)
        L.feed(driver, plant, 1000)
        st = driver.status_where(lambda s: L.count(s, "samples accepted") > 300, 20,
                                 "samples after the refusals", node)
        assert st["values"]["tau (guaranteed convergence time, s)"] == "0.1", st["values"]
        assert not any(k.startswith("restarts:") for k in st["values"]), st["values"]
        assert "Traceback" not in node.log()
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


@pytest.mark.slow
def test_messages_the_middleware_drops_are_counted(tmp_path):
    """Was: of 5,000 samples at 5 kHz a few hundred processed, none counted as lost.  The node
    counts the owner's sequence numbers it never saw: received + lost = sent, shown in
    /diagnostics (messages lost next to the rates; the middleware's own message-lost event
    beside it, which counts transport losses only)."""
    def edit(p):
        p["source"] = "joint_states"
        p["joint_states"].update(input_joints=["joint1"], input_field="effort")
        p["diagnostics"].update(period=0.2, expected_rate=0.0)
        p["qos"] = {"depth": 10}
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "lost", edit))
    driver = Driver(domain, outputs=())
    ts, x, v = L.simulate(5.0)
    try:
        driver.wait_connected(node, [driver.pub_js], outputs=())
        base = time.time_ns() - 30 * 10**9
        sent = 0

        def send(k0, n, rate):
            nonlocal sent
            t0 = time.monotonic()
            for j, k in enumerate(range(k0, k0 + n)):
                driver.pub_js.publish(_js(base + k * 10**6, x[k % len(ts), 0], v[k % len(ts)]))
                sent += 1
                L.pace(j, t0, rate)
        send(0, 20, 100.0)                 # slowly: the first one arrives
        send(20, 5000, 5000.0)             # faster than the node
        time.sleep(0.5)
        send(5020, 20, 100.0)              # slowly again: the last one arrives
        st = driver.status_where(
            lambda s: L.count(s, "messages received: joint_states")
            + L.count(s, "messages lost: joint_states") >= sent - 20, 20, "the last messages", node)
        received = L.count(st, "messages received: joint_states")
        lost = L.count(st, "messages lost: joint_states")
        event = L.count(st, "messages lost (middleware event): joint_states")
        print(f"lost messages: sent {sent}, received {received}, lost {lost} (event: {event})")
        COUNTS["live_lost"] += sent
        assert sent - 20 <= received + lost <= sent, (sent, received, lost)
        assert L.count(st, "samples accepted") + L.count(st, "samples rejected") >= received - 1
        assert "publishers: joint_states" in st["values"]
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()
