#!/usr/bin/env python3
"""Replay speed before and after a change, measured in one run, split into reading, the
runner and writing per sample.

    python benchmarks/bench_replay.py [--before REV] [--repeat R] [--bag BAG]

Each configuration (``bags/dc_motor_nominal`` with ``config/dc_motor_plant.yaml`` plus
``config/dc_motor_luenberger.yaml``, and plus ``config/dc_motor_single_delay.yaml``) is
replayed the way ``fto-replay`` does it (``fto_ros.replay.replay``, the output bag and
metrics written, no figure), in a fresh process per run, by the code of this work tree
("after") and by the code of git revision REV ("before", default ``main``: exported with
``git archive`` into a temp folder and put first on ``PYTHONPATH``).  The runs alternate,
so a change of load hits both alike; the best of R per side counts.

The split is the replay's own ``timing_s`` (metrics.json): read = opening, reading and
decoding the bag and ordering the events; runner = inside ``Runner.set_input`` /
``Runner.process``; loop = the per-sample calls around the runner (after only: before,
it is part of write); write = encoding and writing the output bag, closing it.  Per
sample = per measurement sample of the bag (1 kHz).
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
CONFIGS = {"luenberger": ["config/dc_motor_plant.yaml", "config/dc_motor_luenberger.yaml"],
           "single_delay": ["config/dc_motor_plant.yaml", "config/dc_motor_single_delay.yaml"]}

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


def _run(code: str, bag: str, params: list[str]) -> dict:
    """One replay in a fresh process by the fto_ros package under ``code`` (run from that
    folder: ``python -c`` puts the working directory first on sys.path)."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONPATH=code)
    res = subprocess.run([sys.executable, "-c", _CHILD, str(ROOT / bag),
                          *(str(ROOT / p) for p in params)], cwd=code, env=env,
                         capture_output=True, text=True, check=True)
    out = json.loads(res.stdout.strip().splitlines()[-1])
    if out.pop("code") != str(Path(code) / "fto_ros" / "__init__.py"):
        raise RuntimeError(f"the replay did not run the code under {code}")
    return out


def _split(r: dict) -> dict:
    t = r["timing"]
    return {"read": t["read_decode"] + t["order_events"], "runner": t["runner"],
            "loop": t.get("sample_loop"), "write": t["serialize_write"] + t["close_output"],
            "total": t["replay_total"]}


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
    with tempfile.TemporaryDirectory(prefix="bench-replay-") as tmp:
        archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        print(f"load average before: {os.getloadavg()[0]:.2f}; before = {args.before} "
              f"({rev}), after = this work tree (HEAD {here}, with its changes)")
        rows = []
        for name, params in CONFIGS.items():
            best: dict[str, dict | None] = {"before": None, "after": None}
            same = True
            for _ in range(args.repeat):
                for side, path in (("before", tmp), ("after", str(ROOT))):
                    r = _run(path, args.bag, params)
                    if best[side] is None or r["timing"]["replay_total"] < \
                            best[side]["timing"]["replay_total"]:
                        best[side] = r
            same = best["before"]["metrics"] == best["after"]["metrics"]
            for side in ("before", "after"):
                r = best[side]
                s = _split(r)
                per = {k: (None if v is None else v / r["samples"] * 1e6) for k, v in s.items()}
                rows.append((name, side, r["duration"] / s["total"], per, s["total"], same))
    print(f"\n{args.bag} (1 kHz), best of {args.repeat}; us per sample\n")
    print("| config | code | x real time | read | runner | loop | write | total | "
          "same metrics |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, side, speed, per, total, same in rows:
        cells = " | ".join("in write" if per[k] is None else f"{per[k]:.1f}"
                           for k in ("read", "runner", "loop", "write", "total"))
        print(f"| {name} | {side} | {speed:.1f}x | {cells} | {'yes' if same else 'NO'} |")
    for name in CONFIGS:
        b, a = [r for r in rows if r[0] == name]
        print(f"{name}: whole replay {b[4] / a[4]:.2f}x faster; read "
              f"{b[3]['read'] / a[3]['read']:.1f}x, write (incl. the loop before) "
              f"{(b[3]['write']) / (a[3]['write'] + a[3]['loop']):.1f}x")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if all(r[5] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
