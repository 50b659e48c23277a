#!/usr/bin/env python3
"""The ROS side of a JointState node, per message: executors, raw intake, raw publishing, QoS.

    python benchmarks/bench_node_io.py [--joints 7 1] [--variants ...] [--rate 1000]
                                       [--duration 10] [--repeats 3]
    python benchmarks/bench_node_io.py --qos [--rates 1000 5000] [--duration 5]
    python benchmarks/bench_node_io.py --micro

Live runs: a publisher process sends one sensor_msgs/JointState (``--joints`` names,
position, velocity and effort each that long; header stamp = its wall clock at sending)
at ``--rate`` for ``--duration`` seconds (absolute deadlines); a node process (one
variant, below) takes each message and publishes one JointState with its stamp; this
driver receives them (raw, DDS message info).  Per run:

- node CPU: user + system time of the node process (all its threads, /proc) over the
  publishing window, per message sent and as a share of one core;
- latency: the listener's DDS receipt time of an output minus its header stamp (the
  publisher's send time): publisher -> node -> listener, without the listener's executor;
- lost: sent stamps that never came back.

The variants run one after another on the same stream in every repeat (rounds), the
echo in each round, so every ratio is within one round; the tables give the median
over rounds of each ratio and the load average (1 min) at each round's start.

Variants (executor / intake / output):

- ``echo``: SingleThreadedExecutor, rclpy message in, the same message republished:
  the reference (the node's QoS: best effort keep last 100 in, reliable keep last 10 out);
- ``echo_events``: the same on rclpy.experimental.EventsExecutor;
- ``msg_arrays``: single, message in -> numpy arrays -> one reused message out (the
  arrays assigned as array.array: how the node published before it sent the output
  plan's CDR, nodes/publisher.py);
- ``raw_in``: single, raw intake decoded with numpy (nodes/fast_io.py) -> reused message out;
- ``raw``: single, raw intake -> pre-serialised CDR out (fast_io.JointStatePublisher);
- ``raw_events``: the same on the EventsExecutor;
- ``raw_block`` / ``raw_block_events``: raw, every message waiting taken in one callback
  (fast_io.JointStateIntake(on_block=...)), each republished;
- ``raw_echo_events``: EventsExecutor, the raw bytes republished untouched (the floor).

``--qos``: the echo and raw_events at each rate with the node's input QoS best effort
keep last 1 / 10 / 100 and reliable keep last 100 (the publisher: reliable keep last 100).
``--micro``: in-process cost of decoding and encoding one message each way (no DDS):
rclpy's and rosbags' deserialisers against core/cdr.py's JointStateDecoder (one payload,
and a block of 10), rclpy's assign + serialise against core/cdr.py's JointStateEncoder.
(The column "out: bag/cdr.py template" is gone: bag/cdr.py's template encoder and the
node's encoder are one codec now, core/cdr.py.)
Every DDS process: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, ROS_DOMAIN_ID ``--domain``.
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
sys.path.insert(0, str(ROOT))

#: variant -> (executor, intake, output)
VARIANTS = {
    "echo": ("single", "msg", "echo"),
    "echo_events": ("events", "msg", "echo"),
    "msg_arrays": ("single", "msg", "msg"),
    "raw_in": ("single", "raw", "msg"),
    "raw": ("single", "raw", "raw"),
    "raw_events": ("events", "raw", "raw"),
    "raw_block": ("single", "block", "raw"),
    "raw_block_events": ("events", "block", "raw"),
    "raw_echo_events": ("events", "bytes", "echo"),
}
QOS_STUDY = ("be:1", "be:10", "be:100", "rel:100")
IN_TOPIC, OUT_TOPIC = "joint_states", "joint_states_out"


def joint_names(n: int) -> list[str]:
    return [f"joint_a{i + 1}" for i in range(n)]


def make_qos(spec: str):
    """'be:100' / 'rel:100': best effort / reliable, keep last N, volatile."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    kind, depth = spec.split(":")
    rel = {"be": ReliabilityPolicy.BEST_EFFORT, "rel": ReliabilityPolicy.RELIABLE}[kind]
    return QoSProfile(depth=int(depth), history=HistoryPolicy.KEEP_LAST, reliability=rel,
                      durability=DurabilityPolicy.VOLATILE)


