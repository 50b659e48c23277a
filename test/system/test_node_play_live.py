"""fto-play --clock of committed bags into the live observer node on sim time: the estimates
match the bag's ground truth at its own sample times; hosm publishes the load torque and its
structure on /diagnostics.  Helpers: test/support/live_node.py.

The fto-play test replays bags/dc_motor_nominal (square-wave input): samples dropped by a
loaded machine hurt more there than in test_node_live.py's streams (offline, the replay
error stays below (2e-6, 5e-5, 5e-4) from 0.5 s on), so it checks the median against the
same bound (TOL, derived in test_node_live.py's docstring)."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rclpy")
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402

import domains  # noqa: E402
import live_node as L  # noqa: E402
import processes  # noqa: E402
from live_node import NODE, ROOT, TOL, Driver, NodeProcess  # noqa: E402

#: live DDS nodes: scripts/run-tests runs these after the rest, one at a time
pytestmark = pytest.mark.live


def _play(bag: Path, truth: dict, domain: int, tmp: Path, node: NodeProcess, driver: Driver):
    """fto-play --clock the bag's input and measured output into the node on sim time and wait
    for its last estimates.  Returns (the last status, the estimates {stamp ns: (q, q_dot, I)},
    |estimate - truth| at the bag's sample times from 0.5 s on)."""
    player = processes.run(
        [sys.executable, "-m", "fto_ros.nodes.player", str(bag), "--clock", "--quiet",
         "--wait-for-subscribers", "20", "--delay", "0.5",
         "--topics", "/dc_motor/input", "/dc_motor/measured_output"],
        cwd=ROOT, env=L.ros_env(domain, tmp), capture_output=True, timeout=60)
    assert player.returncode == 0, player.stderr
    last = max(truth)
    driver.wait_for(lambda: driver.has_estimate_after(last - 50 * 10**6), 15,
                    "the estimates of the last samples", node)
    st = driver.status_where(lambda s: True, 10, "a status", node)
    est = dict(driver.got("estimated_joint_states"))
    errs = np.array([np.abs(x - truth[ns]) for ns, x in est.items() if ns >= 0.5e9 and ns in truth])
    assert len(errs) > 0.5 * len(truth), f"only {len(errs)} estimates at the bag's sample times"
    return st, est, errs


@pytest.mark.slow
def test_player_drives_node_with_sim_time(tmp_path):
    """fto-play --clock of a simulated bag into a node with use_sim_time: estimates match the
    bag's ground truth at the bag's own sample times."""
    bag = ROOT / "bags" / "dc_motor_nominal"
    if not (bag / "metadata.yaml").is_file():
        pytest.skip(f"{bag} not generated")
    from fto_ros.bag import read_messages
    truth = {t: np.array(m.data) for _, t, m in read_messages(bag, ["/dc_motor/true_state"])}

    def edit(p):
        p["diagnostics"].update(period=0.2, expected_rate=0.0)
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "play", edit), "-p", "use_sim_time:=true")
    driver = Driver(domain, outputs=("estimated_joint_states",))   # light: 3 processes, 2 cores
    try:
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/estimated_joint_states") > 0, 30,
                        "the node's publishers", node)
        driver.wait_for(driver.last_status, 30, "the first /diagnostics", node)
        st, est, errs = _play(bag, truth, domain, tmp_path, node, driver)
        med = np.median(errs, axis=0)
        print(f"fto-play: {len(errs)} estimates after 0.5 s, median |error| {med}, max {errs.max(axis=0)}; "
              f"accepted {st['values']['samples accepted']}, rejected {st['values']['samples rejected']}")
        assert np.all(med < TOL), f"median |error| (q, q_dot, I) after 0.5 s = {med}"
        assert L.count(st, "samples accepted") > 0.9 * len(truth), st
        assert "rejected: waiting_for_clock" not in st["values"], st   # the bag starts at t = 0
        assert all(np.all(np.isfinite(x)) for _, x in est.items())
    finally:
        driver.close()
        assert node.stop() == 0, node.log()


@pytest.mark.slow
def test_hosm_publishes_the_load_torque_live(tmp_path):
    """fto-play --clock of bags/dc_motor_load into a node running config/dc_motor_hosm.yaml on
    sim time: the state estimates match the truth at the bag's sample times, the load torque
    estimate is published on ~/unknown_input_estimate and ends at the true torque, and
    /diagnostics carries the hosm structure (relative degree, invariant zeros, M)."""
    bag = ROOT / "bags" / "dc_motor_load"
    from fto_ros.bag import read_messages
    truth = {t: np.array(m.data) for _, t, m in read_messages(bag, ["/dc_motor/true_state"])}
    torque = {t: m.data[0] for _, t, m in read_messages(bag, ["/dc_motor/true_unknown_input"])}
    doc = yaml.safe_load((ROOT / "test" / "data" / "dc_motor_explicit" / "dc_motor_hosm.yaml").read_text())
    doc["observer_node"]["ros__parameters"]["diagnostics"].update(period=0.2, expected_rate=0.0)
    params = tmp_path / "hosm.yaml"
    params.write_text(yaml.safe_dump(doc, sort_keys=False))
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, params, "-p", "use_sim_time:=true")
    driver = Driver(domain, outputs=("estimated_joint_states",))
    ui: list = []
    driver.node.create_subscription(
        Float64MultiArray, NODE + "/unknown_input_estimate", lambda m: ui.append(list(m.data)),
        QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
    try:
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/unknown_input_estimate") > 0,
                        30, "the unknown-input publisher", node)
        driver.wait_for(driver.last_status, 30, "the first /diagnostics", node)
        st, _, errs = _play(bag, truth, domain, tmp_path, node, driver)
        # replay of the same bag: 7.4e-7 rad/s, 4.0e-7 A after 0.11 s; live, the node's
        # best-effort subscription drops samples (26-37 % here), and hosm's current estimate
        # over the longer steps measured a median of 1.6e-4 to 3.2e-4 A on an idle machine
        assert np.all(np.median(errs, axis=0) < [1e-6, 1e-4, 1e-3]), np.median(errs, axis=0)
        # published for the samples that arrived (the other live tests' bar: a loaded machine
        # drops 20-30 % of a 1 kHz best-effort stream, measured 3,861 of 5,001 here)
        assert len(ui) > 0.5 * len(truth) and all(len(v) == 1 and math.isfinite(v[0]) for v in ui)
        # the torque moves by at most 1.62 per second: the last estimate is within a few ms of
        # the end (replay: 4.9e-4 max error after 0.11 s)
        assert abs(ui[-1][0] - torque[max(torque)]) < 0.02, (ui[-1], torque[max(torque)])
        v = st["values"]
        assert v["relative degree"] == "2" and "-200" in v["invariant zeros"], v
        assert "M check" in v and "differentiator residual" in v
    finally:
        driver.close()
        assert node.stop() == 0, node.log()
