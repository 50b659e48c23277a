"""Start-up with a plant block, and the per-sample cost of the plant-block form (ROS-free).

1. Start-up: ``Runner(flat)`` for a plant block and each observer type's tuning, i.e. parsing
   the plant, the derivation (sympy), compiling the expressions and the observer's own
   start-up design, for plants of order n = 2 .. 6 in every class:

       x_i' = x_{i+1} (i < n - 1),  x_{n-1}' = -sum_i a_i x_i - 0.5 x_0^3 + u + d,  y = x_0

   (a_i from (s + 1)^n; the cubic term a known term in y, d an unknown input).  First call in
   the process (imports done before) and best of ``--repeats``; the derivation alone
   (``fto_ros.plant.expand``) in its own column.  Target: under 2 s for n <= 6.
2. Per sample: ``Runner.process`` (with ``set_input``) p50 of each committed DC-motor config
   in its plant-block form (config/dc_motor_plant.yaml + tuning file) and in its explicit
   form (test/data/dc_motor_explicit/), interleaved in one run on the same 1 kHz stream; the
   derived observer is the same class with the same parameters, so the ratio should be 1.

    python benchmarks/bench_plant.py [--repeats R] [--samples N]
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate
from fto_ros.plant import expand
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parent.parent
TYPES = ("single_delay", "prescribed_time", "hosm", "luenberger", "newton_inversion", "ekf",
         "global_norm", "high_gain")
DC_CONFIGS = ("single_delay", "single_delay_sampled", "luenberger", "luenberger_poles", "hosm",
              "newton")


def chain_plant(n: int) -> dict:
    a = [math.comb(n, i) for i in range(n)]                 # (s + 1)^n, lowest power first
    xs = [f"x{i}" for i in range(n)]
    last = " - ".join(f"{a[i]}*{xs[i]}" for i in range(n))
    return {"plant.states": xs, "plant.inputs": ["u"], "plant.unknown_inputs": ["d"],
            "plant.f": xs[1:] + [f"-{last} - 0.5*x0**3 + u + d"], "plant.h": ["x0"]}


def tuning(kind: str, n: int) -> dict:
    poles = [-2.0 - i for i in range(n)]
    return {"single_delay": {"k": 10.0, "tau": 0.5},
            "prescribed_time": {"T": 2.0, "l": [float(math.comb(n, i + 1)) for i in range(n)]},
            "hosm": {"poles": poles, "M": [10.0]},
            "luenberger": {"poles": poles},
            "newton_inversion": {},
            "ekf": {"process_noise": [1e-3] * n, "measurement_noise": [1e-6]},
            "global_norm": {"conditions": "warn"},
            "high_gain": {}}[kind]


def flat_for(kind: str, n: int) -> dict:
    flat = dict(chain_plant(n), **{"observer.type": kind})
    flat.update({f"{kind}.{k}": v for k, v in tuning(kind, n).items()})
    return flat


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def startup_table(repeats: int) -> None:
    import warnings
    warnings.simplefilter("ignore")                          # global_norm's footnote-6 warning
    print("| observer | n | Runner start-up, first (s) | best of %d (s) | derivation alone, best (s) |"
          % repeats)
    print("|---|---|---|---|---|")
    for kind in TYPES:
        for n in range(2, 7):
            flat = flat_for(kind, n)
            first = timed(lambda: Runner(flat))
            best = min(timed(lambda: Runner(flat)) for _ in range(repeats))
            derive = min(timed(lambda: expand(flat)) for _ in range(repeats))
            print(f"| {kind} | {n} | {first:.3f} | {best:.3f} | {derive:.3f} |")


def stream(n: int, h: float = 1e-3):
    t = np.arange(n) * h
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage)
    return t, sim.x[:, :1].copy(), sim.u.copy()


def process_p50(flat: dict, t, y, u) -> float:
    r = Runner(flat)
    out = np.empty(len(t))
    clock = time.perf_counter_ns
    for i in range(len(t)):
        t0 = clock()
        r.set_input(t[i], u[i])
        r.process(t[i], y[i])
        out[i] = clock() - t0
    return float(np.median(out)) / 1e3


def per_sample_table(samples: int, repeats: int) -> None:
    t, y, u = stream(samples)
    print("\n| DC-motor config | plant-block form p50 (us) | explicit form p50 (us) | ratio |")
    print("|---|---|---|---|")
    for name in DC_CONFIGS:
        plant = load_params_files([ROOT / "config" / "dc_motor_plant.yaml",
                                   ROOT / "config" / f"dc_motor_{name}.yaml"])
        explicit = load_params_files([ROOT / "test" / "data" / "dc_motor_explicit"
                                      / f"dc_motor_{name}.yaml"])
        a, b = [], []
        for k in range(repeats):                  # interleaved, alternating which goes first
            for flat, out in ((plant, a), (explicit, b))[::1 if k % 2 else -1]:
                out.append(process_p50(flat, t, y, u))
        print(f"| {name} | {min(a):.1f} | {min(b):.1f} | {min(a) / min(b):.2f} |")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--samples", type=int, default=3000)
    args = p.parse_args()
    code = ("import time; t = time.perf_counter(); import fto_ros.runner.settings; "
            "print(time.perf_counter() - t)")
    imports = min(float(subprocess.run([sys.executable, "-c", code], capture_output=True,
                                       text=True, check=True).stdout) for _ in range(args.repeats))
    print(f"imports in a fresh process (numpy, scipy, sympy, fto_ros), best of {args.repeats}: "
          f"{imports:.2f} s (not in the start-up rows: paid once per process)\n")
    startup_table(args.repeats)
    per_sample_table(args.samples, args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