# --------------------------------------------------------------------- the node
def run_node(variant: str, joints: int, in_qos: str, stats_path: str) -> int:
    import array

    import rclpy
    from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import JointState

    from fto_ros.nodes.fast_io import JointStateIntake, JointStatePublisher, create_executor, spin
    from fto_ros.nodes.publisher import OUT_QOS

    executor_kind, intake_kind, output = VARIANTS[variant]
    rclpy.init()
    node = rclpy.create_node("io_node")
    qos = make_qos(in_qos)
    no_sub_events = SubscriptionEventCallbacks(use_default_callbacks=False)
    stats = {"variant": variant, "callbacks": 0, "messages": 0, "max_block": 0}
    names = joint_names(joints)

    def doubles(a) -> array.array:
        return array.array("d", a.tobytes())

    intake = None
    if output == "echo":
        pub = node.create_publisher(JointState, OUT_TOPIC, OUT_QOS,
                                    event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
        node.create_subscription(JointState, IN_TOPIC, pub.publish, qos, raw=intake_kind == "bytes",
                                 event_callbacks=no_sub_events)
    elif output == "msg":
        pub = node.create_publisher(JointState, OUT_TOPIC, OUT_QOS,
                                    event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
        out = JointState(name=names)

        def put(sec, nanosec, pos, vel, eff):
            out.header.stamp.sec, out.header.stamp.nanosec = sec, nanosec
            out.position, out.velocity, out.effort = doubles(pos), doubles(vel), doubles(eff)
            pub.publish(out)
        if intake_kind == "msg":
            def on_msg(msg):
                st = msg.header.stamp
                put(st.sec, st.nanosec, np.array(msg.position), np.array(msg.velocity),
                    np.array(msg.effort))
            node.create_subscription(JointState, IN_TOPIC, on_msg, qos, event_callbacks=no_sub_events)
        else:
            intake = JointStateIntake(node, IN_TOPIC, qos, on_message=lambda js: put(
                js.sec, js.nanosec, js.position, js.velocity, js.effort))
    else:
        raw_pub = JointStatePublisher(node, OUT_TOPIC, names)
        put = raw_pub.publish
        if intake_kind == "raw":
            intake = JointStateIntake(node, IN_TOPIC, qos, on_message=lambda js: put(
                js.sec, js.nanosec, js.position, js.velocity, js.effort))
        else:
            def on_block(runs):
                for stamps, js in runs:
                    k = len(stamps)
                    stats["max_block"] = max(stats["max_block"], k)
                    for i in range(k):
                        s, ns = divmod(int(stamps[i]), 1_000_000_000)
                        put(s, ns, js.position[i], js.velocity[i], js.effort[i])
            intake = JointStateIntake(node, IN_TOPIC, qos, on_block=on_block)
    executor = create_executor(executor_kind)
    executor.add_node(node)
    try:
        spin(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if intake is not None:
            stats.update(callbacks=intake.callbacks, messages=intake.received,
                         fast=intake.decoder.fast, parsed=intake.decoder.parsed,
                         fallback=intake.fallback, rejected=intake.rejected)
        Path(stats_path).write_text(json.dumps(stats))
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# ---------------------------------------------------------------- the publisher
def run_publisher(joints: int, rate: float, duration: float, out: str, stamps: str = "send") -> int:
    """``stamps``: 'send' (the wall clock when the message is sent) or 'nominal' (the wall
    clock at the start + k / rate: a fixed-rate control loop's time, steps exact)."""
    import math

    import rclpy
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node("io_publisher")
    pub = node.create_publisher(JointState, IN_TOPIC, make_qos("rel:100"))
    end = time.monotonic() + 30
    while pub.get_subscription_count() == 0:
        if time.monotonic() > end:
            print("publisher: no subscriber matched", file=sys.stderr)
            return 1
        time.sleep(0.05)
    time.sleep(1.0)   # let the node's and the listener's matches settle
    names = joint_names(joints)
    msg = JointState(name=names, position=[0.0] * joints, velocity=[0.0] * joints,
                     effort=[0.0] * joints)
    n = int(round(rate * duration))
    sent = np.zeros(n, dtype=np.int64)
    period = 1.0 / rate
    print(json.dumps({"start": True}), flush=True)
    t0 = time.monotonic()
    wall0 = time.time_ns()
    stamp = msg.header.stamp
    for k in range(n):
        delay = t0 + k * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        now = time.time_ns() if stamps == "send" else wall0 + round(k * period * 1e9)
        stamp.sec, stamp.nanosec = divmod(now, 1_000_000_000)
        msg.position[0] = math.sin(k * period)
        msg.velocity[0] = float(k)
        pub.publish(msg)
        sent[k] = now
    elapsed = time.monotonic() - t0
    np.save(out, sent)
    print(json.dumps({"sent": n, "elapsed": elapsed}), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


# -------------------------------------------------------------------- the driver
def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _env(domain: int, tmp: str) -> dict:
    env = dict(os.environ)
    env.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
               ROS_LOG_DIR=os.path.join(tmp, "ros_log"), PYTHONUNBUFFERED="1",
               OPENBLAS_NUM_THREADS="1",
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


def measure(variant: str, joints: int, rate: float, duration: float, domain: int, tmp: str,
            in_qos: str = "be:100", node_cmd: list[str] | None = None,
            startup_s: float = 60.0, stamps: str = "send") -> dict:
    """One run: node and publisher subprocesses, this process listening.  The row.
    ``node_cmd``: another node to measure (it subscribes to /joint_states and publishes
    one JointState with the input's stamp on /joint_states_out), e.g. the observer node
    (benchmarks/bench_live_arm.py); ``startup_s``: how long it may take to come up;
    ``stamps``: the publisher's (run_publisher)."""
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain))
    import struct

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from fto_ros.nodes.fast_io import message_info_callback

    env = _env(domain, tmp)
    me = [sys.executable, str(Path(__file__).resolve())]
    tag = f"{variant}_{joints}_{int(rate)}_{in_qos.replace(':', '')}"
    stats_path = os.path.join(tmp, f"stats_{tag}.json")
    node_log = open(os.path.join(tmp, f"node_{tag}.log"), "w")
    if node_cmd is None:
        node_cmd = me + ["--role", "node", "--variant", variant, "--joints", str(joints),
                         "--in-qos", in_qos, "--stats", stats_path]
    node = subprocess.Popen(node_cmd,
                            cwd=ROOT, env=env, stdout=node_log, stderr=subprocess.STDOUT)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    drv = rclpy.create_node("io_listener", context=ctx)
    cap = int(rate * duration) + 1000
    stamp_ns = np.zeros(cap, dtype=np.int64)
    recv_ns = np.zeros(cap, dtype=np.int64)
    count = [0]
    unpack = struct.Struct("<iI").unpack_from

    def on_out(payload, info):
        i = count[0]
        if i < cap:
            sec, nsec = unpack(payload, 4)
            stamp_ns[i] = sec * 1_000_000_000 + nsec
            recv_ns[i] = info.get("received_timestamp") or time.time_ns()
        count[0] = i + 1
    drv.create_subscription(JointState, OUT_TOPIC, message_info_callback(on_out),
                            make_qos("rel:1000"), raw=True)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(drv)

    def spin_until(cond, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not cond():
            ex.spin_once(timeout_sec=0.05)
        return cond()

    row = {"variant": variant, "joints": joints, "rate": rate, "in_qos": in_qos,
           "load": os.getloadavg()[0]}
    pub = None
    try:
        if not spin_until(lambda: drv.count_publishers(OUT_TOPIC) > 0 or node.poll() is not None,
                          startup_s) \
                or node.poll() is not None:
            raise RuntimeError(f"{variant} node did not come up; see {node_log.name}")
        sent_file = os.path.join(tmp, f"sent_{tag}.npy")
        pub = subprocess.Popen(me + ["--role", "publisher", "--stamps", stamps, "--joints", str(joints),
                                     "--rate", str(rate),
                                     "--duration", str(duration), "--out", sent_file],
                               cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)
        if not pub.stdout.readline():   # {"start": true} when publishing starts
            raise RuntimeError("publisher failed to start")
        count[0] = 0
        cpu0, t0 = _cpu_s(node.pid), time.monotonic()
        spin_until(lambda: pub.poll() is not None, duration + 60)
        cpu1, t1 = _cpu_s(node.pid), time.monotonic()
        info = json.loads(pub.stdout.read().strip().splitlines()[-1])
        spin_until(lambda: count[0] >= info["sent"], 2.0)   # stragglers
        sent = np.load(sent_file)
        n = min(count[0], cap)
        got = np.unique(stamp_ns[:n])
        matched = np.isin(sent, got)
        lat_ms = np.sort((recv_ns[:n] - stamp_ns[:n]) * 1e-6)
        row.update(sent=len(sent), sent_rate=len(sent) / info["elapsed"], received=n,
                   lost=int(len(sent) - matched.sum()), extra=int(n - matched.sum()),
                   cpu_s=cpu1 - cpu0, cpu_us=1e6 * (cpu1 - cpu0) / len(sent),
                   cpu_pct=100.0 * (cpu1 - cpu0) / (t1 - t0),
                   lat_p50=float(np.percentile(lat_ms, 50)) if n else float("nan"),
                   lat_p99=float(np.percentile(lat_ms, 99)) if n else float("nan"))
    finally:
        if pub is not None:
            _stop(pub)
        _stop(node)
        node_log.close()
        drv.destroy_node()
        rclpy.try_shutdown(context=ctx)
    if os.path.exists(stats_path):
        row["node"] = json.loads(Path(stats_path).read_text())
    return row


# ---------------------------------------------------------------------- tables
def _med(values):
    values = [v for v in values if v == v]
    return float(np.median(values)) if values else float("nan")


def live_table(rows: list[dict], variants: list[str]) -> str:
    """One table per joint count: medians over the rounds, ratios to the round's echo."""
    out = []
    for joints in sorted({r["joints"] for r in rows}, reverse=True):
        rs = [r for r in rows if r["joints"] == joints and "error" not in r]
        rounds = sorted({r["round"] for r in rs})
        loads = [next((r["load"] for r in rs if r["round"] == k), float("nan")) for k in rounds]
        rate = rs[0]["rate"] if rs else float("nan")
        out += [f"{joints} joint(s) at {rate:g} Hz, {len(rounds)} round(s), load average (1 min) at "
                f"each round's start: {', '.join(f'{x:.1f}' for x in loads)}", "",
                "| variant | CPU per message (us) | CPU (% of a core) | CPU / echo | latency p50 (ms) | "
                "p50 / echo | latency p99 (ms) | lost / sent | messages per callback | fast decodes |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        echo = {r["round"]: r for r in rs if r["variant"] == "echo"}
        for v in variants:
            vr = [r for r in rs if r["variant"] == v]
            if not vr:
                continue
            cpu_ratio = [r["cpu_us"] / echo[r["round"]]["cpu_us"] for r in vr if r["round"] in echo]
            lat_ratio = [r["lat_p50"] / echo[r["round"]]["lat_p50"] for r in vr if r["round"] in echo]
            node = [r.get("node", {}) for r in vr]
            per_cb = [s["messages"] / s["callbacks"] for s in node if s.get("callbacks")]
            fast = [s["fast"] / s["messages"] for s in node if s.get("messages") and "fast" in s]
            lost, sent = sum(r["lost"] for r in vr), sum(r["sent"] for r in vr)
            out.append(
                f"| {v} | {_med([r['cpu_us'] for r in vr]):.1f} | {_med([r['cpu_pct'] for r in vr]):.0f} | "
                f"{_med(cpu_ratio):.2f} | {_med([r['lat_p50'] for r in vr]):.3f} | {_med(lat_ratio):.2f} | "
                f"{_med([r['lat_p99'] for r in vr]):.2f} | {lost} / {sent} | "
                + (f"{_med(per_cb):.3f}" if per_cb else "-") + " | "
                + (f"{100 * _med(fast):.1f} %" if fast else "-") + " |")
        out.append("")
    return "\n".join(out)


def qos_table(rows: list[dict]) -> str:
    out = ["| variant | rate (Hz) | node input QoS | sent rate (Hz) | lost / sent | CPU (% of a core) | "
           "latency p50 / p99 (ms) | load |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            out.append(f"| {r['variant']} | {r['rate']:g} | {r['in_qos']} | failed: {r['error']} |")
            continue
        out.append(f"| {r['variant']} | {r['rate']:g} | {r['in_qos']} | {r['sent_rate']:.0f} | "
                   f"{r['lost']} / {r['sent']} ({100 * r['lost'] / max(r['sent'], 1):.2f} %) | "
                   f"{r['cpu_pct']:.0f} | {r['lat_p50']:.2f} / {r['lat_p99']:.2f} | {r['load']:.1f} |")
    return "\n".join(out)


# ----------------------------------------------------------------------- micro
def micro(repeats: int = 5, n: int = 5000) -> str:
    """In-process cost (us per message, best of ``repeats``) of each way in and out."""
    import array
    import itertools
    import timeit

    from rclpy.serialization import deserialize_message, serialize_message
    from rosbags.typesys import Stores, get_typestore
    from sensor_msgs.msg import JointState

    from fto_ros.core.cdr import JointStateDecoder, JointStateEncoder

    ts = get_typestore(Stores.ROS2_JAZZY)
    lines = [f"In-process, us per message, best of {repeats} x {n}; load average (1 min) "
             f"{os.getloadavg()[0]:.1f}", "",
             "| joints | in: rclpy deserialize_message | in: rosbags deserialise | in: numpy decoder | "
             "in: numpy block of 10 (per msg) | out: assign + rclpy serialise | "
             "out: numpy encoder |", "|---|---|---|---|---|---|---|"]
    for joints in (7, 1):
        names = joint_names(joints)
        vals = np.arange(joints, dtype=np.float64)
        payloads = []   # a stream: the values and stamps change, the layout repeats
        for k in range(100):
            msg = JointState(name=names, position=(vals + k).tolist(), velocity=(vals - k).tolist(),
                             effort=(vals * k).tolist())
            msg.header.stamp.sec = k
            payloads.append(serialize_message(msg))
        stream = itertools.cycle(payloads)
        dec = JointStateDecoder()
        enc = JointStateEncoder(names)
        out = JointState(name=names)

        def assign_serialise():
            out.header.stamp.sec, out.header.stamp.nanosec = 1, 2
            out.position = array.array("d", vals.tobytes())
            out.velocity = array.array("d", vals.tobytes())
            out.effort = array.array("d", vals.tobytes())
            return serialize_message(out)
        blocks = itertools.cycle([payloads[i:i + 10] for i in range(0, 100, 10)])
        cases = [
            (lambda: deserialize_message(next(stream), JointState), 1),
            (lambda: ts.deserialize_cdr(next(stream), "sensor_msgs/msg/JointState"), 1),
            (lambda: dec.decode(next(stream)), 1),
            (lambda: dec.decode_block(next(blocks)), 10),
            (assign_serialise, 1),
            (lambda: enc.encode(1, 2, vals, vals, vals), 1),
        ]
        cells = [f"{1e6 * min(timeit.repeat(f, number=n, repeat=repeats)) / n / per:.2f}"
                 for f, per in cases]
        lines.append(f"| {joints} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ------------------------------------------------------------------------ main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--joints", type=int, nargs="+", default=[7, 1])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--rates", type=float, nargs="+", default=[1000.0, 5000.0], help="--qos rates")
    ap.add_argument("--duration", type=float, default=10.0, help="publishing time per run (s)")
    ap.add_argument("--repeats", type=int, default=3, help="rounds of every variant")
    ap.add_argument("--qos", action="store_true", help="the QoS study instead")
    ap.add_argument("--micro", action="store_true", help="in-process costs instead")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "228")))
    ap.add_argument("--json", help="also write the rows to this JSON file")
    ap.add_argument("--role", choices=("driver", "node", "publisher"), default="driver",
                    help=argparse.SUPPRESS)
    ap.add_argument("--variant", choices=list(VARIANTS), help=argparse.SUPPRESS)
    ap.add_argument("--in-qos", default="be:100", help=argparse.SUPPRESS)
    ap.add_argument("--stats", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--stamps", choices=("send", "nominal"), default="send", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.role == "node":
        return run_node(args.variant, args.joints[0], args.in_qos, args.stats)
    if args.role == "publisher":
        return run_publisher(args.joints[0], args.rate, args.duration, args.out, args.stamps)
    if args.micro:
        print(micro())
        return 0

    rows: list[dict] = []

    def run(round_, variant, joints, rate, qos):
        print(f"# round {round_}: {variant}, {joints} joint(s), {rate:g} Hz, in {qos} "
              f"(load {os.getloadavg()[0]:.1f}) ...", file=sys.stderr, flush=True)
        try:
            row = measure(variant, joints, rate, args.duration, args.domain, tmp, qos)
        except Exception as exc:  # keep going: one failed run must not hide the rest
            row = {"variant": variant, "joints": joints, "rate": rate, "in_qos": qos,
                   "error": str(exc), "load": os.getloadavg()[0]}
        row["round"] = round_
        rows.append(row)
        if "error" not in row:
            print(f"#   cpu {row['cpu_us']:.1f} us/msg ({row['cpu_pct']:.0f} %), p50 "
                  f"{row['lat_p50']:.3f} ms, lost {row['lost']}/{row['sent']}", file=sys.stderr)

    with tempfile.TemporaryDirectory(prefix="fto_nodeio_") as tmp:
        if args.qos:
            for rate in args.rates:
                for qos in QOS_STUDY:
                    for variant in ("echo", "raw_events"):
                        run(0, variant, args.joints[0], rate, qos)
            print(f"QoS study, {args.joints[0]} joint(s), {args.duration:g} s per run, "
                  f"{os.cpu_count()} CPU(s); the publisher reliable keep last 100")
            print(qos_table(rows))
        else:
            for round_ in range(args.repeats):
                for joints in args.joints:
                    for variant in args.variants:
                        run(round_, variant, joints, args.rate, "be:100")
            print(f"Node I/O, {args.duration:g} s per run, {os.cpu_count()} CPU(s), "
                  f"Python {sys.version.split()[0]}")
            print(live_table(rows, args.variants))
            failed = [r for r in rows if "error" in r]
            for r in failed:
                print(f"failed: round {r['round']} {r['variant']} {r['joints']}: {r['error']}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
