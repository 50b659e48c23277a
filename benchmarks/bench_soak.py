#!/usr/bin/env python3
"""Soak: the live node for N minutes at 1 kHz with 1 % junk; memory growth and the fraction
of time the estimate is within its noise level.

    python benchmarks/bench_soak.py [--minutes 10] [--junk 0.01] [--config FILE]

1. ``fto-simulate dc_motor`` records N minutes of the noisy DC motor (sigma 1e-3 on q, the
   model uncertainty on, as bags/dc_motor_noisy) into a temporary bag (cached by its
   settings under the system temp dir).
2. The noise level: the same bag replayed offline (``fto-replay``, no junk): per state,
   the largest |error| after the settle time.  That is what the noise alone costs.
3. Live: the observer node (``--config``, default config/dc_motor_single_delay.yaml) with
   ``use_sim_time``, driven by ``fto-play --clock --junk F`` (input and measured output,
   plus junk after a fraction F of them); this script records ``estimated_joint_states``
   (stamped with the sample time) and samples the node's VmRSS every 5 s.
4. Reported: memory growth from the end of the first minute (start-up done) to the end,
   the fraction of estimates after the settle time within the noise level (every state),
   and the node's rejection counts.

Every process runs with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a domain id of its own.
Prints a markdown table.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def sh(cmd, env=None, **kw):
    return subprocess.run([str(c) for c in cmd], cwd=ROOT, env=env, check=True, **kw)


def make_bag(minutes: float) -> Path:
    key = hashlib.sha1(f"dc_motor noisy {minutes}".encode()).hexdigest()[:10]
    bag = Path(tempfile.gettempdir()) / f"fto_soak_{key}"
    if not (bag / "metadata.yaml").exists():
        print(f"simulating {minutes} min of the DC motor into {bag} ...", file=sys.stderr)
        sh(["fto-simulate", "dc_motor", "--duration", minutes * 60, "--noise", "0.001",
            "--uncertainty", "--seed", "3", "--out", bag, "--overwrite"])
    return bag


def noise_level(bag: Path, config: Path, out: Path) -> tuple[np.ndarray, dict]:
    from fto_ros.runner.plant_files import params_files
    sh(["fto-replay", bag, *(a for p in params_files(config) for a in ("--params", p)),
        "--out", out, "--overwrite", "--no-progress"], stdout=subprocess.DEVNULL)
    m = json.loads((out / "metrics.json").read_text())
    per = m["errors"]["per_state"]
    return np.array([per[n]["max_abs_after_settle"] for n in m["state_names"]]), m


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def truth_by_ns(bag: Path) -> dict[int, np.ndarray]:
    from fto_ros.bag import BagReader
    with BagReader(bag) as b:
        return {t: np.asarray(m.data, float) for _, t, m in b.messages(["/dc_motor/true_state"])}


def live(bag: Path, config: Path, junk: float, minutes: float, tmp: Path, domain: int):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID=str(domain),
               ROS_LOG_DIR=str(tmp / "roslog"))
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    from fto_ros.runner.plant_files import params_files
    files = [a for p in params_files(config) for a in ("--params-file", str(p))]
    node = subprocess.Popen([sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args",
                             *files, "-p", "use_sim_time:=true"],
                            cwd=ROOT, env=env, stdout=open(tmp / "node.log", "w"),
                            stderr=subprocess.STDOUT)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    drv = rclpy.create_node("soak_driver", context=ctx)
    est: dict[int, np.ndarray] = {}
    last_status: dict = {}
    lock = threading.Lock()

    def on_est(m):
        with lock:
            est[m.header.stamp.sec * 10**9 + m.header.stamp.nanosec] = np.array(
                [m.position[0], m.velocity[0], m.effort[0]])

    def on_diag(msg):
        for s in msg.status:
            if s.name.endswith(": observer"):
                with lock:
                    last_status.clear()
                    last_status.update({kv.key: kv.value for kv in s.values}, _level=s.level[0],
                                       _message=s.message)
    drv.create_subscription(JointState, "/observer_node/estimated_joint_states", on_est,
                            QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE))
    drv.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(drv)
    threading.Thread(target=ex.spin, daemon=True).start()
    time.sleep(3.0)
    player = subprocess.Popen(["fto-play", str(bag), "--clock", "--topics", "/dc_motor/input",
                               "/dc_motor/measured_output", "--junk", str(junk), "--seed", "1",
                               "--wait-for-subscribers", "20"],
                              cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=open(tmp / "play.log", "w"))
    rss = []
    t0 = time.monotonic()
    while player.poll() is None:
        rss.append((time.monotonic() - t0, rss_kb(node.pid)))
        time.sleep(5.0)
    rss.append((time.monotonic() - t0, rss_kb(node.pid)))
    time.sleep(3.0)
    node.send_signal(2)
    node.wait(20)
    with lock:
        got, status = dict(est), dict(last_status)
    ex.shutdown()
    rclpy.try_shutdown(context=ctx)
    return got, status, rss, (tmp / "play.log").read_text()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--junk", type=float, default=0.01)
    ap.add_argument("--config", type=Path, default=ROOT / "config" / "dc_motor_single_delay.yaml")
    args = ap.parse_args()
    bag = make_bag(args.minutes)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        level, ref = noise_level(bag, args.config, tmp / "reference")
        settle = ref["settle_time_s"]
        est, status, rss, play_log = live(bag, args.config, args.junk, args.minutes, tmp,
                                          domain=1 + (os.getpid() + 77) % 100)
    truth = truth_by_ns(bag)
    t_start = min(truth)
    within = n = 0
    for ns, x in est.items():
        if ns - t_start < settle * 1e9 or ns not in truth:
            continue
        n += 1
        within += bool(np.all(np.abs(x - truth[ns]) <= level))
    after_1min = [kb for t, kb in rss if t >= 60.0] or [rss[-1][1]]
    growth_mb = (rss[-1][1] - after_1min[0]) / 1024
    junk_line = next((line for line in play_log.splitlines() if "junk sent" in line), "")
    rej = {k: v for k, v in status.items() if k.startswith(("rejected:", "restarts:"))}
    print(f"| minutes | junk | estimates after settle | within noise level | RSS start / end (MB) "
          f"| growth after 1 min (MB) |")
    print("|---|---|---|---|---|---|")
    print(f"| {args.minutes:g} | {args.junk:.0%} | {n} | {within / max(n, 1):.4%} | "
          f"{rss[0][1] / 1024:.1f} / {rss[-1][1] / 1024:.1f} | {growth_mb:.2f} |")
    print(f"\nnoise level (offline replay, no junk, max |error| after {settle:g} s): "
          + ", ".join(f"{v:.3g}" for v in level))
    print(f"node: accepted {status.get('samples accepted')}, rejected {status.get('samples rejected')}; "
          + ", ".join(f"{k} {v}" for k, v in sorted(rej.items())))
    print(f"player: {junk_line.strip()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
