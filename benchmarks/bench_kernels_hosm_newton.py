"""hosm and newton_inversion as compiled kernels: cost per sample, in-process (no ROS).

For each config, on the first --samples samples of a committed bag: median and p99 of one
``observer.update_checked`` call (the kernel behind the observer's clock) and of one
``Runner.process`` call (checks, timeline, gate, kernel, outputs; the input is set before
each sample, untimed), and the time per sample of ``Runner.process_block`` (inputs and
measurements in blocks of BLOCK samples: the compiled loop, no Python per sample; the
median block, so that a busy machine's preemptions do not count); best of --repeats runs,
in microseconds and as ratios to a numpy 3x3 matrix-vector product timed in the same run.
dc_motor_luenberger (the first compiled family) is the reference row.  ``FTO_ROS_NUMBA=0``
in the environment measures the numpy path instead.

    python benchmarks/bench_kernels_hosm_newton.py [--samples N] [--repeats R]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_update import matvec_baseline  # noqa: E402

from fto_ros.bag.reader import read_messages  # noqa: E402
from fto_ros.core import jit  # noqa: E402
from fto_ros.runner import Runner  # noqa: E402
from fto_ros.runner.params_file import load_params_files  # noqa: E402
from fto_ros.runner.plant_files import params_files  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BLOCK = 20
#: (config, bag): the reference, the DC-motor configs of the two families, the papers' examples
CONFIGS = [("dc_motor_luenberger", "dc_motor_nominal"), ("dc_motor_hosm", "dc_motor_load"),
           ("dc_motor_newton", "dc_motor_nominal"), ("fld_example1_hosm", "fld_example1"),
           ("fld_example2_hosm", "fld_example2"), ("possieri_example_newton", "possieri_example"),
           ("possieri_example_newton_notch", "possieri_example")]


def samples(flat: dict, bag: str, count: int):
    """(t, y, u) of the first ``count`` measurements of ``bag``, u the last input before."""
    runner = Runner(flat)
    y_topic, u_topic = (runner.settings[f"topics.{k}"] for k in ("measured_output", "input"))
    m = runner.observer.n_inputs
    topics = [y_topic] + ([u_topic] if m else [])
    t, y, u, u_now = [], [], [], np.zeros(m)
    for topic, t_ns, msg in read_messages(ROOT / "bags" / bag, topics):
        if topic == u_topic:
            u_now = np.array(msg.data, dtype=float)
            continue
        t.append(t_ns * 1e-9)
        y.append(np.array(msg.data, dtype=float))
        u.append(u_now.copy())
        if len(t) == count:
            break
    return t, y, u


def measure(flat: dict, t, y, u, repeats: int):
    """(update_checked p50, p99, Runner.process p50, p99, process_block per sample) in us,
    best of ``repeats``."""
    from fto_ros.runner import loop
    clock = time.perf_counter_ns
    n = len(t)
    m = len(u[0])
    width = max(len(y[0]), m, 1)
    kind = np.repeat([[loop.INPUT, loop.MEASUREMENT]] if m else [[loop.MEASUREMENT]], n, 0)
    times = np.repeat(np.asarray(t)[:, None], kind.shape[1], 1)
    values = np.zeros(kind.shape + (width,))
    if m:
        values[:, 0, :m] = u
    values[:, -1, :len(y[0])] = y
    best_u = best_r = None
    best_b = np.inf
    for _ in range(repeats):
        obs = Runner(flat).observer
        obs.reset()
        obs.update_checked(t[0], y[0], u[0])
        upd = np.empty(n - 1)
        for i in range(1, n):
            t0 = clock()
            obs.update_checked(t[i], y[i], u[i])
            upd[i - 1] = clock() - t0
        r = Runner(flat)
        run = np.empty(n)
        for i in range(n):
            r.set_input(t[i], u[i])
            t0 = clock()
            r.process(t[i], y[i])
            run[i] = clock() - t0
        rb = Runner(flat)
        blocks = []
        for i in range(0, n - BLOCK + 1, BLOCK):
            k, tt, v = (a[i:i + BLOCK].reshape((-1,) + a.shape[2:]) for a in (kind, times, values))
            t0 = clock()
            rb.process_block(k, tt, v)
            blocks.append((clock() - t0) / BLOCK)
        best_b = min(best_b, float(np.median(blocks)))
        if best_u is None or np.median(upd) < np.median(best_u):
            best_u = upd
        if best_r is None or np.median(run) < np.median(best_r):
            best_r = run
    best_u, best_r = best_u / 1e3, best_r / 1e3
    return (np.median(best_u), np.percentile(best_u, 99), np.median(best_r),
            np.percentile(best_r, 99), best_b / 1e3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    rows = []
    for cfg, bag in CONFIGS:
        flat = load_params_files(params_files(ROOT / "config" / f"{cfg}.yaml"))
        t, y, u = samples(flat, bag, args.samples)
        measure(flat, t[:50], y[:50], u[:50], 1)            # compile / load, untimed
        rows.append((cfg, *measure(flat, t, y, u, args.repeats)))
    base = matvec_baseline(args.samples, args.repeats)
    print(f"{'compiled (numba)' if jit.ENABLED else 'numpy path (FTO_ROS_NUMBA=0)'}; "
          f"numpy baseline (3x3 matvec): {base:.2f} us\n")
    print("| config | update_checked p50 (us) | p99 (us) | Runner.process p50 (us) | p99 (us) "
          "| process_block (us/sample) | update / matvec | process / matvec | block / matvec |")
    print("|---|---|---|---|---|---|---|---|---|")
    for cfg, u50, u99, r50, r99, blk in rows:
        print(f"| {cfg} | {u50:.2f} | {u99:.2f} | {r50:.2f} | {r99:.2f} | {blk:.2f} | "
              f"{u50 / base:.1f}x | {r50 / base:.1f}x | {blk / base:.1f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
