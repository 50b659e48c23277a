"""Fault injection against the live node over DDS: a 1 kHz JointState stream with 1 % junk
of every kind a driver or a network can send (NaN and absurd positions, a missing joint, a
joint named twice, arrays of the wrong length, stamps 1 s back, negative, far in the future),
then a stalled publisher, then the stream again after the pause; and the per-joint node with
junk in one joint at a time and junk messages.  (The live families of issue 19: a second
publisher, service bursts, lifecycle transitions, parameter extremes, lost messages:
test_faults_live_families.py.)

What must hold: the node survives, publishes nothing non-finite, accounts for every
message it received (accepted + rejected, one may still be held at a time jump), reports
the stall on /diagnostics (WARN: no measurement accepted) and, once the stream is clean
again, its estimate converges and its level is back to OK.  ROS traffic stays on this
machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a domain id of the test's own)."""
from __future__ import annotations

import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from sensor_msgs.msg import JointState  # noqa: E402

import domains  # noqa: E402
import live_node as L  # noqa: E402
from faultkit import COUNTS  # noqa: E402
from live_node import T_CONVERGED, TOL, Driver, NodeProcess  # noqa: E402

#: live DDS nodes: scripts/run-tests runs these after the rest, one at a time
pytestmark = pytest.mark.live

JUNK_RATE = 0.01

@pytest.mark.slow
def test_node_survives_junk_and_a_stall_and_recovers(tmp_path):
    def edit(p):
        p["source"] = "joint_states"
        p["joint_states"].update(input_joints=["joint1"], input_field="effort")
        p["diagnostics"].update(period=0.2, window=1.0, stale_after=1.0, expected_rate=0.0)
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "faults", edit))
    driver = Driver(domain)
    rng = np.random.default_rng(5)
    ts, x, v = plant = L.simulate(5.0)
    try:
        driver.wait_connected(node, [driver.pub_js], outputs=("estimated_joint_states",))
        base_ns = time.time_ns() - 30 * 10**9          # stamps in the past: never 'future'
        pause_to = 2000                                 # samples 0-1999, a stall, 2000-4999
        stall_s = 2.5
        junk_until = len(ts) - 1500                     # the last 1.5 s are clean
        junk_sent: dict[str, int] = {}
        t0 = time.monotonic()
        sent = 0
        for k in range(len(ts)):
            if k == pause_to:
                with driver.lock:
                    before = len(driver.statuses)
                time.sleep(stall_s)                     # the publisher stalls
                with driver.lock:
                    during = driver.statuses[before:]
                stalled = [s for s in during if "no measurement accepted" in s["message"]]
                assert stalled and stalled[-1]["level"] == 1, [s["message"] for s in during]
                t0 = time.monotonic() - k / 1000.0
            ns = base_ns + k * 10**6 + (int(stall_s * 1e9) if k >= pause_to else 0)
            msg = JointState(name=["joint1"])
            msg.header.stamp = L.stamp(ns)
            msg.position, msg.velocity, msg.effort = [x[k, 0]], [0.0], [v[k]]
            driver.pub_js.publish(msg)
            sent += 1
            if k < junk_until and rng.random() < JUNK_RATE:
                kind, junk = _junk(ns, x[k, 0], v[k], rng)
                driver.pub_js.publish(junk)
                junk_sent[kind] = junk_sent.get(kind, 0) + 1
                COUNTS[f"live_junk_{kind}"] += 1
                sent += 1
            L.pace(k, t0, 1000.0)
        last_ns = base_ns + (len(ts) - 1) * 10**6 + int(stall_s * 1e9)
        driver.wait_for(lambda: driver.has_estimate_after(last_ns - 50 * 10**6), 20,
                        "the estimates of the last samples", node)
        st = driver.status_where(lambda s: True, 10, "a final status", node)
        node.check_alive()
        values = st["values"]
        received = L.count(st, "messages received: joint_states")
        accepted, rejected = L.count(st, "samples accepted"), L.count(st, "samples rejected")
        print(f"live faults: sent {sent} ({sum(junk_sent.values())} junk: {junk_sent}), received "
              f"{received}, accepted {accepted}, rejected {rejected}; "
              + ", ".join(f"{k} {v}" for k, v in values.items() if k.startswith(("rejected:", "restarts:"))))
        assert sum(junk_sent.values()) >= 20
        assert 0 <= received - (accepted + rejected) <= 1           # every message accounted for
        assert rejected >= 0.5 * sum(junk_sent.values())            # (best effort may drop some)
        assert L.count(st, "restarts: gap") == 1                       # the stall, once
        assert L.count(st, "restarts: time_jump") == 0                 # junk stamps never restart
        assert st["level"] == 0, st["message"]                        # clean again: OK
        est = dict(driver.got("estimated_joint_states"))
        assert all(np.all(np.isfinite(e)) for e in est.values())
        # after the stall the estimate converges again on the clean stream
        resumed = {ns - int(stall_s * 1e9): e for ns, e in est.items()
                   if ns >= base_ns + pause_to * 10**6 + int(stall_s * 1e9)}
        errs = L.errors_after(resumed, base_ns, plant, ts[pause_to] + T_CONVERGED)
        assert len(errs) > 0.2 * (len(ts) - pause_to - 500), len(errs)
        assert np.all(errs.max(axis=0) < TOL), errs.max(axis=0)
    finally:
        driver.close()
        assert node.stop() == 0, node.log()


