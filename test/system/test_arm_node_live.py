"""The arm's node over DDS: ``fto-external-torque`` (the observer node with external_torque)
on config/arm7_external_torque.yaml, fed the JointStates of bags/arm7_contact_link6 (and the
bag's /clock: the node runs on sim time, as under fto-play, so the stamps are the bag's
own). What must hold:

- every ~/external_torque it publishes equals, sample by sample and bit for bit, the
  replay of the same bag (fto-replay's unknown_input_estimate_stamped, same stamps);
- the 45 N push on link 6 latches a collision, published on ~/collision at the stamp at
  which the replay's collision flag rises; ~/reset_collision clears it (its answer says how
  many joints were latched; the joints' /diagnostics leave the state collision);
- a payload set at run time (payload.mass, payload.frame) is taken without a restart, and
  the estimates that follow equal an offline runner's that got the same payload at the
  same sample (and differ from one without it: the payload is used).

The node runs as a user starts it (test/support/live_node.py's NodeProcess: its own
session, killed with its group; a domain id of its own from test/support/domains.py)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

import domains  # noqa: E402
import live_node as L  # noqa: E402
from fto_ros.bag import BagReader  # noqa: E402
from fto_ros.replay.replay import replay  # noqa: E402
from fto_ros.runner import Runner  # noqa: E402
from fto_ros.runner.messages import joint_state_sample  # noqa: E402
from fto_ros.runner.params_file import load_params_files  # noqa: E402

pytestmark = pytest.mark.live

ROOT = L.ROOT
BAG = ROOT / "bags" / "arm7_contact_link6"
CONFIG = ROOT / "config" / "arm7_external_torque.yaml"
NAME = "external_torque_node"
NODE = "/" + NAME
TOPIC = "/arm/joint_states"
#: messages published after the bag with the arm at rest, the payload set before them
TAIL = 300
PAYLOAD = {"payload.frame": "link_7", "payload.mass": 2.0}


def _ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


def bag_messages():
    """(stamp ns, names, position, velocity, effort) of the bag's JointStates."""
    with BagReader(BAG) as b:
        return [(_ns(m.header.stamp), list(m.name), list(m.position), list(m.velocity),
                 list(m.effort)) for _, _, m in b.messages([TOPIC])]


def tail(last):
    """TAIL messages after the bag, 1 ms apart, the last position and effort held."""
    ns, names, pos, vel, eff = last
    return [(ns + (k + 1) * 10**6, names, pos, [0.0] * len(pos), eff) for k in range(TAIL)]


def replayed(tmp: Path):
    """stamp ns -> tau_ext of fto-replay on the bag; the stamps at which a joint's
    collision flag rose."""
    out = tmp / "replay"
    replay(BAG, [CONFIG], out, node_name=NAME, progress=False, plot=False)
    ui, conv = {}, []
    with BagReader(out) as b:
        for _, _, m in b.messages([f"{NODE}/unknown_input_estimate_stamped"]):
            ui[_ns(m.header.stamp)] = np.array(m.position)
        for _, _, m in b.messages([f"{NODE}/convergence"]):
            conv.append(np.array(m.data))
    return ui, conv


def _msg(sample) -> JointState:
    ns, names, pos, vel, eff = sample
    m = JointState(name=names, position=pos, velocity=vel, effort=eff)
    m.header.stamp = L.stamp(ns)
    return m


def offline(samples, payload_at: int | None):
    """stamp ns -> tau_ext of the node's per-message path (runner/messages.py with the
    family's intake) on ``samples``, the payload set before sample ``payload_at``."""
    run = Runner(load_params_files([CONFIG], NAME))
    out = {}
    for k, s in enumerate(samples):
        if k == payload_at:
            run.observer.set_payload(PAYLOAD)
        t, y, u = joint_state_sample(_msg(s), run.settings, None, run.intake)
        run.set_input(t, u)
        o = run.process(t, y)
        if not isinstance(o, str):
            out[s[0]] = np.array(o.unknown_input)
    return out


class ArmDriver(L.Driver):
    def __init__(self, domain):
        super().__init__(domain, outputs=())
        rel = QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE)
        for key in ("torque", "collision"):
            self.received[key] = []
            self._collect(JointState, key, f"{NODE}/{'external_torque' if key == 'torque' else key}",
                          rel, lambda m: (_ns(m.header.stamp), list(m.name), np.array(m.effort)))
        self.received["diag"] = []
        from diagnostic_msgs.msg import DiagnosticArray
        self._collect(DiagnosticArray, "diag", "/diagnostics", 100,
                      lambda m: {st.name: dict({kv.key: kv.value for kv in st.values},
                                               message=st.message) for st in m.status})
        pub_qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_arm = self.node.create_publisher(JointState, TOPIC, pub_qos)

    def send(self, samples, rate=400.0):
        t0 = time.monotonic()
        for k, s in enumerate(samples):
            clock = Clock()
            clock.clock = L.stamp(s[0])
            self.pub_clock.publish(clock)
            self.pub_arm.publish(_msg(s))
            L.pace(k, t0, rate)

    def set_parameters(self, values: dict):
        """One atomic SetParameters call to the arm node; its result."""
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.parameter import Parameter
        req = SetParametersAtomically.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        return self.call(SetParametersAtomically, f"{NODE}/set_parameters_atomically",
                         req).result


