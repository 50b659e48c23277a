"""Cost per sample of every committed DC-motor config, in-process (no ROS).

Prints a markdown table, measured in one run on the same 1 kHz sample stream, in
microseconds and as ratios to the plain numpy baseline (one 3x3 matrix-vector product)
timed in the same run, so the table carries over between machines better than
absolute times:

- ``update_checked``: one observer update from Python (the compiled kernel's entry:
  the input and measurement checks, the kernel, commit-if-finite);
- ``Runner.process``: one ``set_input`` + ``process`` pair (validation, timeline, gate,
  the kernel, the output arrays and the convergence figures) from Python;
- ``process_block``: the same stream as one block of input/measurement events through
  ``Runner.process_block`` (the compiled loop the replay and the node's batched intake
  use), per measurement.

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
from fto_ros.runner import loop as L
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files

ROOT = Path(__file__).resolve().parent.parent
#: every committed DC-motor config but the plant file itself
CONFIGS = sorted(p.name for p in (ROOT / "config").glob("dc_motor_*.yaml")
                 if p.name != "dc_motor_plant.yaml")


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


def measure(flat: dict, t, y, u, repeats: int) -> tuple[float, float, float, float, float]:
    """(update_checked p50, p99, Runner.process p50, p99, process_block per sample) in us:
    the best of ``repeats`` runs over the sample stream (t, y, u), each on a fresh Runner."""
    n = len(t)
    best_obs = best_run = None
    best_block = float("inf")
    kind = np.tile(np.array([L.INPUT, L.MEASUREMENT], np.int8), n)
    tt = np.repeat(t, 2)
    vals = np.zeros((2 * n, max(y.shape[1], u.shape[1])))
    vals[0::2, :u.shape[1]] = u
    vals[1::2, :y.shape[1]] = y
    warm = Runner(flat)                  # compiled code loaded (or compiled) before timing
    for i in range(min(n, 50)):
        warm.set_input(t[i], u[i])
        warm.process(t[i], y[i])
    Runner(flat).process_block(kind[:100], tt[:100], vals[:100])
    for _ in range(repeats):
        obs = Runner(flat).observer
        obs.reset(t[0])
        obs.update_checked(t[0], y[0], u[0])
        upd = time_calls(lambda i: obs.update_checked(t[i + 1], y[i + 1], u[i + 1]), n - 1)
        r = Runner(flat)

        def proc(i):
            r.set_input(t[i], u[i])
            r.process(t[i], y[i])
        run = time_calls(proc, n)
        r = Runner(flat)
        t0 = time.perf_counter_ns()
        r.process_block(kind, tt, vals)
        best_block = min(best_block, (time.perf_counter_ns() - t0) / 1e3 / n)
        if best_obs is None or np.median(upd) < np.median(best_obs):
            best_obs = upd
        if best_run is None or np.median(run) < np.median(best_run):
            best_run = run
    return (np.median(best_obs), np.percentile(best_obs, 99),
            np.median(best_run), np.percentile(best_run, 99), best_block)


def print_table(first_column: str, rows, base: float) -> None:
    """The markdown table: rows of (label, update p50, p99, process p50, p99, block)."""
    print(f"numpy baseline (3x3 matvec): {base:.2f} us\n")
    print(f"| {first_column} | update_checked p50 / p99 (us) | Runner.process p50 / p99 (us) | "
          "process_block per sample (us) | update / matvec | process / matvec | block / matvec |")
    print("|---|---|---|---|---|---|---|")
    for name, p50, p99, r50, r99, blk in rows:
        print(f"| {name} | {p50:.1f} / {p99:.1f} | {r50:.1f} / {r99:.1f} | {blk:.2f} | "
              f"{p50 / base:.1f}x | {r50 / base:.1f}x | {blk / base:.1f}x |")


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
        rows.append((cfg[:-5], *measure(flat, t, y, u, args.repeats)))
    print_table("config", rows, base)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
