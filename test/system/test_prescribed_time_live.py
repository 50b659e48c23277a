"""prescribed_time's live node over DDS: window after window without error growth on the
double integrator (JointState source, exact stamps).  The node runs in a session of its own
on a domain of the test's own (test/support/processes.py, domains.py)."""
from __future__ import annotations

import numpy as np
import pytest

import domains
import processes
from fto_ros.models.canonical_form import DOUBLE_INTEGRATOR
from prescribed_time_cases import DI_CONFIG, ROOT, grid, simulate_zoh


@pytest.mark.live
@pytest.mark.slow
def test_live_node_runs_window_after_window_without_error_growth(tmp_path):
    """The node over DDS (JointState source: exact header stamps, y = position and u = effort
    of joint1) on the double integrator with T = 0.5 s, fed 4 s at 1 kHz: eight windows.
    From the first T on the error stays at the rounding level of the stamps (float seconds
    near 1.7e9 resolve 0.24 us; measured ~1e-9), the same in the last window as in the
    second, whatever samples DDS drops (a lost sample is a longer step, exact for n = 2)."""
    import os
    import subprocess
    import sys
    import threading
    import time

    import yaml
    rclpy = pytest.importorskip("rclpy")
    from builtin_interfaces.msg import Time as TimeMsg
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    T, rate, duration = 0.5, 1000.0, 4.0
    doc = yaml.safe_load(DI_CONFIG.read_text())
    p = doc["observer_node"]["ros__parameters"]
    p["source"] = "joint_states"
    p["joint_states"] = dict(output_joints=["joint1"], output_field="position",
                             input_joints=["joint1"], input_field="effort")
    p["diagnostics"]["period"] = 0.2
    p["prescribed_time"]["T"] = T
    params = tmp_path / "live.yaml"
    params.write_text(yaml.safe_dump(doc, sort_keys=False))
    domain = domains.take()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
               ROS_LOG_DIR=str(tmp_path / "ros_log"), PYTHONUNBUFFERED="1",
               PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    log = open(tmp_path / "node.log", "w+")
    node = processes.spawn([sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args",
                            "--params-file", str(params)], domain=domain, cwd=ROOT, env=env,
                           stdout=log, stderr=subprocess.STDOUT)
    before = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    drv = rclpy.create_node("fto_pt_driver", context=ctx)
    lock = threading.Lock()
    est: dict[int, np.ndarray] = {}
    statuses: list[dict] = []

    def on_est(m):
        with lock:
            est[m.header.stamp.sec * 10**9 + m.header.stamp.nanosec] = np.array([m.position[0], m.velocity[0]])

    def on_diag(msg):
        for s in msg.status:
            if s.name == "observer_node: observer":
                with lock:
                    statuses.append({kv.key: kv.value for kv in s.values} | {"_level": s.level[0]})
    rel = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
    drv.create_subscription(JointState, "/observer_node/estimated_joint_states", on_est, rel)
    drv.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
    pub = drv.create_publisher(JointState, "/double_integrator/joint_states", rel)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(drv)
    spin = threading.Thread(target=lambda: ex.spin(), daemon=True)
    spin.start()

    def wait(cond, timeout, what):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return
            if node.poll() is not None:
                break
            time.sleep(0.02)
        log.flush()
        pytest.fail(f"timed out waiting for {what}; node log:\n{(tmp_path / 'node.log').read_text()}")
    try:
        wait(lambda: pub.get_subscription_count() > 0
             and drv.count_publishers("/observer_node/estimated_joint_states") > 0, 30, "the node")
        wait(lambda: statuses, 30, "the first /diagnostics")
        t = grid(duration, 1.0 / rate)
        u = np.sin(10 * t) + np.cos(t)
        X = simulate_zoh(DOUBLE_INTEGRATOR, (20.0, 1.0), t, u)
        base = time.time_ns() - 10 * 10**9
        msg = JointState(name=["joint1"])
        t0 = time.monotonic()
        for k in range(len(t)):
            ns = base + k * 10**6
            msg.header.stamp = TimeMsg(sec=ns // 10**9, nanosec=ns % 10**9)
            msg.position, msg.velocity, msg.effort = [float(X[k, 0])], [0.0], [float(u[k])]
            pub.publish(msg)
            delay = t0 + (k + 1) / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        last = base + (len(t) - 1) * 10**6
        wait(lambda: any(ns >= last - 20 * 10**6 for ns in list(est)), 15, "the last estimates")
        n_stat = len(statuses)
        wait(lambda: len(statuses) > n_stat, 10, "a final status")
        with lock:
            got = dict(est)
            st = statuses[-1]
        errs = {}
        for ns, xh in got.items():
            k = int(round((ns - base) / 1e6))
            errs[k] = np.abs(xh - X[k]).max()
        ks = np.array(sorted(errs))
        e = np.array([errs[k] for k in ks])
        tk = t[ks]
        print(f"live: {len(ks)} estimates of {len(t)} samples; windows: {st['restarts (total)']}; "
              f"max |error| after T {e[tk >= T + 0.01].max():.3g}, in the last window "
              f"{e[tk >= duration - T].max():.3g}")
        assert len(ks) > 0.5 * len(t)
        assert e[tk < 0.05].max() > 1.0                  # it starts far off
        assert e[tk >= T + 0.01].max() < 1e-6            # then exact, window after window
        assert e[tk >= duration - T].max() < 1e-6
        assert st["mode"] == "restart" and int(st["restarts (total)"]) >= 6
        for key in ("time to T (s)", "largest gain now", "gamma_i = g_i (y - x_hat_1)"):
            assert key in st
    finally:
        ex.shutdown(timeout_sec=2)
        drv.destroy_node()
        rclpy.try_shutdown(context=ctx)
        spin.join(5)
        if before is None:
            os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
        else:
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = before
        processes.interrupt(node, 15)
        log.close()
    assert node.returncode == 0, (tmp_path / "node.log").read_text()
