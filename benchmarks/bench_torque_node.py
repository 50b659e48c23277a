#!/usr/bin/env python3
"""The external-torque node at 1 kHz against an rclpy echo node on the same stream.

    python benchmarks/bench_torque_node.py [--duration 8] [--rounds 3] [--domain 225]
    python benchmarks/bench_torque_node.py --micro

Live: a publisher process sends the 7-joint arm's JointState from bags/arm7_contact_link6
(positions and commanded torques of the bag from t = 2 s on; header stamp = its start
time + k ms; absolute 1 ms deadlines) for ``--duration`` s; two processes take the same
stream at once: the node (``python -m fto_ros.nodes.torque_node``, the arm's URDF, the
window estimator, collision detection, /diagnostics every 0.5 s) and an rclpy echo (the
node's input QoS, SingleThreadedExecutor, gc.freeze, each message republished as it came).
Per round: each process's user + system CPU time (/proc, all threads) over the publishing
window as a share of one core, and the loss: messages sent minus those the process took
(the node: /diagnostics accepted + rejected; the echo: its own count). The load average
(1 min) at each round's start; the ratio node / echo per round and its median.

``--micro``: in-process cost of each part of one sample (the same loop the node runs).
Every DDS process: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, ROS_DOMAIN_ID ``--domain``.
"""
from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
BAG = ROOT / "bags" / "arm7_contact_link6"
URDF = ROOT / "urdf" / "arm7.urdf"
JOINTS = [f"joint_a{i}" for i in range(1, 8)]
START = 2.0                                     # bag time of the first message sent