def _junk(ns: int, q: float, v: float, rng) -> tuple[str, JointState]:
    m = JointState(name=["joint1"])
    m.header.stamp = L.stamp(ns + 500_000)
    m.position, m.velocity, m.effort = [q], [0.0], [v]
    kind = ["nan", "absurd", "missing_joint", "long_array", "back_1s", "negative", "future",
            "nan_effort", "duplicate_name", "short_effort"][rng.integers(10)]
    if kind == "nan":
        m.position = [float("nan")]
    elif kind == "absurd":
        m.position = [1e300]
    elif kind == "missing_joint":
        m.name = ["joint2"]
    elif kind == "long_array":
        m.position = [q, q]
    elif kind == "back_1s":
        m.header.stamp = L.stamp(ns - 10**9)
    elif kind == "negative":
        m.header.stamp.sec = -5
    elif kind == "future":
        m.header.stamp = L.stamp(ns + 10**14)
    elif kind == "duplicate_name":          # a second joint1 (another robot's) in the message
        m.name, m.position, m.velocity, m.effort = ["joint1", "joint1"], [q, q + 1.0], [0.0, 0.0], [v, v]
    elif kind == "short_effort":            # the input field shorter than the names
        m.effort = []
    else:
        m.effort = [float("nan")]
    return kind, m


# ------------------------------------------------------------ issue 20: the per-joint node
#: junk of one joint inside a message that carries the others clean
JOINT_JUNK = ("nan", "absurd", "missing_joint", "duplicate_joint", "nan_effort")
#: junk of a whole message (an extra one): refused for every joint alike (short_effort: the
#: input field shorter than the names, so no joint's input is known)
MESSAGE_JUNK = ("back_1s", "negative", "future", "short_effort")


def _joint_junk(m: JointState, joint: str, kind: str) -> None:
    i = m.name.index(joint)
    if kind == "nan":
        m.position[i] = float("nan")
    elif kind == "absurd":
        m.position[i] = 1e300
    elif kind == "missing_joint":
        keep = [k for k in range(len(m.name)) if k != i]
        m.name = [m.name[k] for k in keep]
        m.position, m.velocity, m.effort = ([list(f)[k] for k in keep]
                                            for f in (m.position, m.velocity, m.effort))
    elif kind == "duplicate_joint":          # the joint twice (another robot's entry)
        m.name = list(m.name) + [joint]
        m.position, m.velocity, m.effort = (list(f) + [list(f)[i]]
                                            for f in (m.position, m.velocity, m.effort))
    else:
        m.effort[i] = float("nan")


