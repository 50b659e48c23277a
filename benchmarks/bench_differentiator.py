"""Robust exact differentiator (core/differentiator.py): accuracy and cost of each scheme.

(a) error tables: max |z_i - f^(i)| over t in [15, 25] s, f = sin t, L = 1, rho = 2,
    start z = (f(0), 0, ..., 0), for each scheme against the sampling step h (no noise)
    and against uniform noise of amplitude eps at 1 kHz; plus the accuracy orders fitted
    on them (slope of log error vs log h, resp. log eps) next to the theory N - i and
    (N - i)/N.
(b) cost of one ``Differentiator.update`` call from Python (median and p99 over the stream,
    best of --repeats, microseconds) per scheme and order, one channel and 3 channels (the
    compiled step of core/differentiator_step.py; the observers' kernels call it without
    the Python around it), with the ratio to a numpy 3x3 matvec timed in the same run.

    python benchmarks/bench_differentiator.py [--orders 1,2,3,4,5] [--samples N] [--repeats R]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_update import matvec_baseline, time_calls  # noqa: E402

from fto_ros.core.differentiator import SCHEMES, Differentiator  # noqa: E402

T_END, T_FROM = 25.0, 15.0
H_GRID = (1e-2, 1e-3, 1e-4)
EPS_GRID = (1e-4, 1e-3, 1e-2)


def errors(n, h, scheme, eps=0.0, seed=0, **kw):
    m = int(round(T_END / h))
    t = np.arange(m + 1) * h
    f = np.sin(t)
    if eps:
        f = f + eps * np.random.default_rng(seed).uniform(-1, 1, m + 1)
    d = Differentiator(n, 1.0, scheme=scheme, **kw)
    d.reset(f[:1])
    fl = f.tolist()
    Z = np.empty((m + 1, n + 1))
    Z[0] = d.estimates[0]
    upd = d.update
    for k in range(m):
        Z[k + 1] = upd(h, fl[k + 1])[0]
    der = np.array([np.sin(t + i * np.pi / 2) for i in range(n + 1)]).T
    return np.abs(Z - der)[t >= T_FROM].max(0)


def slope(xs, E):
    lx = np.log(np.asarray(xs))
    return np.polyfit(lx, np.log(np.asarray(E)), 1)[0]


def fmt(v):
    return f"{v:.1e}"


def error_tables(orders):
    print("### (a) errors: max |z_i - f^(i)|, f = sin t, L = 1, rho = 2, t in [15, 25] s\n")
    for n in orders:
        N = n + 1
        cols = " | ".join(f"z{i}" for i in range(N))
        print(f"**order {n}** (theory: h^{tuple(N - i for i in range(N))}, "
              f"eps^{tuple(f'{N - i}/{N}' for i in range(N))})\n".replace("'", ""))
        print(f"| scheme | h | eps | {cols} |")
        print("|---|---|---|" + "---|" * N)
        fits = {}
        for scheme in SCHEMES:
            Eh = [errors(n, h, scheme) for h in H_GRID]
            for h, e in zip(H_GRID, Eh):
                print(f"| {scheme} | {h:g} | 0 | " + " | ".join(fmt(v) for v in e) + " |")
            Ee = [errors(n, 1e-3, scheme, eps=eps) for eps in EPS_GRID]
            for eps, e in zip(EPS_GRID, Ee):
                print(f"| {scheme} | 0.001 | {eps:g} | " + " | ".join(fmt(v) for v in e) + " |")
            fits[scheme] = (slope(H_GRID[:2], Eh[:2]), slope(H_GRID[1:], Eh[1:]),
                            slope(EPS_GRID, Ee))
        print(f"\nfitted orders (slope of log error), order {n}:\n")
        print(f"| scheme | fit | {cols} |")
        print("|---|---|" + "---|" * N)
        print("| theory | h | " + " | ".join(str(N - i) for i in range(N)) + " |")
        print("| theory | eps | " + " | ".join(f"{(N - i) / N:.2f}" for i in range(N)) + " |")
        for scheme, (s1, s2, se) in fits.items():
            print(f"| {scheme} | h 1e-2..1e-3 | " + " | ".join(f"{v:.2f}" for v in s1) + " |")
            print(f"| {scheme} | h 1e-3..1e-4 | " + " | ".join(f"{v:.2f}" for v in s2) + " |")
            print(f"| {scheme} | eps (h = 1e-3) | " + " | ".join(f"{v:.2f}" for v in se) + " |")
        print()


def timing(orders, samples, repeats):
    base = matvec_baseline(samples, repeats)
    h = 1e-3
    f = np.sin(np.arange(samples + 1) * h)
    print("### (b) cost of one update (in-process, median / p99 over the stream, best of "
          f"{repeats})\n")
    print(f"numpy baseline (3x3 matvec): {base:.2f} us\n")
    print("| scheme | order | channels | p50 (us) | p99 (us) | p50 / matvec |")
    print("|---|---|---|---|---|---|")
    for scheme in SCHEMES:
        for n in orders:
            for channels in (1, 3):
                fs = [np.full(channels, v) for v in f]
                best = None
                for _ in range(repeats):
                    d = Differentiator(n, 1.0, scheme=scheme, channels=channels)
                    d.reset(fs[0])
                    upd = d.update
                    ts = time_calls(lambda i: upd(h, fs[i + 1]), samples)
                    if best is None or np.median(ts) < np.median(best):
                        best = ts
                p50 = np.median(best)
                print(f"| {scheme} | {n} | {channels} | {p50:.2f} | "
                      f"{np.percentile(best, 99):.2f} | {p50 / base:.1f}x |")
    print()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", default="1,2,3,4,5", help="orders of the error tables")
    ap.add_argument("--timing-orders", default="1,2,3,4,5,7")
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-errors", action="store_true")
    args = ap.parse_args(argv)
    if not args.skip_errors:
        error_tables([int(v) for v in args.orders.split(",")])
    timing([int(v) for v in args.timing_orders.split(",")], args.samples, args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
