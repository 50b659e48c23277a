"""The live tests' side of a node over DDS: the node as a subprocess (``NodeProcess``, started
as a user starts it: ``python -m fto_ros.nodes.observer_node --ros-args --params-file ...``,
or a command such as `ros2 launch`), the test's own rclpy node (``Driver``: publishers,
subscribers, service clients, an executor spinning in a thread), the simulated DC motor
they exchange, and small message helpers.

Every process gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a domain id no other test of
the run holds (test/support/domains.py), so no traffic leaves the machine and a test never
meets another's node; processes start in a session of their own with default signal handling
and are killed with their group when the test ends (test/support/processes.py).

The plant is the DC-motor manipulator of config/dc_motor_luenberger.yaml
(q' = q_dot, q_dot' = 15 I - 35 sin q - q_dot, I' = 40 V - 36.4 q_dot - 200 I,
V = 2 + sin t, x(0) = (0.5, -1, 0.2)), integrated with scipy and sampled every 1 ms; TOL and
T_CONVERGED are derived in test/system/test_node_live.py's docstring.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy

from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

import domains
import processes

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "test" / "data" / "dc_motor_explicit" / "dc_motor_luenberger.yaml"
STATUS_NAME = "observer_node: observer"
NODE = "/observer_node"
TOL = np.array([1e-3, 1e-2, 5e-2])  # (q, q_dot, I), see test_node_live.py's docstring
T_CONVERGED = 0.5

__all__ = ["CONFIG", "Clock", "Driver", "NODE", "NodeProcess", "ROOT", "STATUS_NAME",
           "T_CONVERGED", "TOL", "array", "assert_all_finite", "count", "errors_after",
           "feed", "pace", "params_file", "ros_env", "simulate", "stamp"]


# --------------------------------------------------------------------------- plant
def simulate(duration: float, dt: float = 1e-3):
    """(t, x, V) of the DC motor from x(0) = (0.5, -1, 0.2) under V = 2 + sin t."""
    from scipy.integrate import solve_ivp

    def f(t, x):
        q, qd, i = x
        v = 2.0 + math.sin(t)
        return [qd, 15.0 * i - 35.0 * math.sin(q) - qd, 40.0 * v - 36.4 * qd - 200.0 * i]

    n = int(round(duration / dt))
    ts = np.arange(n + 1) * dt
    sol = solve_ivp(f, (0.0, ts[-1]), [0.5, -1.0, 0.2], t_eval=ts, rtol=1e-10, atol=1e-12,
                    method="LSODA")
    assert sol.success
    return ts, sol.y.T, 2.0 + np.sin(ts)


def errors_after(est_by_ns: dict, base_ns: int, plant, t_from: float):
    """|estimate - truth| for the estimates stamped base_ns + k ms with t_k >= t_from."""
    ts, x, _ = plant
    errs = []
    for ns, xh in est_by_ns.items():
        k = int(round((ns - base_ns) / 1e6))
        if 0 <= k < len(ts) and ts[k] >= t_from:
            errs.append(np.abs(xh - x[k]))
    return np.array(errs)


# ---------------------------------------------------------------------- processes
def ros_env(domain: int, tmp: Path) -> dict:
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
               ROS_LOG_DIR=str(tmp / "ros_log"), PYTHONUNBUFFERED="1",
               PYTHONPATH=os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    return env


def params_file(tmp: Path, name: str, edit=None) -> Path:
    """A copy of the Luenberger config with the test's own gain, edited by ``edit(params)``.

    The gain is pinned (pole placement at -50, -60, -70, which the tolerances were derived
    for) whatever tuning the shipped config has.
    """
    doc = yaml.safe_load(CONFIG.read_text())
    luenberger = doc["observer_node"]["ros__parameters"]["luenberger"]
    for key in ("process_noise", "measurement_noise"):
        luenberger.pop(key, None)
    luenberger.update(design="poles", poles=[-50.0, -60.0, -70.0])
    if edit is not None:
        edit(doc["observer_node"]["ros__parameters"])
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


class NodeProcess:
    """The observer node (or a command that starts it) as a subprocess in a session of its
    own; stop() is SIGINT to it (Ctrl-C), then SIGKILL to what is left of its group."""

    def __init__(self, tmp: Path, domain: int, params: Path | None, *extra: str,
                 module: str = "fto_ros.nodes.observer_node", cmd: list[str] | None = None,
                 env: dict | None = None):
        """``python -m MODULE --ros-args [--params-file PARAMS] EXTRA...``, or ``cmd`` (e.g.
        `ros2 launch ...`) with ``env``."""
        self.err_path = tmp / f"node_{domain}_{int(time.monotonic() * 1e3)}.log"
        self._err = open(self.err_path, "w+")
        if cmd is None:
            cmd = [sys.executable, "-m", module, "--ros-args",
                   *(("--params-file", str(params)) if params is not None else ()), *extra]
        self.proc = processes.spawn(cmd, domain=domain, cwd=ROOT, env=env or ros_env(domain, tmp),
                                    stdout=self._err, stderr=subprocess.STDOUT)
        self.domain = domain

    def log(self) -> str:
        if not self._err.closed:
            self._err.flush()
        return self.err_path.read_text()

    def check_alive(self) -> None:
        if self.proc.poll() is not None:
            pytest.fail(f"node exited with {self.proc.returncode}:\n{self.log()}")

    def stop(self) -> int:
        code = processes.interrupt(self.proc, 30)
        if not self._err.closed:
            self._err.close()
        return code


class Driver:
    """The test's own rclpy node: publishers, subscribers, clients; spins in a thread."""

    def __init__(self, domain: int, outputs=("state_estimate", "convergence", "estimated_joint_states")):
        self._env_before = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.domain = domain
        domains.hold(domain)
        self.node = rclpy.create_node("fto_test_driver", context=self.ctx)
        self.lock = threading.Lock()
        self.received: dict[str, list] = {}
        self.statuses: list[dict] = []
        rel = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        for topic in ("state_estimate", "convergence"):
            self.received[topic] = []
            if topic in outputs:
                self._collect(Float64MultiArray, topic, NODE + "/" + topic, rel, lambda m: np.array(m.data))
        self.received["estimated_joint_states"] = []
        if "estimated_joint_states" in outputs:
            self._collect(JointState, "estimated_joint_states", NODE + "/estimated_joint_states", rel,
                          lambda m: (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                                     np.array([m.position[0], m.velocity[0], m.effort[0]])))
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)
        pub_qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.pub_y = self.node.create_publisher(Float64MultiArray, "/dc_motor/measured_output", pub_qos)
        self.pub_u = self.node.create_publisher(Float64MultiArray, "/dc_motor/input", pub_qos)
        self.pub_js = self.node.create_publisher(JointState, "/dc_motor/joint_states", pub_qos)
        self.pub_clock = self.node.create_publisher(Clock, "/clock", pub_qos)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # shutdown while spinning
            pass

    def _collect(self, mtype, key, topic, qos, convert):
        def cb(msg, key=key):
            with self.lock:
                self.received[key].append(convert(msg))
        self.node.create_subscription(mtype, topic, cb, qos)

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name == STATUS_NAME:
                with self.lock:
                    self.statuses.append({"level": st.level[0], "message": st.message,
                                          "hardware_id": st.hardware_id,
                                          "values": {kv.key: kv.value for kv in st.values}})

    def close(self):
        self.executor.shutdown(timeout_sec=2)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        self.thread.join(5)
        domains.release(self.domain)
        if self._env_before is None:
            os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
        else:
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = self._env_before

    # -- helpers ------------------------------------------------------------------
    def got(self, topic) -> list:
        with self.lock:
            return list(self.received[topic])

    def wait_for(self, cond, timeout: float, what: str, node: NodeProcess | None = None):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = cond()
            if value:
                return value
            if node is not None:
                node.check_alive()
            time.sleep(0.02)
        log = "" if node is None else "\nnode log:\n" + node.log()
        pytest.fail(f"timed out after {timeout} s waiting for {what}{log}")

    def wait_connected(self, node: NodeProcess, pubs, outputs=("state_estimate",)):
        """Wait until the node's subscriptions and publishers have matched ours."""
        self.wait_for(lambda: all(p.get_subscription_count() > 0 for p in pubs), 30,
                      "the node's subscriptions", node)
        self.wait_for(lambda: all(self.node.count_publishers(f"{NODE}/{t}") > 0 for t in outputs), 30,
                      "the node's publishers", node)
        self.wait_for(self.last_status, 30, "the first /diagnostics", node)

    def has_estimate_after(self, stamp_ns: int) -> bool:
        return any(ns >= stamp_ns for ns, _ in self.got("estimated_joint_states"))

    def last_status(self, after: int = 0) -> dict | None:
        with self.lock:
            return self.statuses[-1] if len(self.statuses) > after else None

    def status_where(self, pred, timeout: float, what: str, node=None) -> dict:
        """Wait for a /diagnostics status (arriving from now on) for which pred holds."""
        with self.lock:
            start = len(self.statuses)

        def check():
            with self.lock:
                for st in self.statuses[start:]:
                    if pred(st):
                        return st
            return None
        return self.wait_for(check, timeout, what, node)

    def wait_quiet(self, node, key: str, timeout: float = 30.0) -> dict:
        """Wait until the node has taken everything sent: its count ``key`` (e.g. 'messages
        received: joint_states') the same in two statuses in a row; that status."""
        seen = [None]

        def quiet():
            st = self.status_where(lambda s: True, 10, "a status", node)
            same = seen[0] is not None and st["values"].get(key) == seen[0]["values"].get(key)
            seen[0] = st
            return st if same else None
        return self.wait_for(quiet, timeout, f"'{key}' to stop growing", node)

    def call(self, srv_type, name: str, request, timeout: float = 10.0):
        client = self.node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=timeout):
                pytest.fail(f"service {name} not available")
            future = client.call_async(request)
            self.wait_for(future.done, timeout, f"the answer of {name}")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def set_parameter(self, name: str, value):
        req = SetParameters.Request()
        req.parameters = [Parameter(name, value=value).to_parameter_msg()]
        return self.call(SetParameters, NODE + "/set_parameters", req).results[0]


