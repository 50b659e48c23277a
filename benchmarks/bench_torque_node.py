#!/usr/bin/env python3
"""The arm's external-torque node (``fto-external-torque``: the observer node with the
``external_torque`` family) at 1 kHz against an rclpy echo node on the same stream.

    python benchmarks/bench_torque_node.py [--duration 8] [--rounds 3] [--domain 225]
        [--family external_torque|momentum_observer]
    python benchmarks/bench_torque_node.py --micro

Live: a publisher process sends the 7-joint arm's JointState from bags/arm7_contact_link6
(positions and commanded torques of the bag from t = 2 s on; header stamp = its start
time + k ms; absolute 1 ms deadlines) for ``--duration`` s; two processes take the same
stream at once: the node (``fto-external-torque`` as its console script starts it, the arm's
URDF and joints, ``--family``: external_torque T = 60 ms or momentum_observer K = 50/s,
collision detection, /diagnostics every 0.5 s) and an rclpy echo (the node's input QoS:
best effort, keep last qos.depth; SingleThreadedExecutor, gc.freeze, each message
republished as it came). Per round: each process's user + system CPU time (/proc, all
threads) over the publishing window as a share of one core, and the loss: messages sent
minus those the process took (the node: /diagnostics samples accepted + rejected; the echo:
its own count); the node's contact onsets. The load average (1 min) at each round's start;
the ratio node / echo per round and its median.

``--micro``: in-process cost per sample of the parts the node runs (no DDS): the model's
terms, the runner's call on one message (``set_input`` + ``process``, as the node's
callback) and the same samples as one ``process_block`` (as the replay).
Every DDS process: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, ROS_DOMAIN_ID ``--domain``.
"""
from __future__ import annotations

import argparse
import copy
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

    from fto_ros.cli.arm_bag import read_arm_bag
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

    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from fto_ros.nodes.publisher import OUT_QOS
    from fto_ros.runner.settings import SETTINGS
    depth = next(p.default for p in SETTINGS if p.name == "qos.depth")
    IN_QOS = QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,     # the node's input
                        reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
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


#: fto-external-torque as its console script starts it (setup.py: fto_ros.nodes.start)
NODE = ["-c", "import sys; from fto_ros.nodes.start import external_torque; "
        "sys.exit(external_torque())"]
#: the node's parameters per family (the arm's URDF and joints, its defaults otherwise)
FAMILY = {"external_torque": ["-p", "external_torque.window:=0.06"],
          "momentum_observer": ["-p", "observer.type:=momentum_observer",
                                "-p", "momentum_observer.gain:=50.0"]}


def one_round(duration: float, domain: int, folder: Path, family: str) -> dict:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    env = _env(domain)
    count_file = folder / "echo_count"
    me = [sys.executable, str(Path(__file__).resolve())]
    node = subprocess.Popen([sys.executable, *NODE, "--ros-args", "-p", f"plant.urdf:={URDF}",
                             "-p", f"joints:=[{','.join(JOINTS)}]",
                             "-p", "diagnostics.period:=0.5", *FAMILY[family]],
                            cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    echo_p = subprocess.Popen(me + ["--role", "echo", "--count-file", str(count_file)], cwd=ROOT,
                              env=env)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    drv = rclpy.create_node("bench_torque_driver", context=ctx)
    last = {}

    def on_diag(msg):
        for st in msg.status:
            if st.name.endswith(": observer"):
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
    took = int(last.get("samples accepted", 0)) + int(last.get("samples rejected", 0))
    echo_took = int(count_file.read_text()) if count_file.exists() else 0
    # per message taken: the whole stream and its drain (both idle but for timers after it)
    node_us = (c0["node_all"] - c0["node"]) / max(took, 1) * 1e6
    echo_us = (c0["echo_all"] - c0["echo"]) / max(echo_took, 1) * 1e6
    return {"load": load, "sent": sent, "node_cpu": node_cpu, "echo_cpu": echo_cpu,
            "ratio": node_cpu / echo_cpu, "node_us": node_us, "echo_us": echo_us,
            "us_ratio": node_us / echo_us, "node_lost": sent - took, "echo_lost": sent - echo_took,
            "restarts": {k: v for k, v in last.items() if k.startswith("restarts.")},
            "detections": last.get("contact onsets")}


def micro(n: int = 3000, family: str = "external_torque") -> None:
    from benchmarks.arm_runs import arm_runner, rows as block_rows
    from fto_ros.cli.arm_bag import read_arm_bag
    run, _ = read_arm_bag(BAG)
    runner = arm_runner(family, JOINTS, urdf=URDF)
    model = runner.observer.model
    ks = np.arange(2000, 2000 + n)

    def per_sample(f):
        f(ks[0])
        t0 = time.perf_counter()
        for k in ks:
            f(k)
        return (time.perf_counter() - t0) / n * 1e6
    q, v, tau = run.q_measured, run.v, run.tau
    names = list(run.names)
    take = runner.intake.take
    # the model's terms, compiled (Pinocchio's: benchmarks/bench_arm_dynamics.py)
    out = [("model terms: M, Mdot, C'v, g (momentum_terms)",
            per_sample(lambda k: model.momentum_terms(q[k], v[k]))),
           ("  the same without M (the window's centre)",
            per_sample(lambda k: model.momentum_terms(q[k], v[k], False))),
           ("JointState intake by name (ArmIntake.take)",
            per_sample(lambda k: take(names, q[k], tau[k])))]
    for k in range(1000, 2000):                # fill the window, calibrate
        y, u = take(names, q[k], tau[k])
        runner.set_input(k * 1e-3, u)
        runner.process(k * 1e-3, y)

    def one(k):
        y, u = take(names, q[k], tau[k])
        runner.set_input(k * 1e-3, u)
        runner.process(k * 1e-3, y)
    out.append(("whole sample: intake, set_input + process (the node's call)", per_sample(one)))
    part = copy.copy(run)
    for f in ("t", "q", "v", "q_measured", "tau", "tau_ext", "effort", "stamp_ns"):
        setattr(part, f, getattr(run, f)[ks[0]:ks[-1] + 1])
    kind, t, values = block_rows(runner, part)
    fresh = arm_runner(family, JOINTS, urdf=URDF)
    t0 = time.perf_counter()
    fresh.process_block(kind, t, values)
    out.append((f"the same {n} samples as one process_block (the replay's call, a fresh runner)",
                (time.perf_counter() - t0) / n * 1e6))
    load = Path("/proc/loadavg").read_text().split()[0]
    print(f"per-sample cost, 7 joints, {family}, {n} samples of {BAG.name}, load {load}")
    print("| part | us per sample |\n|---|---|")
    for name, us in out:
        print(f"| {name} | {us:.1f} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--role", choices=("driver", "publisher", "echo"), default="driver")
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--domain", type=int, default=225)
    ap.add_argument("--count-file")
    ap.add_argument("--micro", action="store_true")
    ap.add_argument("--family", choices=sorted(FAMILY), default="external_torque")
    a = ap.parse_args(argv)
    if a.role == "publisher":
        publisher(a.duration)
        return 0
    if a.role == "echo":
        echo(a.count_file)
        return 0
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    if a.micro:
        micro(family=a.family)
        return 0
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(a.domain))
    rows = []
    for r in range(a.rounds):
        with tempfile.TemporaryDirectory(prefix="bench_torque_") as tmp:
            rows.append(one_round(a.duration, a.domain, Path(tmp), a.family))
        print(f"round {r + 1}: {rows[-1]}", flush=True)
    print(f"\n{a.family}, 7 joints at 1 kHz, {a.duration:g} s a round, {a.rounds} rounds")
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
