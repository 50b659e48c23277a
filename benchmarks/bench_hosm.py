"""Cost of the ``hosm`` observer: update time per sample and replay speed (in-process, no ROS).

1. Median / p99 of one ``HosmObserver.update`` and one ``Runner.process`` call (us) for the
   shipped configs (on their own plant's data) and for integrator chains of order n = 1..6
   (strongly observable, unknown input identified with k = 0, so the differentiator has
   order n), with the ratio to a 3x3 numpy matvec timed in the same run.
2. Replay speed (bag seconds per wall second) of ``fto-replay`` on the 1 kHz bags, with where
   the time goes (per sample).

    python benchmarks/bench_hosm.py [--samples N] [--repeats R] [--no-replay]
    python benchmarks/bench_hosm.py --study     # Example 1/2 reproduction tables + docs/hosm_*.png

Prints markdown tables (pasted into docs/hosm.md).  ``--study`` runs the paper's Example 1
(sampling steps 1e-4, 1e-3, 1e-2 without noise; the 0.1 output noise at 1 kHz) and Example 2
on exact simulations (plant + exosystem of zeta stepped with expm) and writes the plots.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_update import matvec_baseline, measure  # noqa: E402

from fto_ros.models import MODELS  # noqa: E402
from fto_ros.models.simulate import simulate  # noqa: E402
from fto_ros.runner.params_file import load_params_files  # noqa: E402
from fto_ros.runner.plant_files import params_files  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = [("fld_example1_hosm.yaml", "fld_example1"), ("fld_example2_hosm.yaml", "fld_example2"),
           ("dc_motor_hosm.yaml", "dc_motor_load")]
BAGS = [("fld_example1", "fld_example1_hosm.yaml"), ("fld_example2", "fld_example2_hosm.yaml"),
        ("dc_motor_load", "dc_motor_hosm.yaml")]


def model_stream(model: str, n: int, h: float = 1e-3):
    spec = MODELS[model]
    t = np.arange(n) * h
    sim = simulate(spec.make_rhs(dict(spec.default_params)), spec.default_x0, t, spec.default_input)
    return t, sim.x[:, :1].copy(), sim.u.reshape(n, spec.m).copy()


def chain_flat(n: int) -> dict:
    """Integrator chain y^(n) = -sum a_i y^(i) + zeta, poles of A - L C at -1..-n, k = 0."""
    A = np.diag(np.ones(n - 1), 1) if n > 1 else np.zeros((1, 1))
    A[-1] = -np.poly(-np.arange(1.0, n + 1) * 0.5)[1:][::-1]
    C = np.zeros(n)
    C[0] = 1.0
    D = np.zeros(n)
    D[-1] = 1.0
    return {"observer.type": "hosm", "hosm.n_states": n, "hosm.A": A.ravel().tolist(),
            "hosm.C": C.tolist(), "hosm.D": D.tolist(),
            "hosm.poles": (-np.arange(1.0, n + 1)).tolist(), "hosm.M": [2.0],
            "hosm.smoothness_order": 0}


def chain_stream(n_states: int, n: int, h: float = 1e-3):
    t = np.arange(n) * h
    y = (np.sin(t) + 0.3 * np.cos(3 * t))[:, None]
    return t, y, np.zeros((n, 0))


def update_table(samples: int, repeats: int) -> None:
    base = matvec_baseline(samples, repeats)
    print(f"numpy baseline (3x3 matvec): {base:.2f} us\n")
    print("| config / plant | n | differentiator order | update p50 (us) | update p99 (us) | "
          "runner.process p50 (us) | runner.process p99 (us) | update p50 / matvec |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for cfg, model in CONFIGS:
        flat = load_params_files(params_files(ROOT / "config" / cfg))
        t, y, u = model_stream(model, samples)
        rows.append((cfg, flat, measure(flat, t, y, u, repeats)))
    for n in range(1, 7):
        flat = chain_flat(n)
        t, y, u = chain_stream(n, samples)
        rows.append(("integrator chain, k = 0", flat, measure(flat, t, y, u, repeats)))
    from fto_ros.runner import Runner
    for name, flat, (p50, p99, r50, r99) in rows:
        obs = Runner(flat).observer
        print(f"| {name} | {obs.n_states} | {', '.join(map(str, obs.orders))} | {p50:.1f} | "
              f"{p99:.1f} | {r50:.1f} | {r99:.1f} | {p50 / base:.0f}x |")


def replay_table(repeats: int) -> None:
    from fto_ros.replay.replay import replay
    print("\n| bag (1 kHz) | config | replay speed (x real time) | read+decode (us/sample) | "
          "runner (us/sample) | serialise+write (us/sample) | total (us/sample) |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for bag, cfg in BAGS:
            best = None
            for _ in range(repeats):
                m = replay(ROOT / "bags" / bag, params_files(ROOT / "config" / cfg), Path(tmp) / "out",
                           overwrite=True, progress=False, plot=False)
                if best is None or m["replay_speed_x_realtime"] > best["replay_speed_x_realtime"]:
                    best = m
            ns = best["sample_count"]
            tm = best["timing_s"]
            us = {k: tm[k] / ns * 1e6 for k in ("read_decode", "runner", "serialize_write",
                                                 "replay_total")}
            print(f"| {bag} | {cfg} | {best['replay_speed_x_realtime']:.1f} | "
                  f"{us['read_decode']:.1f} | {us['runner']:.1f} | {us['serialize_write']:.1f} | "
                  f"{us['replay_total']:.1f} |")


# -- the paper's examples -------------------------------------------------------------------
def exact_fld(example: int, t: np.ndarray):
    """x(t), zeta(t) of Example 1 or 2, exactly: plant + exosystem of zeta stepped with expm."""
    from scipy.linalg import expm

    from fto_ros.models import fld_examples as fx
    A, D, x0 = ((fx.EXAMPLE1_A, fx.EXAMPLE1_D, fx.EXAMPLE1_X0) if example == 1
                else (fx.EXAMPLE2_A, fx.EXAMPLE2_D, fx.EXAMPLE2_X0))
    n = A.shape[0]
    S = np.zeros((5, 5))      # w = (cos .5t, sin .5t, cos t, sin t, 1)
    S[0, 1], S[1, 0], S[2, 3], S[3, 2] = -0.5, 0.5, -1.0, 1.0
    E = np.array([1.0, 0.0, 0.0, 0.5, 0.5])
    Aa = np.zeros((n + 5, n + 5))
    Aa[:n, :n], Aa[:n, n:], Aa[n:, n:] = A, np.outer(D, E), S
    Phi = expm(Aa * (t[1] - t[0]))
    xa = np.concatenate([x0, [1.0, 0.0, 1.0, 0.0, 1.0]])
    X, Z = np.empty((len(t), n)), np.empty(len(t))
    for k in range(len(t)):
        if k:
            xa = Phi @ xa
        X[k], Z[k] = xa[:n], E @ xa[n:]
    return X, Z


def run_hosm(cfg: dict, t, y):
    from fto_ros.core.params import resolve
    from fto_ros.observers.base import SampleRejected
    from fto_ros.observers.hosm import HosmObserver
    obs = HosmObserver(resolve(HosmObserver.PARAMS, cfg, "hosm."))
    X = np.full((len(t), obs.n_states), np.nan)
    Z = np.full(len(t), np.nan)
    obs.reset(t[0])
    u = np.zeros(0)
    for k in range(len(t)):
        try:
            obs.update(t[k], y[k:k + 1], u)
        except SampleRejected:
            return X, Z, False
        X[k] = obs.estimate
        if obs.unknown_input is not None:
            Z[k] = obs.unknown_input[0]
    return X, Z, True


def ex1_cfg(**kw) -> dict:
    from fto_ros.models import fld_examples as fx
    c = dict(n_states=4, A=fx.EXAMPLE1_A.ravel().tolist(), C=[1.0, 0, 0, 0],
             D=fx.EXAMPLE1_D.tolist(), L=[5.0, 5, 5, 5])
    c.update(kw)
    return c


PAPER_GAINS = [1.1, 1.5, 2.0, 3.0, 5.0, 8.0]
OBSERVERS = {
    "6.1.1 states (M = 2)": dict(M=[2.0], identify_unknown_input=False),
    "6.1.2 identification (k = 1, M = 1)": dict(M=[1.0], smoothness_order=1),
}
SCHEMES = {
    "eigenvalue_matched rho=2": dict(),
    "eigenvalue_matched rho=1": dict(differentiator_rho=1.0),
    "livne_levant (paper gains)": dict(differentiator_scheme="livne_levant",
                                       differentiator_gains=PAPER_GAINS),
    "euler (paper gains)": dict(differentiator_scheme="euler", differentiator_gains=PAPER_GAINS),
}
WINDOW = (5.0, 10.0)


def _fmt_err(X, Z, x, z, m, ok):
    if not ok:
        return "diverged (non-finite: sample rejected) | | | | "
    e = np.abs(X - x)[m].max(axis=0)
    ez = np.abs(Z - z)[m].max() if np.isfinite(Z[m]).all() else float("nan")
    return " | ".join(f"{v:.2g}" for v in e) + " | " + ("-" if np.isnan(ez) else f"{ez:.2g}")


def study() -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from fto_ros.models import fld_examples as fx
    docs = ROOT / "docs"
    print(f"### Example 1, sampling-step study (no noise; max |error| over t in {WINDOW})\n")
    print("| observer | scheme | step (s) | x1 | x2 | x3 | x4 | zeta |")
    print("|---|---|---|---|---|---|---|---|")
    curves = {}
    for h in (1e-4, 1e-3, 1e-2):
        t = np.arange(int(round(10.0 / h)) + 1) * h
        x, z = exact_fld(1, t)
        m = (t >= WINDOW[0]) & (t <= WINDOW[1])
        for oname, ocfg in OBSERVERS.items():
            for sname, scfg in SCHEMES.items():
                if sname == "eigenvalue_matched rho=1":
                    continue
                X, Z, ok = run_hosm(ex1_cfg(**ocfg, **scfg), t, x[:, 0])
                print(f"| {oname} | {sname} | {h:g} | {_fmt_err(X, Z, x, z, m, ok)} |")
                if sname.startswith("eigenvalue") and oname.startswith("6.1.2"):
                    curves[h] = (t, np.abs(X - x), np.abs(Z - z), Z, z)
    print(f"\n### Example 1 with the paper's output noise 0.1 sin(1037|cos 687t|), step 1e-3 "
          f"(max |error| over t in {WINDOW}; RMS in brackets)\n")
    print("| observer | scheme | x1 | x2 | x3 | x4 | zeta |")
    print("|---|---|---|---|---|---|---|")
    t = np.arange(10001) * 1e-3
    x, z = exact_fld(1, t)
    noise = np.array([fx.example1_noise(s)[0] for s in t])
    m = (t >= WINDOW[0]) & (t <= WINDOW[1])
    for oname, ocfg in OBSERVERS.items():
        for sname, scfg in SCHEMES.items():
            X, Z, ok = run_hosm(ex1_cfg(**ocfg, **scfg), t, x[:, 0] + noise)
            if not ok:
                print(f"| {oname} | {sname} | diverged | | | | |")
                continue
            e = np.abs(X - x)[m]
            ez = np.abs(Z - z)[m]
            cells = [f"{a.max():.2g} ({np.sqrt(np.mean(a * a)):.2g})" for a in e.T]
            zc = "-" if np.isnan(ez).all() else f"{ez.max():.2g} ({np.sqrt(np.mean(ez * ez)):.2g})"
            print(f"| {oname} | {sname} | {' | '.join(cells)} | {zc} |")

    print(f"\n### Example 1, states-only observer (6.1.1), noise amplitude eps scaled, step 1e-3 "
          f"(max |error| over t in {WINDOW})\n")
    print("| eps | scheme | x1 | x2 | x3 | x4 |")
    print("|---|---|---|---|---|---|")
    for eps in (0.1, 0.01, 0.001):
        for sname in ("eigenvalue_matched rho=1", "euler (paper gains)"):
            X, _, ok = run_hosm(ex1_cfg(**OBSERVERS["6.1.1 states (M = 2)"], **SCHEMES[sname]), t,
                                x[:, 0] + noise * (eps / 0.1))
            e = np.abs(X - x)[m].max(axis=0)
            print(f"| {eps:g} | {sname} | " + " | ".join(f"{v:.2g}" for v in e) + " |")

    # plot 1: errors vs time for the three steps (identification observer, default scheme)
    fig = Figure(figsize=(9, 7.5), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    colors = {1e-4: "tab:blue", 1e-3: "tab:orange", 1e-2: "tab:green"}
    for h, (tt, E, EZ, _, _) in sorted(curves.items()):
        for ax, series, label in ((axes[0], E[:, 1], "x2"), (axes[1], E[:, 3], "x4"),
                                  (axes[2], EZ, "zeta")):
            ax.semilogy(tt, np.maximum(series, 1e-16), color=colors[h], linewidth=0.7,
                        label=f"step {h:g} s")
            ax.set_ylabel(f"|{label} error|")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.set_ylim(1e-13, 1e3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title("Example 1 (Fridman, Levant & Davila 2007), no noise:\nhosm with identification "
                      "(k = 1, M = 1), eigenvalue-matched differentiator", fontsize=9)
    axes[-1].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(docs / "hosm_fld_example1_steps.png")

    # plot 2: the unknown input, estimate vs truth (step 1e-3), and its error for the 3 steps
    fig = Figure(figsize=(9, 6), dpi=100)
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    tt, _, _, Zh, zt = curves[1e-3]
    ax1.plot(tt, zt, color="black", linewidth=1.2, label="zeta (truth)")
    ax1.plot(tt, Zh, color="tab:orange", linestyle="--", linewidth=1.0, label="zeta_hat (step 1e-3)")
    ax1.set_ylim(-1.5, 3.0)
    ax1.legend(loc="upper right", fontsize=8)
    ax1.set_ylabel("zeta")
    ax1.grid(True, alpha=0.3)
    for h, (tt, _, EZ, _, _) in sorted(curves.items()):
        ax2.semilogy(tt, np.maximum(EZ, 1e-16), color=colors[h], linewidth=0.7, label=f"step {h:g} s")
    ax2.set_ylim(1e-9, 1e3)
    ax2.set_ylabel("|zeta - zeta_hat|")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(loc="upper right", fontsize=8)
    ax2.set_xlabel("t (s)")
    ax1.set_title("Example 1: unknown-input identification (29), no noise", fontsize=9)
    fig.tight_layout()
    fig.savefig(docs / "hosm_fld_example1_unknown_input.png")

    # Example 2: canonical-coordinate errors
    t = np.arange(10001) * 1e-3
    x, z = exact_fld(2, t)
    from fto_ros.models import fld_examples as fx2
    cfg = dict(n_states=6, A=fx2.EXAMPLE2_A.ravel().tolist(), C=[1.0, 0, 0, 0, 0, 0],
               D=fx2.EXAMPLE2_D.tolist(), L=fx2.EXAMPLE2_L.tolist(), M=[2.0], smoothness_order=0)
    X, Z, _ = run_hosm(cfg, t, x[:, 0])
    Po = np.vstack([fx2.EXAMPLE2_C @ np.linalg.matrix_power(fx2.EXAMPLE2_A, i) for i in range(4)])
    eO = np.abs((X - x) @ Po.T)
    print("\n### Example 2 (no noise, step 1e-3): max |error| per window\n")
    print("| window (s) | e_O1 | e_O2 | e_O3 | e_O4 | x5 | x6 | zeta |")
    print("|---|---|---|---|---|---|---|---|")
    for a, b in ((1, 2), (2, 3), (3, 4), (4, 6), (6, 8), (8, 10)):
        m = (t >= a) & (t <= b)
        vals = list(eO[m].max(axis=0)) + list(np.abs(X - x)[m][:, 4:].max(axis=0)) + \
            [np.abs(Z - z)[m].max()]
        print(f"| [{a}, {b}] | " + " | ".join(f"{v:.2g}" for v in vals) + " |")
    fig = Figure(figsize=(9, 4.5), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.subplots(1, 1)
    for i in range(4):
        ax.semilogy(t, np.maximum(eO[:, i], 1e-16), linewidth=0.8,
                    label=f"e_O{i + 1} = C A^{i} (x_hat - x)")
    ax.semilogy(t, np.maximum(np.abs(X - x)[:, 4], 1e-16), linewidth=0.8, label="x5")
    ax.semilogy(t, np.maximum(np.abs(Z - z), 1e-16), linewidth=0.8, label="zeta")
    ax.set_ylim(1e-12, 1e4)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=3, loc="upper right")
    ax.set_xlabel("t (s)")
    ax.set_title("Example 2 (r = 3 < n = 6): e_O1..e_O3 exact in finite time, the rest asymptotic "
                 "(zeros -1, -2, -3)", fontsize=9)
    fig.tight_layout()
    fig.savefig(docs / "hosm_fld_example2.png")
    print("\nwrote docs/hosm_fld_example1_steps.png, docs/hosm_fld_example1_unknown_input.png, "
          "docs/hosm_fld_example2.png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=3000)
    ap.add_argument("--repeats", type=int, default=3, help="best-of repeats of each measurement")
    ap.add_argument("--no-replay", action="store_true")
    ap.add_argument("--study", action="store_true", help="the paper's examples: tables + plots")
    args = ap.parse_args(argv)
    if args.study:
        study()
        return 0
    update_table(args.samples, args.repeats)
    if not args.no_replay:
        replay_table(args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
