"""The live node in per-joint mode (``joints``) over DDS: one JointState of three joints in
(any order), one JointState out (``~/estimated_joint_states``), one /diagnostics status per
joint plus the node's, ``~/set_state`` per joint.

What must hold: every published joint value equals, bit for bit, the runner's
``process_joints`` on the same messages (the offline run of the messages the node answered:
a message best effort dropped is dropped for both); one joint's junk (a NaN position, a NaN
effort, the joint missing) leaves the other joints' outputs exactly those of a run without
the junk, is counted in that joint's own status, and drops that joint only from the output
message.  The node runs as a subprocess exactly as a user starts it (test/support/live_node.py,
live_joints.py)."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from fto_ros.runner import Runner  # noqa: E402
from fto_ros.runner.intake import JointIntake  # noqa: E402
from fto_ros.runner.messages import stamp_seconds  # noqa: E402
from fto_ros.runner.params_file import load_params_files  # noqa: E402
import domains  # noqa: E402
import live_node as L  # noqa: E402
from live_joints import JOINTS, JointDriver, connect, joint_params, start  # noqa: E402
from live_node import NODE  # noqa: E402

pytestmark = pytest.mark.live


def stream(n: int, base_ns: int, junk=None):
    """n JointStates of the three joints 1 ms apart, names in a rotating order; ``junk`` maps
    k -> a function editing message k."""
    out = []
    for k in range(n):
        t = k * 1e-3
        order = [JOINTS[(k + i) % 3] for i in range(3)]
        m = JointState(name=order)
        m.header.stamp = L.stamp(base_ns + k * 10**6)
        m.position = [0.4 * math.sin(2.0 * t + JOINTS.index(j)) for j in order]
        m.velocity = [0.0] * 3
        m.effort = [2.0 + math.sin(t + JOINTS.index(j)) for j in order]
        if junk and k in junk:
            junk[k](m)
        out.append(m)
    return out


def offline(files, msgs):
    """Per message stamp: the runner's per-joint outputs on ``msgs`` (the node's path)."""
    runner = Runner(load_params_files(files, "observer_node"))
    s = runner.settings
    intake = JointIntake(runner.joints, s["joint_states.output_fields"],
                         s["joint_states.input_fields"], runner.observer.n_inputs)
    out = {}
    for m in msgs:
        y, u, refused = intake.take_message(m)
        st = m.header.stamp
        out[st.sec * 10**9 + st.nanosec] = runner.process_joints(stamp_seconds(st), y, u, refused)
    return runner, out


def _set(field, joint, value):
    def edit(m):
        vals = list(getattr(m, field))
        vals[m.name.index(joint)] = value
        setattr(m, field, vals)
    return edit


def _drop(joint):
    def edit(m):
        i = m.name.index(joint)
        m.name = [n for n in m.name if n != joint]
        m.position = [v for k, v in enumerate(m.position) if k != i]
        m.velocity = [v for k, v in enumerate(m.velocity) if k != i]
        m.effort = [v for k, v in enumerate(m.effort) if k != i]
    return edit


#: message -> (the joint it junks, the edit)
JUNK = {200: ("j2", _set("position", "j2", math.nan)), 300: ("j3", _drop("j3")),
        400: ("j2", _set("effort", "j2", math.nan)), 450: ("j3", _set("position", "j3", 1e300)),
        500: ("j2", _drop("j2"))}


@pytest.mark.parametrize("tuning", ["dc_motor_luenberger", "dc_motor_hosm"])
def test_joint_outputs_equal_the_runner_and_junk_stays_in_its_joint(tmp_path, tuning):
    files = joint_params(tmp_path, tuning)
    domain = domains.take()
    node = start(tmp_path, files, domain)
    driver = JointDriver(domain)
    n = 800
    try:
        pub = driver.pub_js
        connect(driver, node)
        base_ns = time.time_ns() - 10 * 10**9
        msgs = stream(n, base_ns, {k: edit for k, (_, edit) in JUNK.items()})
        t0 = time.monotonic()
        for k, m in enumerate(msgs):
            pub.publish(m)
            L.pace(k, t0, 500.0)
        last = base_ns + (n - 1) * 10**6
        driver.wait_for(lambda: any(o[0] >= last for o in driver.got("joint_out")), 15,
                        "the output of the last message", node)
        status = {j: driver.joint_status(f"observer_node: joint {j}") for j in JOINTS}
        node_status = driver.joint_status("observer_node: observer")
        got = {o[0]: o for o in driver.got("joint_out")}
        # the offline run of the messages the node answered (every one has a clean joint)
        answered = [m for m in msgs if m.header.stamp.sec * 10**9 + m.header.stamp.nanosec in got]
        assert len(answered) > 0.5 * n, len(answered)
        runner, want = offline(files, answered)
        _, clean = offline(files, [m for m in stream(n, base_ns)
                                   if m.header.stamp.sec * 10**9 + m.header.stamp.nanosec in got])
        roles = runner.roles[0]
        first_junk = {j: min([base_ns + k * 10**6 for k, (v, _) in JUNK.items() if v == j],
                             default=math.inf) for j in JOINTS}
        compared = 0
        for ns, (_, names, pos, vel, eff) in got.items():
            outs = want[ns]
            expect = [j for j, o in zip(JOINTS, outs) if not isinstance(o, (str, type(None)))]
            assert names == expect, (ns, names, outs)
            for i, joint in enumerate(names):
                o = outs[JOINTS.index(joint)]
                assert pos[i] == o.estimate[roles.position], (ns, joint)
                assert vel[i] == o.estimate[roles.velocity], (ns, joint)
                if roles.effort[0] == "unknown_input":
                    assert eff[i] == o.unknown_input[0], (ns, joint)
                else:
                    assert len(eff) == 0
                c = clean[ns][JOINTS.index(joint)]
                if ns < first_junk[joint]:   # the other joints' junk changes nothing here
                    assert np.array_equal(o.estimate, c.estimate), (ns, joint)
                    assert np.array_equal(o.convergence, c.convergence), (ns, joint)
                compared += 1
            assert all(np.isfinite(pos)) and all(np.isfinite(vel)) and all(np.isfinite(eff))
        # the junk is dropped from its joint only, and counted in its joint's status only
        for k, (victim, _) in JUNK.items():
            ns = base_ns + k * 10**6
            if ns in got:
                assert victim not in got[ns][1] and len(got[ns][1]) == 2, (k, got[ns][1])
        for joint in JOINTS:
            rejected = int(status[joint]["samples rejected"])
            counted = sum(int(v) for key, v in status[joint].items() if key.startswith("rejected: "))
            assert rejected == counted
            per_joint = runner.rejected_of(JOINTS.index(joint))
            assert rejected == sum(per_joint.values()), (joint, status[joint], per_joint)
            assert int(status[joint]["samples accepted"]) == int(runner._mem.rs[JOINTS.index(joint), 11])
        assert int(status["j1"]["samples rejected"]) == 0
        assert int(status["j2"]["samples rejected"]) >= 1 and int(status["j3"]["samples rejected"]) >= 1
        assert node_status["joints"] == "j1, j2, j3"
        print(f"{tuning}: {len(got)} output messages of {n} sent, {compared} joint values equal "
              f"the runner's; rejected per joint: "
              + ", ".join(f"{j} {status[j]['samples rejected']}" for j in JOINTS))
    finally:
        driver.close()
        assert node.stop() == 0, node.log()


def test_set_state_per_joint(tmp_path):
    files = joint_params(tmp_path, "dc_motor_luenberger")
    domain = domains.take()
    node = start(tmp_path, files, domain)
    driver = JointDriver(domain)
    try:
        connect(driver, node)
        req = SetParameters.Request()
        req.parameters = [Parameter("j2", value=[0.1, 0.0, 0.0]).to_parameter_msg()]
        res = driver.call(SetParameters, NODE + "/set_state", req)
        assert res.results[0].successful, res.results[0].reason
        st = driver.joint_status("observer_node: joint j2")
        assert st.get("restarts: set_state") == "1", st
        assert "restarts: set_state" not in driver.joint_status("observer_node: joint j1")
        for bad in ([Parameter("j9", value=[0.0, 0.0, 0.0])], [Parameter("j1", value=[0.0, 0.0])],
                    [Parameter("j1", value=[0.0, math.nan, 0.0])]):
            req.parameters = [p.to_parameter_msg() for p in bad]
            res = driver.call(SetParameters, NODE + "/set_state", req)
            assert not res.results[0].successful and res.results[0].reason
        assert "restarts: set_state" not in driver.joint_status("observer_node: joint j1")
        node.check_alive()
    finally:
        driver.close()
        assert node.stop() == 0, node.log()
