"""Fault injection against the live node over DDS: a 1 kHz JointState stream with 1 % junk
of every kind a driver or a network can send (NaN and absurd positions, a missing joint,
arrays of the wrong length, stamps 1 s back, negative, far in the future), then a stalled
publisher, then the stream again after the pause.

What must hold: the node survives, publishes nothing non-finite, accounts for every
message it received (accepted + rejected, one may still be held at a time jump), reports
the stall on /diagnostics (WARN: no measurement accepted) and, once the stream is clean
again, its estimate converges and its level is back to OK.  ROS traffic stays on this
machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, a domain id of the test's own)."""
from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
from sensor_msgs.msg import JointState  # noqa: E402

from test_node_live import (T_CONVERGED, TOL, Driver, NodeProcess, _count,  # noqa: E402
                            _domain, _errors_after, _pace, _params_file, _simulate, _stamp)

#: live DDS nodes: scripts/run-tests runs these after the rest, one at a time
pytestmark = pytest.mark.live

JUNK_RATE = 0.01


@pytest.mark.slow
def test_node_survives_junk_and_a_stall_and_recovers(tmp_path):
    def edit(p):
        p["source"] = "joint_states"
        p["joint_states"].update(input_joints=["joint1"], input_field="effort")
        p["diagnostics"].update(period=0.2, window=1.0, stale_after=1.0, expected_rate=0.0)
    domain = _domain(31)
    node = NodeProcess(tmp_path, domain, _params_file(tmp_path, "faults", edit))
    driver = Driver(domain)
    rng = np.random.default_rng(5)
    ts, x, v = plant = _simulate(5.0)
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
            msg.header.stamp = _stamp(ns)
            msg.position, msg.velocity, msg.effort = [x[k, 0]], [0.0], [v[k]]
            driver.pub_js.publish(msg)
            sent += 1
            if k < junk_until and rng.random() < JUNK_RATE:
                kind, junk = _junk(ns, x[k, 0], v[k], rng)
                driver.pub_js.publish(junk)
                junk_sent[kind] = junk_sent.get(kind, 0) + 1
                sent += 1
            _pace(k, t0, 1000.0)
        last_ns = base_ns + (len(ts) - 1) * 10**6 + int(stall_s * 1e9)
        driver.wait_for(lambda: driver.has_estimate_after(last_ns - 50 * 10**6), 20,
                        "the estimates of the last samples", node)
        st = driver.status_where(lambda s: True, 10, "a final status", node)
        node.check_alive()
        values = st["values"]
        received = _count(st, "messages received: joint_states")
        accepted, rejected = _count(st, "samples accepted"), _count(st, "samples rejected")
        print(f"live faults: sent {sent} ({sum(junk_sent.values())} junk: {junk_sent}), received "
              f"{received}, accepted {accepted}, rejected {rejected}; "
              + ", ".join(f"{k} {v}" for k, v in values.items() if k.startswith(("rejected:", "restarts:"))))
        assert sum(junk_sent.values()) >= 20
        assert 0 <= received - (accepted + rejected) <= 1           # every message accounted for
        assert rejected >= 0.5 * sum(junk_sent.values())            # (best effort may drop some)
        assert _count(st, "restarts: gap") == 1                       # the stall, once
        assert _count(st, "restarts: time_jump") == 0                 # junk stamps never restart
        assert st["level"] == 0, st["message"]                        # clean again: OK
        est = dict(driver.got("estimated_joint_states"))
        assert all(np.all(np.isfinite(e)) for e in est.values())
        # after the stall the estimate converges again on the clean stream
        resumed = {ns - int(stall_s * 1e9): e for ns, e in est.items()
                   if ns >= base_ns + pause_to * 10**6 + int(stall_s * 1e9)}
        errs = _errors_after(resumed, base_ns, plant, ts[pause_to] + T_CONVERGED)
        assert len(errs) > 0.2 * (len(ts) - pause_to - 500), len(errs)
        assert np.all(errs.max(axis=0) < TOL), errs.max(axis=0)
    finally:
        driver.close()
        assert node.stop() == 0, node.log()


def _junk(ns: int, q: float, v: float, rng) -> tuple[str, JointState]:
    m = JointState(name=["joint1"])
    m.header.stamp = _stamp(ns + 500_000)
    m.position, m.velocity, m.effort = [q], [0.0], [v]
    kind = ["nan", "absurd", "missing_joint", "long_array", "back_1s", "negative", "future",
            "nan_effort"][rng.integers(8)]
    if kind == "nan":
        m.position = [float("nan")]
    elif kind == "absurd":
        m.position = [1e300]
    elif kind == "missing_joint":
        m.name = ["joint2"]
    elif kind == "long_array":
        m.position = [q, q]
    elif kind == "back_1s":
        m.header.stamp = _stamp(ns - 10**9)
    elif kind == "negative":
        m.header.stamp.sec = -5
    elif kind == "future":
        m.header.stamp = _stamp(ns + 10**14)
    else:
        m.effort = [float("nan")]
    return kind, m
