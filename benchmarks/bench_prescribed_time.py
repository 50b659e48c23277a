"""Update cost per sample of the prescribed_time observer, in-process (no ROS), n = 2, 3, 4, 8
and the DC motor.

Same method as bench_update.py: median and p99 of one ``Observer.update`` call and of
one ``Runner.process`` call on the same 1 kHz sample stream, best of R repeats, and the
median as a ratio to a plain numpy 3x3 matrix-vector product timed in the same run; and
the median of ``Observer.update_checked`` (the compiled kernel's entry without the
Python-side checks of y and u) and its ratio.

Rows: the two example configs (n = 2: the paper's Example 1; n = 3, relative degree 2),
then n = 4 and n = 8 chains of integrators (l from (s + 1)^n, T = 5 s, m = 1), then the DC
motor's plant block (config/dc_motor_plant.yaml: n = 3, relative degree 3, F = the sin q
terms, a state map) with T = 1 s, l from (s + 1)^3, on the DC-motor stream of
bench_update.py.  The stream is 5000 samples (5 s at 1 kHz) of the plant, so it covers a
whole window up to its end at T, where the gains are largest (the cost does not depend on
them).

    python benchmarks/bench_prescribed_time.py [--samples N] [--repeats R]

``--modes [--plot PNG]`` instead compares the continuous-operation modes on Example 1
(20 s, 1 kHz, x(0) = (20, 1), x_hat(0) = 0), without and with Gaussian noise on y:
it prints the largest |x - x_hat| after the first window per mode and noise level, and
draws the largest gain and the error norm over time (docs/prescribed_time_modes.png):

    python benchmarks/bench_prescribed_time.py --modes --plot docs/prescribed_time_modes.png
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.linalg import expm

from fto_ros.models.canonical_form import DOUBLE_INTEGRATOR, THIRD_ORDER, CanonicalPlant
from fto_ros.runner import Runner, load_params_file

import bench_update
from bench_update import matvec_baseline, measure, time_calls   # the same measurement

ROOT = Path(__file__).resolve().parent.parent


def chain_params(n: int) -> dict:
    return {"observer.type": "prescribed_time", "prescribed_time.n_states": n,
            "prescribed_time.relative_degree": n, "prescribed_time.a": [0.0] * n,
            "prescribed_time.b": [1.0], "prescribed_time.T": 5.0, "prescribed_time.m": 1,
            "prescribed_time.l": [float(c) for c in np.poly(-np.ones(n))[1:]]}


def cases():
    return [
        ("double_integrator_prescribed_time.yaml (n = 2)",
         load_params_file(ROOT / "config" / "double_integrator_prescribed_time.yaml"),
         DOUBLE_INTEGRATOR, (20.0, 1.0), lambda t: np.sin(10 * t) + np.cos(t)),
        ("third_order_prescribed_time.yaml (n = 3)",
         load_params_file(ROOT / "config" / "third_order_prescribed_time.yaml"),
         THIRD_ORDER, (1.0, -2.0, 3.0), lambda t: np.sin(3 * t) + 0.5 * np.cos(0.7 * t)),
        ("chain of 4 integrators (n = 4)", chain_params(4), CanonicalPlant((0.0,) * 4, (1.0,)),
         np.ones(4), lambda t: np.sin(t)),
        ("chain of 8 integrators (n = 8)", chain_params(8), CanonicalPlant((0.0,) * 8, (1.0,)),
         np.ones(8), lambda t: np.sin(t)),
    ]


def dc_motor_params() -> dict:
    from fto_ros.runner.params_file import load_params_files
    flat = load_params_files([ROOT / "config" / "dc_motor_plant.yaml"])
    flat.update({"observer.type": "prescribed_time", "prescribed_time.T": 1.0,
                 "prescribed_time.l": [3.0, 3.0, 1.0]})
    return flat


def measure_checked(flat: dict, t, y, u, repeats: int) -> float:
    """Median time (us) of ``update_checked``, the best of ``repeats`` runs."""
    y = np.ascontiguousarray(y, dtype=float)
    u = np.ascontiguousarray(u, dtype=float)
    best = None
    for _ in range(repeats):
        obs = Runner(flat).observer
        obs.reset(t[0])
        obs.update_checked(t[0], y[0], u[0])
        got = np.median(time_calls(lambda i: obs.update_checked(t[i + 1], y[i + 1], u[i + 1]),
                                   len(t) - 1))
        best = got if best is None else min(best, got)
    return float(best)


def stream(plant: CanonicalPlant, x0, ufun, n: int, h: float = 1e-3):
    """Exact samples of the plant with the input held between them."""
    A, B = plant.matrices()
    k = plant.n
    M = np.zeros((k + 1, k + 1))
    M[:k, :k] = A * h
    M[:k, k] = B * h
    E = expm(M)
    t = np.arange(n) * h
    u = ufun(t)
    x = np.zeros((n, k))
    x[0] = x0
    for i in range(n - 1):
        x[i + 1] = E[:k, :k] @ x[i] + E[:k, k] * u[i]
    return t, x[:, :1].copy(), u[:, None].copy()


#: (label, prescribed_time parameters) of the mode comparison; the cap g_max = 1e3 ends
#: Example 1's windows 79 ms before T
MODES = [
    ("restart at T (default)", {}),
    ("restart, g_max = 1e3", {"g_max": 1e3}),
    ("stop, g_max = 1e3", {"mode": "stop", "g_max": 1e3}),
    ("constant, g_max = 1e3", {"mode": "constant", "g_max": 1e3}),
]
NOISE = (0.0, 1e-4, 1e-3)


def run_modes(duration: float = 20.0, seed: int = 1):
    """{(label, sigma): (t, largest gain, error norm, observer)} on Example 1."""
    flat0 = load_params_file(ROOT / "config" / "double_integrator_prescribed_time.yaml")
    t, y, u = stream(DOUBLE_INTEGRATOR, (20.0, 1.0), lambda t: np.sin(10 * t) + np.cos(t),
                     int(round(duration / 1e-3)) + 1)
    A, B = DOUBLE_INTEGRATOR.matrices()
    x = np.zeros((len(t), 2))
    x[0] = (20.0, 1.0)
    E = expm(np.block([[A * 1e-3, B[:, None] * 1e-3], [np.zeros((1, 3))]]))
    for i in range(len(t) - 1):
        x[i + 1] = E[:2, :2] @ x[i] + E[:2, 2] * u[i, 0]
    out = {}
    for sigma in NOISE:
        noise = np.random.default_rng(seed).normal(0.0, sigma, len(t)) if sigma else np.zeros(len(t))
        for label, over in MODES:
            flat = dict(flat0)
            flat.update({f"prescribed_time.{k}": v for k, v in over.items()})
            obs = Runner(flat).observer
            obs.reset(t[0])
            g, e = np.empty(len(t)), np.empty(len(t))
            for i in range(len(t)):
                obs.update(t[i], y[i] + noise[i], u[i])
                g[i] = float(np.max(np.abs(obs.gains)))
                e[i] = float(np.linalg.norm(x[i] - obs.estimate))
            out[(label, sigma)] = (t, g, e, obs)
    return out


def modes_table(res) -> str:
    head = "| mode | window end (s after start) | " + " | ".join(
        f"max \\|x - x_hat\\| after 5 s, sigma = {s:g}" for s in NOISE) + " |"
    rows = [head, "|" + "---|" * (2 + len(NOISE))]
    for label, _ in MODES:
        t, _, _, obs = res[(label, 0.0)]
        cells = []
        for sigma in NOISE:
            t, _, e, _ = res[(label, sigma)]
            cells.append(f"{e[t >= 5.0].max():.2g}")
        rows.append(f"| {label} | {obs.s_end:.4f} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def modes_plot(res, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(9.0, 8.0), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    colors = ["tab:blue", "tab:orange", "tab:red", "tab:green"]
    for (label, _), c in zip(MODES, colors):
        t, g, e0, _ = res[(label, 0.0)]
        _, _, e1, _ = res[(label, NOISE[-1])]
        axes[0].semilogy(t, np.maximum(g, 1e-1), color=c, linewidth=0.9, label=label)
        axes[1].semilogy(t, np.maximum(e0, 1e-16), color=c, linewidth=0.9, label=label)
        axes[2].semilogy(t, np.maximum(e1, 1e-16), color=c, linewidth=0.9, label=label)
    axes[0].set_ylabel("largest gain |g_i|\n(stop: 0, drawn at 0.1)")
    axes[1].set_ylabel("|x - x_hat|, exact y")
    axes[2].set_ylabel(f"|x - x_hat|, y + noise\nsigma = {NOISE[-1]:g}")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        for k in range(1, 4):
            ax.axvline(5.0 * k, color="gray", linestyle=":", linewidth=0.8)
    axes[0].legend(loc="upper center", ncol=2, fontsize=8, bbox_to_anchor=(0.5, 1.32), frameon=False)
    axes[-1].set_xlabel("time (s); dotted: t0 + k T, T = 5 s")
    fig.suptitle("prescribed_time after T: Example 1 (double integrator, x(0) = (20, 1), 1 kHz)",
                 fontsize=10, y=0.995)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.97))
    fig.savefig(path, format="png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=3, help="best-of repeats of each measurement")
    ap.add_argument("--modes", action="store_true", help="compare the continuous-operation modes")
    ap.add_argument("--plot", type=Path, help="with --modes: write the comparison figure here")
    args = ap.parse_args(argv)
    if args.modes:
        res = run_modes()
        print(modes_table(res))
        if args.plot:
            modes_plot(res, args.plot)
            print(f"\nwrote {args.plot}")
        return 0
    base = matvec_baseline(args.samples, args.repeats)
    runs = [(label, flat, stream(plant, x0, ufun, args.samples))
            for label, flat, plant, x0, ufun in cases()]
    runs.append(("dc_motor_plant.yaml, T = 1 s (n = 3, F, state map)", dc_motor_params(),
                 bench_update.stream(args.samples)))
    rows, checked = [], []
    for label, flat, (t, y, u) in runs:
        rows.append((label, *measure(flat, t, y, u, args.repeats)))
        checked.append(measure_checked(flat, t, y, u, args.repeats))
    print(f"numpy baseline (3x3 matvec): {base:.2f} us\n")
    print("| prescribed_time | update p50 (us) | update p99 (us) | update_checked p50 (us) | "
          "runner.process p50 (us) | runner.process p99 (us) | update / matvec | "
          "update_checked / matvec | process / matvec |")
    print("|---|---|---|---|---|---|---|---|---|")
    for (name, p50, p99, r50, r99), c50 in zip(rows, checked):
        print(f"| {name} | {p50:.1f} | {p99:.1f} | {c50:.1f} | {r50:.1f} | {r99:.1f} | "
              f"{p50 / base:.1f}x | {c50 / base:.1f}x | {r50 / base:.1f}x |")
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
