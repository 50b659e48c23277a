"""Update cost of the compiled ekf and of the acquire-then-track composition on the DC motor,
as ratios to a numpy 3x3 matrix-vector product timed in the same run (issue 18's unit).

Per configuration: ``Observer.update_checked`` and ``Runner.set_input`` + ``process`` per
sample (median and p99, best of --repeats runs, bench_update.py's method), the per-sample
cost of ``Runner.process_block`` over the whole stream (inputs and measurements in one
block), and, compiled, the kernel alone (observers/kernel.py ``update`` called from a
compiled loop: what a sample costs without the Python call).  Configurations: the DC
motor's ekf, its committed acquire-then-track, and the composition with a stand-in
acquirer (a luenberger kernel claiming tau = 0.1 s: the composition's own cost on the
cheapest compiled child).

    python benchmarks/bench_ekf_track.py [--samples N] [--repeats R]
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_update import ROOT, matvec_baseline, measure, stream  # noqa: E402

from fto_ros.core import jit as J  # noqa: E402
from fto_ros.observers import REGISTRY, kernel as K  # noqa: E402
from fto_ros.observers.luenberger import LuenbergerObserver  # noqa: E402
from fto_ros.runner import Runner, loop as L, settings as S  # noqa: E402
from fto_ros.runner.params_file import load_params_files  # noqa: E402
from fto_ros.runner.plant_files import params_files  # noqa: E402


class StandInAcquirer(LuenbergerObserver):
    """The cheapest compiled acquirer: the composition's own cost on top of its children."""

    def __init__(self, cfg):
        super().__init__(cfg)
        self._st[K.GUARANTEED] = 0.1


def _flat(name: str) -> dict:
    return load_params_files(params_files(ROOT / "config" / name))


def configs() -> list[tuple[str, dict]]:
    out = [("ekf", _flat("dc_motor_ekf.yaml")), ("track (committed)", _flat("dc_motor_acquire_track.yaml"))]
    stand_in = _flat("dc_motor_ekf.yaml")
    _, _, lu = S.split(_flat("dc_motor_luenberger_poles.yaml"))
    stand_in.update({"luenberger." + k: v for k, v in lu.items()})
    stand_in.update({"observer.type": "track", "track.acquirer": "single_delay",
                     "track.tracker": "ekf"})
    out.append(("track (compiled, stand-in acquirer)", stand_in))
    return out


#: samples per block (the node hands over what arrived since its last callback)
CHUNK = 100


def block_cost(flat: dict, t, y, u, repeats: int) -> float:
    """Per-sample time (us) of Runner.process_block on blocks of CHUNK samples (an input and
    a measurement each): the median over the blocks, the best of repeats."""
    kind = np.tile(np.array([L.INPUT, L.MEASUREMENT], np.int8), CHUNK)
    best = np.inf
    for _ in range(repeats):
        r = Runner(flat)
        times = []
        for a in range(0, len(t) - CHUNK + 1, CHUNK):
            ts = np.repeat(t[a:a + CHUNK], 2)
            values = np.stack([u[a:a + CHUNK, 0], y[a:a + CHUNK, 0]], axis=1).reshape(-1, 1)
            t0 = time.perf_counter()
            r.process_block(kind, ts, values)
            times.append((time.perf_counter() - t0) / CHUNK * 1e6)
        best = min(best, float(np.median(times)))
    return best


def kernel_cost(flat: dict, t, y, u, repeats: int) -> float:
    """Per-sample time (us) of the kernel through observers/kernel.py's update, from a
    compiled loop over CHUNK samples (the median over the chunks, the best of repeats; nan
    without numba)."""
    obs = Runner(flat).observer
    if not J.ENABLED:
        return float("nan")
    best = np.inf
    for _ in range(repeats):
        obs.reset()
        prog = obs.program()
        times = []
        for a in range(0, len(t) - CHUNK + 1, CHUNK):
            t0 = time.perf_counter()
            _drive(*prog, t[a:a + CHUNK], y[a:a + CHUNK], u[a:a + CHUNK])
            times.append((time.perf_counter() - t0) / CHUNK * 1e6)
        best = min(best, float(np.median(times)))
    return best


def _drive_py(kernels, models, st, nx, c, ic, wk, clk, t, y, u):
    for i in range(t.shape[0]):
        K.update(kernels, models, st, nx, c, ic, wk, clk, t[i], y[i], u[i])


_drive = J.jit(_drive_py)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=3000)
    ap.add_argument("--repeats", type=int, default=3, help="best-of repeats of each measurement")
    args = ap.parse_args(argv)
    t, y, u = stream(args.samples)
    for name, flat in configs():                  # compile (or load) everything first
        with _acquirer(name):
            kernel_cost(flat, t[:CHUNK], y[:CHUNK], u[:CHUNK], 1)
            block_cost(flat, t[:CHUNK], y[:CHUNK], u[:CHUNK], 1)
    base = matvec_baseline(args.samples, args.repeats)
    print(f"numpy baseline (3x3 matvec): {base:.2f} us; numba {'on' if J.ENABLED else 'off'}\n")
    print("| configuration | update p50 | update p99 | process p50 | process p99 | "
          "block per sample | kernel alone | update p50 / matvec | block / matvec |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, flat in configs():
        with _acquirer(name):
            p50, p99, r50, r99 = measure(flat, t, y, u, args.repeats)
            blk = block_cost(flat, t, y, u, args.repeats)
            ker = kernel_cost(flat, t, y, u, args.repeats)
            cls = type(Runner(flat).observer).__name__
        print(f"| {name} ({cls}) | {p50:.1f} | {p99:.1f} | {r50:.1f} | {r99:.1f} | {blk:.1f} | "
              f"{ker:.1f} | {p50 / base:.1f}x | {blk / base:.1f}x |")
    return 0


@contextlib.contextmanager
def _acquirer(name: str):
    """The stand-in acquirer registered as single_delay while its configuration runs."""
    real = REGISTRY["single_delay"]
    if "stand-in" in name:
        REGISTRY["single_delay"] = StandInAcquirer
    try:
        yield
    finally:
        REGISTRY["single_delay"] = real


if __name__ == "__main__":
    raise SystemExit(main())
