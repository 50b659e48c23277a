#!/usr/bin/env python3
"""Live-node throughput, drops, latency and memory: the observer node vs a plain rclpy echo.

    python benchmarks/bench_live_node.py [--rates 1000 2000 5000] [--duration 20]
                                         [--kinds echo observer_js observer_topics]

For every (rate, kind) it starts three processes, each on a DDS domain of its own run
(LOCALHOST discovery, distinct ROS_DOMAIN_IDs): the node under test, a publisher
process that sends at the target rate for --duration seconds (absolute deadlines, so
it catches up after a late wake-up), and this driver, which subscribes to the node's
output and records the arrival times.  Kinds:

- ``echo``: a plain rclpy node that republishes every Float64MultiArray it gets (same
  QoS and executor as the observer node: best effort keep-last 100 in, reliable
  keep-last 10 out, SingleThreadedExecutor).  The message carries its send time.
- ``observer_js``: fto_ros's observer node (config/dc_motor_luenberger.yaml) on a
  JointState source at the target rate, one message per sample, header stamp = send
  time (wall clock); the driver receives ``estimated_joint_states``, whose stamp is the
  measurement stamp, so every latency is exact.
- ``observer_topics``: the same node on Float64MultiArray ``input`` + ``measured_output``
  (two messages per sample, stamped on receipt).  ``estimated_joint_states`` then
  carries the node's receipt time; each estimate is matched to the last sample sent
  before that time (exact while the node keeps up; 'lat' is marked ~ otherwise).

Latency is one way publisher -> node -> driver (CLOCK_REALTIME shared by the processes).
Memory is the node's VmRSS from /proc at the start and the end of the publishing window;
CPU is the node's user+system time over the window.  --duration 600 is the 10-minute run
for the memory target.  Prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "dc_motor_luenberger.yaml"
KINDS = ("echo", "observer_js", "observer_topics")


# ----------------------------------------------------------------------- echo node
def run_echo() -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
    from std_msgs.msg import Float64MultiArray

    rclpy.init()
    node = rclpy.create_node("echo_node")
    pub = node.create_publisher(Float64MultiArray, "echo_out",
                                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    node.create_subscription(Float64MultiArray, "echo_in", pub.publish,
                             QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                                        reliability=ReliabilityPolicy.BEST_EFFORT))
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ------------------------------------------------------------------- publisher
def run_publisher(kind: str, rate: float, duration: float, out: str) -> int:
    import math

    import rclpy
    from builtin_interfaces.msg import Time as TimeMsg
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    rclpy.init()
    node = rclpy.create_node("bench_publisher")
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    if kind == "echo":
        pubs = [node.create_publisher(Float64MultiArray, "echo_in", qos)]
    elif kind == "observer_js":
        pubs = [node.create_publisher(JointState, "/dc_motor/joint_states", qos)]
    else:
        pubs = [node.create_publisher(Float64MultiArray, "/dc_motor/input", qos),
                node.create_publisher(Float64MultiArray, "/dc_motor/measured_output", qos)]
    deadline = time.monotonic() + 30
    while any(p.get_subscription_count() == 0 for p in pubs):
        if time.monotonic() > deadline:
            print("publisher: no subscriber matched", file=sys.stderr)
            return 1
        time.sleep(0.05)
    time.sleep(1.0)  # let the reverse matches settle too

    n = int(round(rate * duration))
    sent = np.zeros(n, dtype=np.int64)
    period = 1.0 / rate
    js = JointState(name=["joint1"], position=[0.0], velocity=[0.0], effort=[0.0])
    u_msg, y_msg, e_msg = Float64MultiArray(), Float64MultiArray(), Float64MultiArray()
    base_ns = time.time_ns()
    t0 = time.monotonic()
    print(json.dumps({"start_ns": base_ns}), flush=True)
    for k in range(n):
        target = t0 + k * period
        delay = target - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        t = k * period
        now = time.time_ns()
        if kind == "echo":
            e_msg.data = [(now - base_ns) * 1e-9, float(k)]
            pubs[0].publish(e_msg)
        elif kind == "observer_js":
            js.header.stamp = TimeMsg(sec=now // 10**9, nanosec=now % 10**9)
            js.position[0] = 0.5 * math.sin(t)
            js.effort[0] = 2.0 + math.sin(t)
            pubs[0].publish(js)
        else:
            u_msg.data = [2.0 + math.sin(t)]
            pubs[0].publish(u_msg)
            now = time.time_ns()
            y_msg.data = [0.5 * math.sin(t)]
            pubs[1].publish(y_msg)
        sent[k] = now
    elapsed = time.monotonic() - t0
    np.save(out, sent)
    print(json.dumps({"sent": n, "elapsed": elapsed, "base_ns": base_ns}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# ---------------------------------------------------------------------- driver
def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _env(domain: int, tmp: str) -> dict:
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
               ROS_LOG_DIR=os.path.join(tmp, "ros_log"), PYTHONUNBUFFERED="1",
               PYTHONPATH=os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    return env


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def measure(kind: str, rate: float, duration: float, domain: int, tmp: str,
            config: Path = CONFIG) -> dict:
    """One run: node + publisher subprocesses, this process receiving.  Returns the row."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    env = _env(domain, tmp)
    me = [sys.executable, str(Path(__file__).resolve())]
    if kind == "echo":
        node_cmd = me + ["--role", "echo"]
    else:
        from fto_ros.runner.plant_files import params_files   # not in the echo node's process
        node_cmd = [sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args",
                    *[a for p in params_files(config) for a in ("--params-file", str(p))],
                    "-p", "diagnostics.period:=0.5",
                    "-p", f"diagnostics.expected_rate:={float(rate)}"]
        if kind == "observer_js":
            node_cmd += ["-p", "source:=joint_states", "-p", "joint_states.input_joints:=[joint1]"]
    node_log = open(os.path.join(tmp, f"node_{kind}_{int(rate)}.log"), "w")
    node = subprocess.Popen(node_cmd, cwd=ROOT, env=env, stdout=node_log, stderr=subprocess.STDOUT)

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    drv = rclpy.create_node("bench_driver", context=ctx)
    n_expected = int(round(rate * duration))
    recv_ns = np.zeros(n_expected + 1000, dtype=np.int64)
    key = np.zeros(n_expected + 1000, dtype=np.float64)   # send time (echo) or stamp (observer)
    count = [0]
    diag: dict = {}
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)

    if kind == "echo":
        topic = "echo_out"

        def on_out(msg):
            i = count[0]
            if i < len(recv_ns):
                recv_ns[i] = time.time_ns()
                key[i] = msg.data[0]
            count[0] = i + 1
        drv.create_subscription(Float64MultiArray, topic, on_out, qos)
    else:
        topic = "/observer_node/estimated_joint_states"

        def on_out(msg):
            i = count[0]
            if i < len(recv_ns):
                recv_ns[i] = time.time_ns()
                st = msg.header.stamp
                key[i] = st.sec * 1e9 + st.nanosec   # float64: exact to ~0.25 us
            count[0] = i + 1
        drv.create_subscription(JointState, topic, on_out, qos)

        def on_diag(msg):
            for s in msg.status:
                if s.name.endswith(": observer"):
                    diag.clear()
                    diag.update({kv.key: kv.value for kv in s.values})
        drv.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(drv)

    def spin_until(cond, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not cond():
            ex.spin_once(timeout_sec=0.05)
        return cond()

    row = {"kind": kind, "rate": rate}
    pub_proc = None
    try:
        if not spin_until(lambda: drv.count_publishers(topic) > 0 or node.poll() is not None, 60) \
                or node.poll() is not None:
            raise RuntimeError(f"{kind} node did not come up; see {node_log.name}")
        sent_file = os.path.join(tmp, f"sent_{kind}_{int(rate)}.npy")
        pub_proc = subprocess.Popen(me + ["--role", "publisher", "--kind", kind, "--rate", str(rate),
                                          "--duration", str(duration), "--out", sent_file],
                                    cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)
        first = pub_proc.stdout.readline()   # {"start_ns": ...} when publishing starts
        if not first:
            raise RuntimeError("publisher failed to start")
        rss0, cpu0, t0 = _rss_kb(node.pid), _cpu_s(node.pid), time.monotonic()
        spin_until(lambda: pub_proc.poll() is not None, duration + 60)
        rss1, cpu1, t1 = _rss_kb(node.pid), _cpu_s(node.pid), time.monotonic()
        info = json.loads(pub_proc.stdout.read().strip().splitlines()[-1])
        # stragglers, then a fresh /diagnostics
        spin_until(lambda: count[0] >= info["sent"], 3.0)
        if kind != "echo":
            diag.clear()
            spin_until(lambda: bool(diag), 3.0)
        sent = np.load(sent_file)
        n = min(count[0], len(recv_ns))
        recv, k = recv_ns[:n], key[:n]
        approx = False
        if kind == "echo":
            lat = (recv - info["base_ns"]) * 1e-9 - k
        elif kind == "observer_js":
            lat = (recv - k) * 1e-9
        else:
            idx = np.searchsorted(sent.astype(np.float64), k, side="right") - 1
            ok = idx >= 0
            lat = (recv[ok] - sent[idx[ok]]) * 1e-9
            approx = n != len(sent)
            if not approx:  # one estimate per sample, in order: exact matching
                lat = (recv - sent[:n]) * 1e-9
        lat_ms = np.sort(lat) * 1e3
        row.update(
            sent=int(info["sent"]), sent_rate=info["sent"] / info["elapsed"],
            node_in=int(diag.get("messages received: joint_states" if kind == "observer_js"
                                 else "messages received: measured_output", n)) if kind != "echo" else n,
            accepted=int(diag["samples accepted"]) if "samples accepted" in diag else None,
            out=n, out_rate=n / info["elapsed"], dropped=int(info["sent"]) - n,
            lat_p50=float(np.percentile(lat_ms, 50)) if n else float("nan"),
            lat_p99=float(np.percentile(lat_ms, 99)) if n else float("nan"),
            lat_max=float(lat_ms[-1]) if n else float("nan"), approx=approx,
            rss0_mb=rss0 / 1024, rss1_mb=rss1 / 1024, cpu=100.0 * (cpu1 - cpu0) / (t1 - t0),
            update_us=diag.get("update time p50/p99 (us)", "-"))
    finally:
        if pub_proc is not None:
            _stop(pub_proc)
        _stop(node)
        node_log.close()
        drv.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return row


def table(rows: list[dict], duration: float) -> str:
    head = ("| node | target (Hz) | sent | sent rate (Hz) | node received | estimates out | "
            "out rate (Hz) | lost | latency p50 / p99 / max (ms) | node CPU (%) | "
            "RSS start -> end (MB) | update p50/p99 (us) |")
    lines = [f"Live node benchmark, {duration:g} s per run, {os.cpu_count()} CPU(s), "
             f"Python {sys.version.split()[0]}", "", head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['kind']} | {r['rate']:g} | failed: {r['error']} |")
            continue
        lat = f"{r['lat_p50']:.2f} / {r['lat_p99']:.2f} / {r['lat_max']:.1f}"
        if r["approx"]:
            lat = "~" + lat
        lines.append(
            f"| {r['kind']} | {r['rate']:g} | {r['sent']} | {r['sent_rate']:.0f} | {r['node_in']} | "
            f"{r['out']} | {r['out_rate']:.0f} | "
            f"{r['dropped']} ({100.0 * r['dropped'] / max(r['sent'], 1):.2f} %) | "
            f"{lat} | {r['cpu']:.0f} | {r['rss0_mb']:.1f} -> {r['rss1_mb']:.1f} | {r['update_us']} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[1000.0])
    ap.add_argument("--duration", type=float, default=20.0, help="publishing time per run (s)")
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--json", help="also write the rows to this JSON file")
    ap.add_argument("--config", default=str(CONFIG),
                    help="params file of the observer node (default: %(default)s)")
    ap.add_argument("--role", choices=("driver", "echo", "publisher"), default="driver",
                    help=argparse.SUPPRESS)
    ap.add_argument("--kind", choices=KINDS, help=argparse.SUPPRESS)
    ap.add_argument("--rate", type=float, help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.role == "echo":
        return run_echo()
    if args.role == "publisher":
        return run_publisher(args.kind, args.rate, args.duration, args.out)

    rows = []
    with tempfile.TemporaryDirectory(prefix="fto_bench_") as tmp:
        for i, rate in enumerate(args.rates):
            for j, kind in enumerate(args.kinds):
                domain = 1 + (os.getpid() + 20 + 3 * i + j) % 100
                print(f"# {kind} at {rate:g} Hz for {args.duration:g} s (domain {domain}) ...",
                      file=sys.stderr, flush=True)
                try:
                    rows.append(measure(kind, rate, args.duration, domain, tmp, Path(args.config)))
                except Exception as exc:  # keep going: one failed run must not hide the rest
                    rows.append({"kind": kind, "rate": rate, "error": str(exc)})
    print(f"observer params: {Path(args.config).name}")
    print(table(rows, args.duration))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