# -------------------------------------------------------------------- messages
def array(values) -> Float64MultiArray:
    msg = Float64MultiArray()
    msg.data = [float(v) for v in values]
    return msg


def stamp(ns: int) -> TimeMsg:
    return TimeMsg(sec=ns // 10**9, nanosec=ns % 10**9)


def count(st: dict, key: str) -> int:
    return int(st["values"].get(key, "0"))


def assert_all_finite(driver: Driver, topics=("state_estimate", "convergence")):
    for topic in topics:
        data = driver.got(topic)
        assert data, f"nothing received on {topic}"
        assert all(np.all(np.isfinite(d)) for d in data), f"non-finite value published on {topic}"


def pace(k: int, t0: float, rate: float):
    """Sleep so that sample k goes out at about t0 + k / rate (wall clock)."""
    delay = t0 + k / rate - time.monotonic()
    if delay > 0:
        time.sleep(delay)


def feed(driver, plant, n, *, start=0, rate=500.0, y_override=None):
    """Publish n (u, y) pairs of the simulated plant at `rate` Hz wall clock."""
    ts, x, v = plant
    t0 = time.monotonic()
    for k in range(start, start + n):
        driver.pub_u.publish(array([v[k]]))
        y = [x[k, 0]] if y_override is None else y_override(k)
        driver.pub_y.publish(array(y))
        pace(k - start, t0, rate)
