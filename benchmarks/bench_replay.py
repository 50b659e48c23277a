#!/usr/bin/env python3
"""Replay speed before and after a change, measured in one run, split into reading, the
runner and writing per sample.

    python benchmarks/bench_replay.py [--before REV] [--repeat R]

Each configuration (``bags/dc_motor_nominal`` with ``config/dc_motor_plant.yaml`` plus
``config/dc_motor_luenberger.yaml``, and plus ``config/dc_motor_single_delay.yaml``; the
7-joint arm ``bags/arm7_contact_link6``, 10 s at 1 kHz, with ``config/arm7_plant.yaml``
plus ``config/arm7_hosm.yaml`` and plus ``config/arm7_luenberger.yaml``: the per-joint
mode, which code before the per-joint replay cannot run, shown as such) is replayed the way ``fto-replay`` does it (``fto_ros.replay.replay``, the output bag and
metrics written, no figure), in a fresh process per run, by the code of this work tree
("after") and by the code of git revision REV ("before", default ``main``: exported with
``git archive`` into a temp folder and put first on ``PYTHONPATH``).  The runs alternate,
so a change of load hits both alike; the best of R per side counts.

The split is the replay's own ``timing_s`` (metrics.json): read = opening, reading and
decoding the bag, ordering the events and making the runner's rows of them; runner = the
runner calls (``Runner.process_block`` once per window; before the block path,
``set_input`` / ``process`` per sample and the Python loop around them); write = encoding
and writing the output bag, closing it.  Per sample = per message of the bag's measurement
(or JointState) topic, 1 kHz.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DC, ARM = "bags/dc_motor_nominal", "bags/arm7_contact_link6"
CONFIGS = {"dc_motor luenberger": (DC, ["config/dc_motor_plant.yaml", "config/dc_motor_luenberger.yaml"]),
           "dc_motor single_delay": (DC, ["config/dc_motor_plant.yaml",
                                          "config/dc_motor_single_delay.yaml"]),
           "arm7 hosm (7 joints)": (ARM, ["config/arm7_plant.yaml", "config/arm7_hosm.yaml"]),
           "arm7 luenberger (7 joints)": (ARM, ["config/arm7_plant.yaml",
                                                 "config/arm7_luenberger.yaml"])}

_CHILD = r"""
import json, sys, tempfile, os
import fto_ros
from fto_ros.replay import replay
bag, out = sys.argv[1], os.path.join(tempfile.mkdtemp(), "out")
m = replay(bag, sys.argv[2:], out, plot=False, progress=False)
print(json.dumps({"code": fto_ros.__file__, "timing": m["timing_s"], "samples": m["sample_count"],
                  "duration": m["bag_duration_s"], "metrics": {k: m[k] for k in (
                      "samples_accepted", "errors", "convergence_time_s", "rejected_by_reason")}}))
"""


def _run(code: str, bag: str, params: list[str]) -> dict | None:
    """One replay in a fresh process by the fto_ros package under ``code`` (run from that
    folder: ``python -c`` puts the working directory first on sys.path)."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONPATH=code)
    res = subprocess.run([sys.executable, "-c", _CHILD, str(ROOT / bag),
                          *(str(ROOT / p) for p in params)], cwd=code, env=env,
                         capture_output=True, text=True)
    if res.returncode:
        return None                      # this code cannot replay it
    out = json.loads(res.stdout.strip().splitlines()[-1])
    if out.pop("code") != str(Path(code) / "fto_ros" / "__init__.py"):
        raise RuntimeError(f"the replay did not run the code under {code}")
    return out


def _split(r: dict) -> dict:
    t = r["timing"]
    return {"read": t["read_decode"] + t["order_events"],
            "runner": t["runner"] + t.get("sample_loop", 0.0),
            "write": t["serialize_write"] + t["close_output"], "total": t["replay_total"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default="main", help="git revision to compare with")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--bag", default="bags/dc_motor_nominal")
    args = ap.parse_args(argv)
    rev = subprocess.run(["git", "rev-parse", "--short", args.before], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout.strip()
    here = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout.strip()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-replay-") as tmp:
        archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        print(f"load average before: {os.getloadavg()[0]:.2f}; before = {args.before} "
              f"({rev}), after = this work tree (HEAD {here}, with its changes)")
        for name, (bag, params) in CONFIGS.items():
            best: dict[str, dict | None] = {"before": None, "after": None}
            for _ in range(args.repeat):
                for side, path in (("before", tmp), ("after", str(ROOT))):
                    r = _run(path, bag, params)
                    if r is not None and (best[side] is None or r["timing"]["replay_total"] <
                                          best[side]["timing"]["replay_total"]):
                        best[side] = r
            same = best["before"] is None or best["before"]["metrics"] == best["after"]["metrics"]
            for side in ("before", "after"):
                r = best[side]
                if r is None:
                    rows.append((name, side, None, None, None, same))
                    continue
                s = _split(r)
                per = {k: v / r["samples"] * 1e6 for k, v in s.items()}
                rows.append((name, side, r["duration"] / s["total"], per, s["total"], same))
    print(f"\nbest of {args.repeat}; us per sample (message)\n")
    print("| config | code | x real time | read | runner | write | total | same metrics |")
    print("|---|---|---|---|---|---|---|---|")
    for name, side, speed, per, total, same in rows:
        if speed is None:
            print(f"| {name} | {side} | cannot replay it | | | | | |")
            continue
        cells = " | ".join(f"{per[k]:.1f}" for k in ("read", "runner", "write", "total"))
        print(f"| {name} | {side} | {speed:.1f}x | {cells} | {'yes' if same else 'NO'} |")
    for name in CONFIGS:
        b, a = [r for r in rows if r[0] == name]
        if b[2] is not None:
            print(f"{name}: whole replay {b[4] / a[4]:.2f}x faster; runner "
                  f"{b[3]['runner'] / a[3]['runner']:.1f}x, read {b[3]['read'] / a[3]['read']:.1f}x")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if all(r[5] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
