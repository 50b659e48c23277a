"""Update time of global_norm (and high_gain) per sample, in-process, vs a numpy 3x3 matvec:
``Observer.update``, ``Observer.update_checked`` (the compiled kernel's entry without the
Python-side checks of y) and ``Runner.process`` (the compiled runner), in one run.

    cd /work/main && PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/bench_global_norm.py

Streams: the cubic_escape trajectory (n_states = 2, x(0) = (0.6, 0), 1 kHz, 3.5 s: the
gains grow from ~2e3 to ~1e8) and the Van der Pol oscillator; a synthetic n_states = 3
chain x0' = x1, x1' = x2, x2' = -x2 - 2 x1 - x0 + 0.5 sin(x0).  Target: update p50 <= 40 us
for n_states <= 3.
"""
from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_update import matvec_baseline, time_calls  # noqa: E402
from fto_ros.core.params import resolve  # noqa: E402
from fto_ros.observers.global_norm import GlobalNormObserver  # noqa: E402
from fto_ros.observers.high_gain import HighGainObserver  # noqa: E402
from fto_ros.runner import Runner  # noqa: E402


def stream(rhs, x0, n):
    t = np.arange(n) * 1e-3
    s = solve_ivp(rhs, (0, t[-1]), x0, t_eval=t, rtol=1e-10, atol=1e-12, method="DOP853")
    return t, s.y[0].reshape(-1, 1).copy()


def bench(cls, vals, t, y, repeats):
    """(update p50, p99, update_checked p50, Runner.process p50) in us, best of repeats."""
    best = {}
    u = np.zeros(0)
    flat = {"observer.type": cls.TYPE, **{f"{cls.TYPE}.{k}": v for k, v in vals.items()}}
    for _ in range(repeats):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ob = cls(resolve(cls.PARAMS, vals, cls.TYPE + "."))
            r = Runner(flat)
        ob.reset(t[0])
        ob.update(t[0], y[0], u)
        got = {"update": time_calls(lambda i: ob.update(t[i + 1], y[i + 1], u), len(t) - 1)}
        ob.reset(t[0])
        ob.update_checked(t[0], y[0], u)
        got["checked"] = time_calls(lambda i: ob.update_checked(t[i + 1], y[i + 1], u), len(t) - 1)
        got["process"] = time_calls(lambda i: r.process(t[i], y[i]), len(t))
        for k, d in got.items():
            if k not in best or np.median(d) < np.median(best[k]):
                best[k] = d
    return (np.median(best["update"]), np.percentile(best["update"], 99),
            np.median(best["checked"]), np.median(best["process"]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=3500)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    base = matvec_baseline(args.samples, args.repeats)
    cub = stream(lambda t, x: [x[1], -x[1] + x[0] ** 3], [0.6, 0.0], args.samples)
    vdp = stream(lambda t, x: [x[1], (1 - x[0] ** 2) * x[1] - x[0]], [2.0, 0.0], args.samples)
    ch3 = stream(lambda t, x: [x[1], x[2], -x[2] - 2 * x[1] - x[0] + 0.5 * math.sin(x[0])],
                 [1.0, 0.0, -1.0], args.samples)
    cubic = dict(f="-x1 + y**3", gamma_1="5*y**2 + y**6",
                 gamma_hat="1 + (1 + 2*sqrt(2))*sqrt(4*w + 2) + (4*w + 2)**1.5")
    vdpp = dict(f="(1 - y**2)*x1 - y", gamma_1="y**2", gamma_hat="4 + 4*w")
    chain = dict(n_states=3, f="-x2 - 2*x1 - y + 0.5*sin(y)", gamma_1="y**2", gamma_hat="3 + w",
                 conditions="warn")
    rows = [
        ("global_norm full, cubic_escape (n_states 2)", GlobalNormObserver, cubic, cub),
        ("global_norm reduced, cubic_escape (n_states 2)", GlobalNormObserver, {**cubic, "form": "reduced"}, cub),
        ("global_norm full, van_der_pol (n_states 2)", GlobalNormObserver, vdpp, vdp),
        ("global_norm full, synthetic chain (n_states 3)", GlobalNormObserver, chain, ch3),
        ("global_norm reduced, synthetic chain (n_states 3)", GlobalNormObserver, {**chain, "form": "reduced"}, ch3),
        ("high_gain, cubic_escape (n_states 2)", HighGainObserver,
         dict(f="-x1 + y**3", L=20.0, saturation=10.0), cub),
        ("high_gain, synthetic chain (n_states 3)", HighGainObserver,
         dict(n_states=3, f="-x2 - 2*x1 - y + 0.5*sin(y)", L=20.0), ch3),
    ]
    print(f"numpy baseline (3x3 matvec): {base:.2f} us; {args.samples} samples, best of "
          f"{args.repeats}\n")
    print("| observer, stream | update p50 (us) | update p99 (us) | update_checked p50 (us) | "
          "Runner.process p50 (us) | update / matvec | update_checked / matvec | "
          "process / matvec |")
    print("|---|---|---|---|---|---|---|---|")
    for name, cls, vals, (t, y) in rows:
        p50, p99, c50, r50 = bench(cls, vals, t, y, args.repeats)
        print(f"| {name} | {p50:.1f} | {p99:.1f} | {c50:.1f} | {r50:.1f} | {p50 / base:.1f}x | "
              f"{c50 / base:.1f}x | {r50 / base:.1f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
