#!/usr/bin/env python3
"""Parallel speed-up of the main job and of fto-sweep, and the Dask path against local workers.

    python benchmarks/bench_sweep.py [--repeat R] [--skip-main-job]

Measured in one run, on the same machine, each configuration as a user runs it (a fresh
``fto-report`` / ``fto-sweep`` process, imports included, wall time):

1. the main job (``fto-report``, every committed bag with every config, plots included)
   with ``--workers 1`` (one replay after the other in one process) and ``--workers 2``;
2. a 100-run sweep (``single_delay.tau`` x ``single_delay.k``, 10 x 10 values, on
   ``bags/dc_motor_nominal``, no figures) with ``--workers 1`` and ``--workers 2``;
3. the same sweep with ``--scheduler`` on a ``distributed.LocalCluster`` of 2 worker
   processes (1 thread each, loopback only, started just before the timing and closed
   after it: ``--scheduler`` uses an existing cluster; its start-up time is printed apart).

With ``--repeat R`` every configuration runs R times (in turn, so that a change of load
hits all of them alike) and the best time counts.  The machine's load average is printed
before and after: on a shared machine the ratios are only as good as the load was steady.
Prints markdown tables (ratios: time on 1 worker / time on 2, Dask time / pool time), and
for the sweeps the CPU time their runs took in the workers (``cpu_s`` of results.csv) over
the wall time: the cores the sweep actually got, which tells a parallel overhead (the CPU
grows) from a busy machine (the cores got fall short of the workers).
"""
from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
TAUS = [f"{0.02 + 0.01 * i:.2f}" for i in range(10)]
KS = [str(100 + 10 * i) for i in range(10)]


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg()) + \
        f" (1, 5, 15 min) on {os.cpu_count()} cores"


def timed(cmd: list[str], cwd: Path = ROOT) -> float:
    """Wall time of a command that must succeed (its output is discarded)."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return wall


def runs_cpu(out: Path) -> float:
    """The CPU time the sweep's runs took in their worker processes (results.csv's cpu_s)."""
    with open(out / "results.csv", newline="") as f:
        return sum(float(r["cpu_s"]) for r in csv.DictReader(f))


def main_job(workers: int, tmp: Path) -> list[str]:
    return [str(BIN / "fto-report"), "--no-progress", "--workers", str(workers),
            "--out", str(tmp / f"report{workers}")]


def sweep(tmp: Path, name: str, *where: str) -> list[str]:
    return [str(BIN / "fto-sweep"), "--params", str(ROOT / "config/dc_motor_plant.yaml"),
            "--params", str(ROOT / "config/dc_motor_single_delay.yaml"),
            "--bag", str(ROOT / "bags/dc_motor_nominal"),
            "--set", "single_delay.tau=" + ",".join(TAUS),
            "--set", "single_delay.k=" + ",".join(KS),
            "--out", str(tmp / name), "--overwrite", "--no-plots", "--quiet", *where]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration (best counts)")
    ap.add_argument("--skip-main-job", action="store_true", help="only the sweeps")
    args = ap.parse_args(argv)
    from distributed import LocalCluster

    print(f"before: {load()}\n")
    configs = ["main 1", "main 2"] if not args.skip_main_job else []
    configs += ["sweep 1", "sweep 2", "dask 2"]
    t = {name: float("inf") for name in configs}   # best wall time per configuration
    cpu = {}                                         # the sweeps' runs' CPU time in that run
    startup = float("inf")
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as d:
        tmp = Path(d)
        for _ in range(args.repeat):
            for name in configs:
                if name == "dask 2":
                    # started for its own measurement only: an idle cluster's heartbeats
                    # would take CPU from the others
                    t0 = time.perf_counter()
                    with LocalCluster(host="127.0.0.1", n_workers=2, threads_per_worker=1,
                                      processes=True, dashboard_address=None) as cluster:
                        startup = min(startup, time.perf_counter() - t0)
                        wall = timed(sweep(tmp, name, "--scheduler", cluster.scheduler_address))
                else:
                    kind, workers = name.split()
                    wall = timed(main_job(int(workers), tmp) if kind == "main" else
                                 sweep(tmp, name, "--workers", workers))
                if wall < t[name]:
                    t[name] = wall
                    if not name.startswith("main"):
                        cpu[name] = runs_cpu(tmp / name)
    print("| what | 1 worker (s) | 2 workers (s) | speed-up | target |")
    print("|---|---|---|---|---|")
    if not args.skip_main_job:
        print(f"| main job (fto-report) | {t['main 1']:.1f} | {t['main 2']:.1f} | "
              f"{t['main 1'] / t['main 2']:.2f}x | >= 1.7x |")
    print(f"| 100-run sweep, local processes | {t['sweep 1']:.1f} | {t['sweep 2']:.1f} | "
          f"{t['sweep 1'] / t['sweep 2']:.2f}x | >= 1.7x |")
    print()
    print("| 100-run sweep on 2 workers | local process pool | Dask LocalCluster | "
          "Dask / pool | target |")
    print("|---|---|---|---|---|")
    print(f"| wall time (s) | {t['sweep 2']:.1f} | {t['dask 2']:.1f} | "
          f"{t['dask 2'] / t['sweep 2']:.2f} | <= 1.2 |")
    print()
    print("The sweeps' runs' CPU time (results.csv's cpu_s, summed) and the cores they got on "
          "average (CPU / wall; 1 and 2 on an idle machine):\n")
    print("| sweep | runs' CPU (s) | wall (s) | cores got |")
    print("|---|---|---|---|")
    for name in ("sweep 1", "sweep 2", "dask 2"):
        print(f"| {name.replace('sweep', 'local').replace('dask', 'Dask')} worker(s) | "
              f"{cpu[name]:.1f} | {t[name]:.1f} | {cpu[name] / t[name]:.2f} |")
    print(f"\nLocalCluster start-up (not in the Dask time): {startup:.1f} s")
    print(f"after: {load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