def test_the_arm_node_equals_the_replay_and_takes_reset_and_payload(tmp_path):
    msgs = bag_messages()
    want, conv = replayed(tmp_path)
    domain = domains.take()
    exe = Path(sys.executable).parent / "fto-external-torque"
    node = L.NodeProcess(tmp_path, domain, None, cmd=[
        str(exe), "--ros-args", "--params-file", str(CONFIG), "-p", "use_sim_time:=true",
        "-p", "qos.depth:=1000", "-p", "diagnostics.period:=0.2"])
    driver = ArmDriver(domain)
    try:
        driver.wait_for(lambda: driver.pub_arm.get_subscription_count() > 0, 120,
                        "the node's subscription", node)
        driver.wait_for(lambda: driver.node.count_publishers(f"{NODE}/external_torque") > 0, 30,
                        "the node's ~/external_torque", node)
        time.sleep(1.0)                  # the node sees our subscriptions (its refresh)
        driver.send(msgs)
        last = msgs[-1][0]
        driver.wait_for(lambda: any(o[0] >= last for o in driver.got("torque")), 60,
                        "the estimate of the bag's last message", node)
        # the node took every message (its input is best effort: on a loaded machine a
        # message may be lost, and the estimates then differ from the replay's: retry)
        start = len(driver.got("diag"))
        seen = driver.wait_for(lambda: next((d[f"{NAME}: observer"] for d in driver.got("diag")[start:]
                                             if f"{NAME}: observer" in d), None), 10,
                               "the node's status", node)
        assert seen["messages received: joint_states"] == str(len(msgs)), seen
        got = {ns: eff for ns, _, eff in driver.got("torque")}
        # every published tau_ext is the replay's at that stamp, bit for bit (the driver
        # may miss some of the node's messages: its outputs keep the last 10)
        assert len(got) > 0.5 * len(msgs), len(got)
        for ns, eff in got.items():
            assert np.array_equal(eff, want[ns]), (ns, eff, want[ns])
        assert all(np.isfinite(e).all() for e in got.values())
        # the collision: published where the replay's flag rose, then cleared on request
        fields = Runner(load_params_files([CONFIG], NAME)).convergence_fields
        cols = [i for i, f in enumerate(fields) if f.startswith("collision.")]
        stamps = sorted(want)
        flags = np.array([c[cols] for c in conv])
        rose = [stamps[k] for k in range(1, len(flags)) if np.any(flags[k] > flags[k - 1])]
        assert rose and all(5.9e9 < s < 6.2e9 for s in rose), rose
        col = driver.wait_for(lambda: driver.got("collision"), 10, "~/collision", node)
        assert [c[0] for c in col] == rose, (col, rose)
        res = driver.call(Trigger, f"{NODE}/reset_collision", Trigger.Request())
        latched = int(np.count_nonzero(flags[-1]))
        assert res.success and f"({latched} joint(s) were latched)" in res.message, res.message
        joints = [f"{NAME}: joint_a{i}" for i in range(1, 8)]
        start = len(driver.got("diag"))
        driver.wait_for(lambda: any(all(j in d and d[j]["message"] == "armed" for j in joints)
                                    for d in driver.got("diag")[start:]), 20,
                        "every joint armed after the reset", node)
        # the payload at run time: taken, no restart, the tail as offline with it
        r = driver.set_parameters(PAYLOAD)
        assert r.successful, r.reason
        more = tail(msgs[-1])
        driver.send(more)
        driver.wait_for(lambda: any(o[0] >= more[-1][0] for o in driver.got("torque")), 30,
                        "the tail's last estimate", node)
        live = {ns: eff for ns, _, eff in driver.got("torque") if ns > last}
        with_payload = offline(msgs + more, len(msgs))
        without = offline(msgs + more, None)
        assert len(live) > 0.9 * TAIL
        for ns, eff in live.items():
            assert np.array_equal(eff, with_payload[ns]), ns
        end = more[-1][0]
        assert np.abs(with_payload[end] - without[end]).max() > 1.0     # 2 kg at the tool
        print(f"{len(got)} tau_ext messages equal the replay's; collision at {rose}; "
              f"reset: {res.message}; payload tail {len(live)} equal offline")
    finally:
        driver.close()
        assert node.stop() == 0, node.log()