def _cpu(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# --------------------------------------------------------------------------- processes
def publisher(duration: float) -> None:
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from fto_ros.cli.simulate_arm import read_arm_bag
    run, _ = read_arm_bag(BAG)
    k0 = int(np.searchsorted(run.t, START))
    rclpy.init()
    node = rclpy.create_node("bench_torque_publisher")
    pub = node.create_publisher(JointState, "joint_states",
                                QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    deadline = time.monotonic() + 60
    while pub.get_subscription_count() < 2:
        if time.monotonic() > deadline:
            raise SystemExit("publisher: the node and the echo did not subscribe within 60 s")
        time.sleep(0.05)
    time.sleep(1.0)
    n = int(round(duration * 1000))
    print("start", flush=True)
    t0_ns = time.time_ns()
    start = time.monotonic()
    msg = JointState()
    msg.name = JOINTS
    for k in range(n):
        delay = start + k * 1e-3 - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t0_ns + k * 1_000_000,
                                                                1_000_000_000)
        msg.position = run.q_measured[k0 + k].tolist()
        msg.effort = run.tau[k0 + k].tolist()
        pub.publish(msg)
    print(f"sent {n} {time.monotonic() - start:.3f}", flush=True)
    time.sleep(0.5)
    node.destroy_node()
    rclpy.try_shutdown()


def echo(count_file: str) -> None:
    import gc

    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from fto_ros.nodes.torque_node import IN_QOS, OUT_QOS
    rclpy.init()
    node = rclpy.create_node("bench_torque_echo")
    pub = node.create_publisher(JointState, "joint_states_echo", OUT_QOS)
    count = [0]

    def cb(msg):
        count[0] += 1
        pub.publish(msg)
    node.create_subscription(JointState, "joint_states", cb, IN_QOS)
    gc.freeze()
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    Path(count_file).write_text(str(count[0]))
    rclpy.try_shutdown()


# ------------------------------------------------------------------------------ driver
def _env(domain: int) -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
               OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def one_round(duration: float, domain: int, folder: Path) -> dict:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    env = _env(domain)
    count_file = folder / "echo_count"
    me = [sys.executable, str(Path(__file__).resolve())]
    node = subprocess.Popen([sys.executable, "-m", "fto_ros.nodes.torque_node", "--ros-args",
                             "-p", f"plant.urdf:={URDF}", "-p", "diagnostics.period:=0.5"],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    echo_p = subprocess.Popen(me + ["--role", "echo", "--count-file", str(count_file)], cwd=ROOT,
                              env=env)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    drv = rclpy.create_node("bench_torque_driver", context=ctx)
    last = {}

    def on_diag(msg):
        for st in msg.status:
            if st.name.endswith(": external torque"):
                last.update({kv.key: kv.value for kv in st.values})
    drv.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(drv)
    try:
        return _measure(duration, node, echo_p, ex, last, count_file, me, env)
    finally:
        for p in (node, echo_p):
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in (node, echo_p):
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
        ex.shutdown()
        drv.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _measure(duration, node, echo_p, ex, last, count_file, me, env) -> dict:
    deadline = time.monotonic() + 120
    while not last and time.monotonic() < deadline:       # the node is up (compiled, cached)
        ex.spin_once(timeout_sec=0.1)
    if not last:
        raise SystemExit(f"the node sent no /diagnostics in 120 s (exit status {node.poll()})")
    load = float(Path("/proc/loadavg").read_text().split()[0])
    pub = subprocess.Popen(me + ["--role", "publisher", "--duration", str(duration)], cwd=ROOT,
                           env=env, stdout=subprocess.PIPE, text=True)
    # the publishing window: from its first message to 0.5 s before its last
    if pub.stdout.readline().strip() != "start":
        raise SystemExit(f"the publisher did not start (exit status {pub.wait()})")
    c0 = {"node": _cpu(node.pid), "echo": _cpu(echo_p.pid)}
    w0 = time.monotonic()
    while time.monotonic() - w0 < duration - 0.5:
        ex.spin_once(timeout_sec=0.05)
    c0["node_end"], c0["echo_end"] = _cpu(node.pid), _cpu(echo_p.pid)
    c0["wall_end"] = time.monotonic()
    while pub.poll() is None:
        ex.spin_once(timeout_sec=0.05)
    out = pub.stdout.read()
    end = time.monotonic() + 1.5                  # the queues drained, the last /diagnostics
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.1)
    c0["node_all"], c0["echo_all"] = _cpu(node.pid), _cpu(echo_p.pid)
    for p in (node, echo_p):
        p.send_signal(signal.SIGINT)
    echo_p.wait(20)
    sent = int(out.split()[1]) if out.startswith("sent") else 0
    wall = c0["wall_end"] - w0
    node_cpu = (c0["node_end"] - c0["node"]) / wall
    echo_cpu = (c0["echo_end"] - c0["echo"]) / wall
    took = int(last.get("accepted", 0)) + int(last.get("rejected", 0))
    echo_took = int(count_file.read_text()) if count_file.exists() else 0
    # per message taken: the whole stream and its drain (both idle but for timers after it)
    node_us = (c0["node_all"] - c0["node"]) / max(took, 1) * 1e6
    echo_us = (c0["echo_all"] - c0["echo"]) / max(echo_took, 1) * 1e6
    return {"load": load, "sent": sent, "node_cpu": node_cpu, "echo_cpu": echo_cpu,
            "ratio": node_cpu / echo_cpu, "node_us": node_us, "echo_us": echo_us,
            "us_ratio": node_us / echo_us, "node_lost": sent - took, "echo_lost": sent - echo_took,
            "restarts": {k: v for k, v in last.items() if k.startswith("restarts.")},
            "detections": last.get("detections")}


def micro(n: int = 3000) -> None:
    from fto_ros.cli.simulate_arm import read_arm_bag
    from fto_ros.arm import steps
    from fto_ros.runner.torque_loop import TorqueLoop
    from fto_ros.runner.torque_settings import build
    run, _ = read_arm_bag(BAG)
    setup = build({"plant.urdf": str(URDF)})
    model = setup.model
    ks = np.arange(2000, 2000 + n)

    def per_sample(f):
        f(ks[0])
        t0 = time.perf_counter()
        for k in ks:
            f(k)
        return (time.perf_counter() - t0) / n * 1e6
    q, v = run.q_measured, run.v
    # the model's terms, compiled (Pinocchio's calls before: benchmarks/bench_arm_dynamics.py)
    rows = [("model terms: M, Mdot, C'v, g (momentum_terms)",
             per_sample(lambda k: model.momentum_terms(q[k], v[k]))),
            ("  the same without M (the window's centre)",
             per_sample(lambda k: model.momentum_terms(q[k], v[k], False)))]
    for compiled in (True, False):
        loop = TorqueLoop(build({"plant.urdf": str(URDF)}))
        loop.est.compiled = compiled
        loop.est.reset()
        for k in range(1000, 1100):           # fill the window (and compile)
            loop.process(k * 1_000_000, JOINTS, q[k], run.tau[k])
        rows.append((f"whole sample, loop.process ({'compiled' if compiled else 'numpy'} steps)",
                     per_sample(lambda k, lp=loop: lp.process(k * 1_000_000, JOINTS, q[k],
                                                              run.tau[k]))))
    W = setup.estimator.samples
    c = steps.window_consts(7, W, 1e-3, model.viscous)
    st = steps.window_init(c)
    M, Md, _, _ = model.momentum_terms(q[0], v[0])
    for k in range(W + 1):
        st = steps.window_step(st, c, 1e-3, q[k], run.tau[k], M, Md, np.zeros(7))
    rows.append(("numpy window_step alone", per_sample(
        lambda k: steps.window_step(st, c, 1e-3, q[k], run.tau[k], M, Md, np.zeros(7), Md,
                                    np.zeros(7)))))
    from fto_ros.arm import steps_compiled
    new = np.empty_like(st)
    rows.append(("compiled window_step alone", per_sample(
        lambda k: steps_compiled.window_step(st, c, q[k], run.tau[k], M, Md, np.zeros(7), Md,
                                             np.zeros(7), True, new))))
    load = Path("/proc/loadavg").read_text().split()[0]
    print(f"per-sample cost, 7 joints, T = 60 ms (W = {W}), {n} samples, load {load}")
    print("| part | us per sample |\n|---|---|")
    for name, us in rows:
        print(f"| {name} | {us:.1f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--role", choices=("driver", "publisher", "echo"), default="driver")
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--domain", type=int, default=225)
    ap.add_argument("--count-file")
    ap.add_argument("--micro", action="store_true")
    a = ap.parse_args(argv)
    if a.role == "publisher":
        publisher(a.duration)
        return 0
    if a.role == "echo":
        echo(a.count_file)
        return 0
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    if a.micro:
        micro()
        return 0
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(a.domain))
    rows = []
    for r in range(a.rounds):
        with tempfile.TemporaryDirectory(prefix="bench_torque_") as tmp:
            rows.append(one_round(a.duration, a.domain, Path(tmp)))
        print(f"round {r + 1}: {rows[-1]}", flush=True)
    print(f"\n7 joints at 1 kHz, {a.duration:g} s a round, {a.rounds} rounds")
    print("| round | load (1 min) | sent | node CPU (core) | echo CPU (core) | ratio | "
          "node us/msg | echo us/msg | ratio per msg | node lost | echo lost | detections |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")
    for i, r in enumerate(rows):
        print(f"| {i + 1} | {r['load']:.2f} | {r['sent']} | {r['node_cpu']:.3f} | "
              f"{r['echo_cpu']:.3f} | {r['ratio']:.2f} | {r['node_us']:.0f} | {r['echo_us']:.0f} | "
              f"{r['us_ratio']:.2f} | {r['node_lost']} | {r['echo_lost']} | {r['detections']} |")
    print(f"\nmedian ratio node / echo: CPU share {statistics.median(r['ratio'] for r in rows):.2f}, "
          f"CPU per message taken {statistics.median(r['us_ratio'] for r in rows):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
