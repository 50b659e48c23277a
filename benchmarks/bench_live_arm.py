#!/usr/bin/env python3
"""A whole arm in one node at 1 kHz (issue 20): the observer node vs an rclpy echo node.

    python benchmarks/bench_live_arm.py [--kinds ...] [--rate 1000] [--duration 10]
                                        [--repeats 3] [--domain 220]
    python benchmarks/bench_live_arm.py --micro        # where the time goes per message

Live runs (bench_node_io.py's publisher and listener): a publisher process sends one
sensor_msgs/JointState at ``--rate`` for ``--duration`` s (header stamp = its wall clock
at sending); the node under test takes each and publishes one JointState with its stamp
(the observer: ``~/estimated_joint_states`` remapped to the listener's topic); the
listener (this process) records the DDS receipt times.  Per run: the node's CPU (user +
system, /proc) per message sent, latency p50 (receipt - stamp), messages lost.  In every
round the kinds run one after another on the same stream, the echo first, so each ratio
is taken within one round; the tables give the median of the per-round ratios and the
load average at each round's start.  Kinds:

- ``echo`` (7 joints) / ``echo_1`` (1 joint): SingleThreadedExecutor, the rclpy message
  republished (the issue's reference);
- ``arm7_hosm`` / ``arm7_luenberger``: the observer node in per-joint mode on the 7 joints
  (config/arm7_plant.yaml + config/arm7_<tuning>.yaml: one observer per joint, all in one
  runner call per message; raw intake, raw publisher, the EventsExecutor: node.executor
  auto);
- ``arm7_hosm_single``: the same on the SingleThreadedExecutor (what the executor buys);
- ``dc_motor``: the single-observer node of config/dc_motor_luenberger.yaml on a
  one-joint JointState (joint_states source, rclpy messages, single executor: the path of
  every non-joints node);
- ``dc_motor_joints``: the same model as a one-joint arm (joints: [joint_a1]).

``--micro``: the per-message stages of the per-joint node in one process (no DDS, no
executor), for 7 joints, through the code the node runs (nodes/observer_core.py): the
source's rows of one payload (runner/sources/joints.py: the numpy decode and the intake
by name together; the decode alone, core/cdr.py's JointStateDecoder, is shown beside it
and is part of that figure), the runner call (``process_rows``) and the output plan's
``estimated_joint_states`` message (runner/sources/plan.py ``encode_one``: the output
fields and the CDR encoding together, which were two columns before the plan did both).
The sum is rows + runner + output.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_node_io as io  # noqa: E402
from fto_ros.runner import loop as L  # noqa: E402

CONFIG = ROOT / "config"
OBSERVER = [sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args"]
REMAP = ["-r", "~/estimated_joint_states:=/" + io.OUT_TOPIC, "-p", "topics.joint_states:=/" + io.IN_TOPIC,
         "-p", "diagnostics.expected_rate:=0.0"]


def _files(*names) -> list[str]:
    out = []
    for n in names:
        out += ["--params-file", str(CONFIG / f"{n}.yaml")]
    return out


#: kind -> (joints, node command or None for bench_node_io's echo)
KINDS = {
    "echo": (7, None),
    "arm7_hosm": (7, OBSERVER + _files("arm7_plant", "arm7_hosm") + REMAP),
    "arm7_luenberger": (7, OBSERVER + _files("arm7_plant", "arm7_luenberger") + REMAP),
    "arm7_hosm_single": (7, OBSERVER + _files("arm7_plant", "arm7_hosm") + REMAP
                         + ["-p", "node.executor:=single"]),
    "echo_1": (1, None),
    "dc_motor": (1, OBSERVER + _files("dc_motor_plant", "dc_motor_luenberger") + REMAP + [
        "-p", "source:=joint_states", "-p", "joint_states.output_joints:=[joint_a1]",
        "-p", "joint_states.input_joints:=[joint_a1]",
        "-p", "estimated_joint_states.joint_names:=[joint_a1]"]),
    "dc_motor_joints": (1, OBSERVER + _files("dc_motor_plant", "dc_motor_luenberger") + REMAP + [
        "-p", "source:=joint_states", "-p", "joints:=[joint_a1]"]),
}


def micro(n: int = 5000, repeats: int = 5) -> str:
    """In-process cost of each stage of the per-joint node's message path (7 joints)."""
    from fto_ros.core.cdr import JointStateDecoder, JointStateEncoder
    from fto_ros.runner import Runner
    from fto_ros.runner.params_file import load_params_files
    from fto_ros.runner.sources import make_source

    lines = ["| tuning | decode alone (us) | source rows: decode + intake (us) | runner (us) | "
             "output: fields + CDR (us) | sum (us) |", "|---|---|---|---|---|---|"]
    names = io.joint_names(7)
    enc = JointStateEncoder(names)
    for tuning in ("hosm", "luenberger"):
        runner = Runner(load_params_files([CONFIG / "arm7_plant.yaml", CONFIG / f"arm7_{tuning}.yaml"],
                                          "observer_node"))
        source = make_source(runner)
        plan = source.plan
        out = next(i for i, spec in enumerate(plan.specs) if spec.topic == "estimated_joint_states")
        dec = JointStateDecoder()
        t0 = int(time.time())
        best = {}
        for r in range(repeats):
            # each repeat on a timeline of its own (stamps 10 s on: the runner restarts),
            # received at its stamp (the node's clock check passes)
            stamps = [(t0 + 10 * r) * 10**9 + k * 10**6 for k in range(n)]
            payloads = [enc.encode(ns // 10**9, ns % 10**9, 0.1 * np.sin(k * 1e-3 + np.arange(7)),
                                   np.zeros(7), np.ones(7)) for k, ns in enumerate(stamps)]
            times = dict.fromkeys(("decode", "rows", "runner", "output"), 0.0)
            pc = time.perf_counter
            for ns, p in zip(stamps, payloads):
                recv, clock = np.array([ns]), np.array([ns * 1e-9])
                a = pc()
                dec.decode(p)
                b = pc()
                rows = source.rows("joint_states", (p,), recv, recv, clock)
                c = pc()
                status, x, ui, conv = runner.process_rows(rows.kind, rows.t, rows.values, rows.pre)
                d = pc()
                s = int(rows.srow[0])
                plan.encode_one(out, ns // 10**9, ns % 10**9, x[s], ui[s], conv[s],
                                status[s] == L.OUTPUT)
                e = pc()
                for key, dt in zip(times, (b - a, c - b, d - c, e - d)):
                    times[key] += dt
            for key, v in times.items():
                best[key] = min(best.get(key, np.inf), 1e6 * v / n)
        if runner.accepted == 0:
            raise RuntimeError(f"arm7_{tuning}: no sample accepted; the micro measured nothing")
        total = best["rows"] + best["runner"] + best["output"]
        lines.append(f"| {tuning} | " + " | ".join(f"{best[k]:.1f}" for k in best) + f" | {total:.1f} |")
    return "\n".join(lines)