@pytest.mark.slow
def test_joints_node_keeps_each_joints_junk_in_that_joint(tmp_path):
    """Per-joint mode, 3 joints at 1 kHz with 2 % per-joint junk on j2 and j3 and 0.5 % junk
    messages: j1 (never junked) loses only the whole-message junk and its estimate converges;
    every joint accounts for every message; the node ends OK."""
    from live_joints import JOINTS, JointDriver, connect, joint_params, start
    files = joint_params(tmp_path, "dc_motor_luenberger", {
        "plant": {"constants": ["b0=40", "b1=15", "a1=35", "a2=1", "a3=36.4", "a4=200"]},
        "diagnostics": {"period": 0.2, "window": 1.0, "stale_after": 1.0, "expected_rate": 0.0}})
    domain = domains.take()
    node = start(tmp_path, files, domain)
    driver = JointDriver(domain)
    rng = np.random.default_rng(20)
    ts, x, v = plant = L.simulate(3.0)
    junk_until = len(ts) - 1500
    joint_junk = {j: {} for j in JOINTS}
    message_junk: dict[str, int] = {}
    try:
        connect(driver, node)
        base_ns = time.time_ns() - 30 * 10**9
        t0 = time.monotonic()
        for k in range(len(ts)):
            ns = base_ns + k * 10**6
            m = JointState(name=list(JOINTS))
            m.header.stamp = L.stamp(ns)
            m.position, m.velocity, m.effort = [x[k, 0]] * 3, [0.0] * 3, [v[k]] * 3
            if k < junk_until and rng.random() < 0.02:
                joint, kind = JOINTS[1 + rng.integers(2)], JOINT_JUNK[rng.integers(len(JOINT_JUNK))]
                _joint_junk(m, joint, kind)
                joint_junk[joint][kind] = joint_junk[joint].get(kind, 0) + 1
                COUNTS[f"live_joint_junk_{kind}"] += 1
            driver.pub_js.publish(m)
            if k < junk_until and rng.random() < 0.005:
                kind = MESSAGE_JUNK[rng.integers(len(MESSAGE_JUNK))]
                bad = JointState(name=list(JOINTS))
                bad.position, bad.velocity, bad.effort = [x[k, 0]] * 3, [0.0] * 3, [v[k]] * 3
                bad.header.stamp = L.stamp({"back_1s": ns - 10**9, "future": ns + 10**14}.get(kind, ns))
                if kind == "negative":
                    bad.header.stamp.sec = -5
                elif kind == "short_effort":
                    bad.effort = bad.effort[:-1]
                driver.pub_js.publish(bad)
                message_junk[kind] = message_junk.get(kind, 0) + 1
                COUNTS[f"live_joint_message_junk_{kind}"] += 1
            L.pace(k, t0, 1000.0)
        last_ns = base_ns + (len(ts) - 1) * 10**6
        driver.wait_for(lambda: any(o[0] >= last_ns - 50 * 10**6 for o in driver.got("joint_out")),
                        20, "the estimates of the last samples", node)
        seen = len(driver.got("diag_all"))
        first_after = driver.wait_for(lambda: next(iter(driver.got("diag_all")[seen:]), None), 10,
                                      "a status after the last estimates", node)
        st = driver.wait_quiet(node, "messages received: joint_states")
        received = L.count(st, "messages received: joint_states")
        status = {j: driver.joint_status(f"observer_node: joint {j}") for j in JOINTS}
        node_status = driver.joint_status("observer_node: observer")
        node.check_alive()
        print(f"per-joint live faults: junk per joint {joint_junk}, junk messages {message_junk}, "
              f"received {received}; rejected per joint "
              + ", ".join(f"{j} {status[j]['samples rejected']}" for j in JOINTS))
        assert sum(sum(d.values()) for d in joint_junk.values()) >= 20 and sum(message_junk.values()) >= 3
        for j in JOINTS:
            acc, rej = int(status[j]["samples accepted"]), int(status[j]["samples rejected"])
            assert 0 <= received - (acc + rej) <= 1, (j, received, acc, rej)   # every message
            assert int(status[j].get("restarts: time_jump", "0")) == 0        # junk never restarts
        # j1 lost only what every joint lost (whole messages): its reasons are the message
        # reasons, as many as j2 and j3 have of each
        j1 = {k: v for k, v in status["j1"].items() if k.startswith("rejected: ")}
        for key, count in j1.items():
            for j in JOINTS[1:]:
                assert int(status[j].get(key, "0")) >= int(count), (key, j)
        assert not any(key.startswith(("rejected: measurement", "rejected: joint_states_joint",
                                       "rejected: joint_states_dup")) for key in j1), j1
        for j in JOINTS[1:]:
            assert int(status[j]["samples rejected"]) > int(status["j1"]["samples rejected"]), j
        out = driver.got("joint_out")
        assert all(np.all(np.isfinite(o[2])) and np.all(np.isfinite(o[3])) for o in out)
        est = {o[0]: np.array([o[2][o[1].index("j1")], o[3][o[1].index("j1")], x[0, 2]])
               for o in out if "j1" in o[1]}
        errs = L.errors_after(est, base_ns, plant, T_CONVERGED)[:, :2]
        assert len(errs) > 0.2 * (len(ts) - 500), len(errs)
        assert np.all(errs.max(axis=0) < TOL[:2]), errs.max(axis=0)
        # the first statuses after the last estimates: the last 1.5 s were clean, every joint OK
        assert first_after["observer_node: observer"]["level"] == "0", first_after
        for j in JOINTS:
            assert first_after[f"observer_node: joint {j}"]["level"] == "0", (j, first_after)
        assert node_status["joints"] == "j1, j2, j3"
    finally:
        driver.close()
        assert node.stop() == 0, node.log()
