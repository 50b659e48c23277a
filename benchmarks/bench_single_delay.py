"""Per-sample cost of the single_delay kernels (both forms) on the DC motor, in-process.

Prints a markdown table: p50 and p99 (us) of ``obs.update_checked`` (the kernel through the
observer's clock, called from Python), of ``Runner.process`` alone and of
``Runner.set_input`` + ``process`` per sample (bench_update.py's figure), and the mean per
sample of ``Runner.process_block`` (the compiled block loop) and of the kernel alone in a
compiled loop (the observer's clock and kernel, no runner: what is left once the call from
Python is gone), each also as a ratio to a numpy 3x3 matrix-vector product timed in the same
run.  A mean counts the first sample of every new step size (a matrix exponential, through
scipy), which a p50 does not see.  The continuous form runs
on a 1 kHz stream (y and u at every sample); the sampled form on y at irregular 1-2 ms
instants with u at 1 kHz (its update integrates the predictor over the interval, every
input advances it).

    python benchmarks/bench_single_delay.py [--seconds S] [--repeats R]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench_update import matvec_baseline, time_calls
from fto_ros.core.jit import jit
from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate
from fto_ros.observers import kernel as K
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = {"continuous": "dc_motor_single_delay.yaml", "sampled": "dc_motor_single_delay_sampled.yaml"}
INPUT, MEASUREMENT = 1, 0          # runner/loop.py's event kinds


def events(form: str, seconds: float):
    """[(t, kind, value)] in time order: y and u at 1 kHz (continuous), or y at irregular
    1-2 ms instants on a 0.1 ms grid and u at 1 kHz (sampled)."""
    tu = np.arange(int(round(seconds * 1000)) + 1) * 1e-3
    if form == "continuous":
        ty = tu
    else:
        gaps = np.random.default_rng(2022).integers(10, 21, size=int(seconds * 1000)) * 100_000
        ty = np.concatenate(([0], np.cumsum(gaps)))
        ty = ty[ty <= seconds * 1e9] / 1e9
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, ty, dc_motor.default_voltage,
                   t_input=tu, output=dc_motor.output)
    ev = [(t, INPUT, np.array(dc_motor.default_voltage(t))) for t in tu]
    ev += [(t, MEASUREMENT, np.asarray(y, dtype=float)) for t, y in zip(ty, sim.y)]
    return sorted(ev, key=lambda e: (e[0], -e[1]))           # an input at a stamp first


@jit
def _kernel_loop(kernels, models, st, nx, c, ic, wk, clk, kind, t, v, empty):
    """Every event through the observer's clock and kernel: inputs advance (sampled form) or
    are held until the next measurement, which the kernel takes with the input in force."""
    u = v[0]
    for i in range(t.shape[0]):
        if kind[i] == 1:
            u = v[i]
            K.advance(kernels, models, st, nx, c, ic, wk, clk, t[i], u, empty)
        else:
            K.update(kernels, models, st, nx, c, ic, wk, clk, t[i], v[i], u)
    return 0


def best(fn, count: int, repeats: int) -> np.ndarray:
    """The per-call times (us) of the repeat with the lowest median; fn(i) for i < count,
    after fn(None) sets up a fresh run."""
    out = None
    for _ in range(repeats):
        fn(None)
        run = time_calls(fn, count)
        if out is None or np.median(run) < np.median(out):
            out = run
    return out


def measure(form: str, seconds: float, repeats: int) -> list[tuple[str, np.ndarray]]:
    flat = load_params_files(params_files(ROOT / "config" / CONFIGS[form]))
    ev = events(form, seconds)
    meas = [(t, v) for t, k, v in ev if k == MEASUREMENT]
    u_at = {}                                              # the input in force at each y
    u = None
    for t, k, v in ev:
        if k == INPUT:
            u = v
        else:
            u_at[t] = u
    rows = []
    state = {}

    def obs_update(i):
        if i is None:
            state["obs"] = obs = Runner(flat).observer
            obs.reset(None)
            return
        t, y = meas[i]
        state["obs"].update_checked(t, y, u_at[t])
    rows.append(("obs.update_checked", best(obs_update, len(meas), repeats)))

    rows.append(("Runner.process", _process_alone(flat, ev, repeats)))

    def both(i):
        if i is None:
            state["r"] = Runner(flat)
            return
        t, k, v = ev[i]
        r = state["r"]
        r.set_input(t, v) if k == INPUT else r.process(t, v)
    times = best(both, len(ev), repeats)
    rows.append(("Runner.set_input + process (per sample)",
                 times * len(ev) / len(meas)))

    if hasattr(Runner(flat), "process_block"):
        kind = np.array([k for _, k, _ in ev], dtype=np.int8)
        tt = np.array([t for t, _, _ in ev])
        vals = np.array([v for _, _, v in ev])
        per = []
        for _ in range(repeats):
            r = Runner(flat)
            t0 = time.perf_counter_ns()
            r.process_block(kind, tt, vals)
            per.append((time.perf_counter_ns() - t0) / 1e3 / len(meas))
        rows.append(("Runner.process_block (mean per sample)", np.array([min(per)])))
    if hasattr(Runner(flat).observer, "program"):                # a compiled kernel
        per = []
        for _ in range(repeats):
            obs = Runner(flat).observer
            obs.reset(None)
            prog = obs.program()
            t0 = time.perf_counter_ns()
            _kernel_loop(*prog, kind, tt, vals, np.zeros(0))
            per.append((time.perf_counter_ns() - t0) / 1e3 / len(meas))
        rows.append(("kernel alone, compiled loop (mean per sample)", np.array([min(per)])))
    return rows


def _process_alone(flat, ev, repeats):
    """Runner.process times only (the inputs fed between them untimed)."""
    out = None
    clock = time.perf_counter_ns
    for _ in range(repeats):
        r = Runner(flat)
        run = []
        for t, k, v in ev:
            if k == INPUT:
                r.set_input(t, v)
            else:
                t0 = clock()
                r.process(t, v)
                run.append(clock() - t0)
        run = np.array(run) / 1e3
        if out is None or np.median(run) < np.median(out):
            out = run
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0, help="stream length (s)")
    ap.add_argument("--repeats", type=int, default=3, help="best-of repeats of each measurement")
    args = ap.parse_args(argv)
    rows = {form: measure(form, args.seconds, args.repeats) for form in CONFIGS}
    base = matvec_baseline(5000, args.repeats)
    print(f"numpy baseline (3x3 matvec): {base:.2f} us\n")
    print("| form | call | p50 or mean (us) | p99 (us) | / matvec |")
    print("|---|---|---|---|---|")
    for form, form_rows in rows.items():
        for name, us in form_rows:
            p50 = np.median(us)
            p99 = f"{np.percentile(us, 99):.2f}" if us.size > 1 else "-"
            print(f"| {form} | {name} | {p50:.2f} | {p99} | {p50 / base:.1f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