def table(rows: list[dict], kinds: list[str]) -> str:
    out = []
    for joints, ref in ((7, "echo"), (1, "echo_1")):
        rs = [r for r in rows if r["joints"] == joints and "error" not in r]
        if not rs:
            continue
        rounds = sorted({r["round"] for r in rs})
        loads = [next((r["load"] for r in rs if r["round"] == k), float("nan")) for k in rounds]
        out += [f"{joints} joint(s) at {rs[0]['rate']:g} Hz, {len(rounds)} round(s), load average "
                f"(1 min) at each round's start: {', '.join(f'{x:.1f}' for x in loads)}", "",
                "| node | CPU per message (us) | CPU (% of a core) | CPU / echo | latency p50 (ms) | "
                "p50 / echo | latency p99 (ms) | lost / sent | echo lost in the same rounds |",
                "|---|---|---|---|---|---|---|---|---|"]
        echo = {r["round"]: r for r in rs if r["variant"] == ref}
        for kind in kinds:
            vr = [r for r in rs if r["variant"] == kind]
            if not vr:
                continue
            cpu = [r["cpu_us"] / echo[r["round"]]["cpu_us"] for r in vr if r["round"] in echo]
            lat = [r["lat_p50"] / echo[r["round"]]["lat_p50"] for r in vr if r["round"] in echo]
            e_lost = sum(echo[r["round"]]["lost"] for r in vr if r["round"] in echo)
            out.append(f"| {kind} | {io._med([r['cpu_us'] for r in vr]):.1f} | "
                       f"{io._med([r['cpu_pct'] for r in vr]):.0f} | {io._med(cpu):.2f} | "
                       f"{io._med([r['lat_p50'] for r in vr]):.3f} | {io._med(lat):.2f} | "
                       f"{io._med([r['lat_p99'] for r in vr]):.2f} | {sum(r['lost'] for r in vr)} / "
                       f"{sum(r['sent'] for r in vr)} | {e_lost} |")
        out.append("")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=list(KINDS))
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--duration", type=float, default=10.0, help="publishing time per run (s)")
    ap.add_argument("--repeats", type=int, default=3, help="rounds of every kind")
    ap.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "220")))
    ap.add_argument("--stamps", choices=("send", "nominal"), default="send",
                    help="header stamps: the wall clock at sending (jittered steps), or the "
                    "publisher's start + k / rate (a fixed-rate control loop's time)")
    ap.add_argument("--micro", action="store_true", help="the in-process stages instead")
    ap.add_argument("--json", help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.micro:
        print(micro())
        return 0
    # the echo of each joint count first in every round
    kinds = sorted(args.kinds, key=lambda k: (-KINDS[k][0], k not in ("echo", "echo_1")))
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="fto_arm_") as tmp:
        for round_ in range(args.repeats):
            for kind in kinds:
                joints, cmd = KINDS[kind]
                print(f"# round {round_}: {kind} (load {os.getloadavg()[0]:.1f}) ...",
                      file=sys.stderr, flush=True)
                try:
                    row = io.measure("echo" if cmd is None else kind, joints, args.rate,
                                     args.duration, args.domain, tmp, node_cmd=cmd, startup_s=300.0,
                                     stamps=args.stamps)
                except Exception as exc:  # keep going: one failed run must not hide the rest
                    row = {"variant": kind, "joints": joints, "error": str(exc),
                           "load": os.getloadavg()[0]}
                row["variant"], row["round"] = kind, round_
                rows.append(row)
                if "error" in row:
                    print(f"#   failed: {row['error']}", file=sys.stderr)
                else:
                    print(f"#   cpu {row['cpu_us']:.1f} us/msg ({row['cpu_pct']:.0f} %), p50 "
                          f"{row['lat_p50']:.3f} ms, lost {row['lost']}/{row['sent']}", file=sys.stderr)
    print(f"Live arm, {args.duration:g} s per run, stamps '{args.stamps}', {os.cpu_count()} CPU(s), "
          f"Python {sys.version.split()[0]}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(table(rows, kinds))
    for r in rows:
        if "error" in r:
            print(f"failed: round {r['round']} {r['variant']}: {r['error']}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
