"""Update cost per sample of each observer, in-process (no ROS), on the DC-motor bags' data.

Prints a markdown table: median and p99 of one ``Observer.update`` call and of one
``Runner.process`` call (validation + update + outputs), in microseconds, measured
in one run on the same sample stream, plus each figure as a ratio to the plain
numpy baseline (one 3x3 matrix-vector product) timed in the same run, so the
table carries over between machines better than absolute times.

    python benchmarks/bench_update.py [--samples N] [--repeats R]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ["dc_motor_single_delay.yaml", "dc_motor_luenberger.yaml", "dc_motor_hosm.yaml",
           "dc_motor_newton.yaml"]


def stream(n: int, h: float = 1e-3):
    t = np.arange(n) * h
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage)
    return t, sim.x[:, :1].copy(), sim.u.copy()


def time_calls(fn, n: int) -> np.ndarray:
    out = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        t0 = clock()
        fn(i)
        out[i] = clock() - t0
    return out / 1e3


def matvec_baseline(samples: int, repeats: int) -> float:
    """Median time (us) of one 3x3 matrix-vector product: the unit of the ratio column."""
    M, v = np.random.default_rng(0).normal(size=(3, 3)), np.ones(3)
    return min(np.median(time_calls(lambda i: M @ v, samples)) for _ in range(repeats))


def measure(flat: dict, t, y, u, repeats: int) -> tuple[float, float, float, float]:
    """(update p50, p99, Runner.process p50, p99) in us: the best of ``repeats`` runs
    over the sample stream (t, y, u), each on a fresh Runner."""
    n = len(t)
    best_obs = best_run = None
    for _ in range(repeats):
        obs = Runner(flat).observer
        obs.reset(t[0])
        obs.update(t[0], y[0], u[0])
        upd = time_calls(lambda i: obs.update(t[i + 1], y[i + 1], u[i + 1]), n - 1)
        r = Runner(flat)

        def proc(i):
            r.set_input(t[i], u[i])
            r.process(t[i], y[i])
        run = time_calls(proc, n)
        if best_obs is None or np.median(upd) < np.median(best_obs):
            best_obs = upd
        if best_run is None or np.median(run) < np.median(best_run):
            best_run = run
    return (np.median(best_obs), np.percentile(best_obs, 99),
            np.median(best_run), np.percentile(best_run, 99))


def print_table(first_column: str, rows, base: float) -> None:
    """The markdown table: rows of (label, update p50, p99, process p50, p99)."""
    print(f"numpy baseline (3x3 matvec): {base:.2f} us\n")
    print(f"| {first_column} | update p50 (us) | update p99 (us) | runner.process p50 (us) | "
          "runner.process p99 (us) | update p50 / matvec |")
    print("|---|---|---|---|---|---|")
    for name, p50, p99, r50, r99 in rows:
        print(f"| {name} | {p50:.1f} | {p99:.1f} | {r50:.1f} | {r99:.1f} | {p50 / base:.0f}x |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=3, help="best-of repeats of each measurement")
    args = ap.parse_args(argv)
    t, y, u = stream(args.samples)
    base = matvec_baseline(args.samples, args.repeats)
    rows = []
    for cfg in CONFIGS:
        flat = load_params_files(params_files(ROOT / "config" / cfg))
        rows.append((flat["observer.type"], *measure(flat, t, y, u, args.repeats)))
    print_table("observer", rows, base)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
