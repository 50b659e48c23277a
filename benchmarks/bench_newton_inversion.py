"""newton_inversion: update cost per sample and start-up time, in-process (no ROS).

Median/p99 of one ``Observer.update`` and one ``Runner.process`` call on example (22)
(n = 2, input differentiator included) and the DC motor (n = 3), each as a ratio to the
numpy 3x3 matvec baseline timed in the same run; the start-up time (symbolic derivation,
compilation and the start-up check) of the DC-motor and example observers; and the cost of
the map from Python, the generated model function vs lambdify 'numpy'.

    PYTHONPATH=. python benchmarks/bench_newton_inversion.py [--samples N] [--repeats R]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import sympy

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_update import matvec_baseline, measure, print_table, stream, time_calls  # noqa: E402
from fto_ros.core.symbolic_model import SymbolicModel  # noqa: E402
from fto_ros.models import possieri_example as pe  # noqa: E402
from fto_ros.runner import Runner  # noqa: E402
from fto_ros.runner.params_file import load_params_files  # noqa: E402
from fto_ros.runner.plant_files import params_files  # noqa: E402


def example_stream(n: int, h: float = 1e-3):
    t = np.round(np.arange(n) * h * 1e9) / 1e9
    s = pe.simulate_example(t)
    return t, s["y"], s["u"]


def startup(cfg: str, repeats: int) -> float:
    flat = load_params_files(params_files(ROOT / "config" / cfg))
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        Runner(flat)
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    # start-up first: the first construction pays sympy's own import-time caches too
    t0 = time.perf_counter()
    Runner(load_params_files(params_files(ROOT / "config" / "dc_motor_newton.yaml")))
    cold = time.perf_counter() - t0
    base = matvec_baseline(args.samples, args.repeats)
    rows = []
    ty = example_stream(args.samples)
    for cfg in ("possieri_example_newton.yaml", "possieri_example_newton_notch.yaml",
                "possieri_example_newton_ndim.yaml"):
        rows.append((cfg[:-5], *measure(load_params_files(params_files(ROOT / "config" / cfg)), *ty, args.repeats)))
    t, y, u = stream(args.samples)
    rows.append(("dc_motor_newton", *measure(load_params_files(params_files(ROOT / "config" / "dc_motor_newton.yaml")),
                                             t, y, u, args.repeats)))
    rows.append(("dc_motor_single_delay (reference)",
                 *measure(load_params_files(params_files(ROOT / "config" / "dc_motor_single_delay.yaml")), t, y, u,
                          args.repeats)))
    print_table("config", rows, base)
    print()
    print("| start-up (parse, sympy derivation, code generation, J check) | seconds |")
    print("|---|---|")
    print(f"| dc_motor_newton, first in the process | {cold:.3f} |")
    for cfg in ("dc_motor_newton.yaml", "possieri_example_newton.yaml"):
        print(f"| {cfg[:-5]} (best of {args.repeats}) | {startup(cfg, args.repeats):.3f} |")
    # the map (O, J, G) of example (22) from Python: the generated model function (the
    # kernel's, run as Python) against lambdify's numpy backend
    m = SymbolicModel(["x1", "x2"], ["u"], list(pe.F_TEXT), [pe.H_TEXT])
    flat = tuple(m.O) + tuple(x for r in m.J for x in r) + tuple(m.G)
    f_np = sympy.lambdify((m.x, m.ue), flat, modules="numpy", cse=True)
    x, ue = [0.3, -0.2], [0.1, 0.5, 0.0]
    xa, uea = np.array(x), np.array(ue)
    t_math = np.median(time_calls(lambda i: m.evaluate(x, ue), args.samples))
    t_np = np.median(time_calls(lambda i: f_np(xa, uea), args.samples))
    print()
    print("| compiled (O, J, G) of example (22), one call | p50 (us) |")
    print("|---|---|")
    print(f"| generated model function (core/model_code.py), as Python | {t_math:.2f} |")
    print(f"| lambdify modules='numpy' | {t_np:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
