"""Reproduce the numbers and figures of docs/global_norm.md (relative errors on the bags).

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python scripts/global_norm_figures.py

Drives the registered observers (the same classes the node and fto-replay run) over
bags/cubic_escape and bags/van_der_pol with the configs in config/, and computes the
relative error |x - x_hat| / (1 + |x|) against /<system>/true_state.
"""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fto_ros.bag.reader import read_messages  # noqa: E402
from fto_ros.observers import REGISTRY  # noqa: E402
from fto_ros.core.params import resolve  # noqa: E402
from fto_ros.runner.settings import load_params_file  # noqa: E402

ESCAPE = 3.8541


def build(config: Path, **override):
    flat = load_params_file(config)
    typ = flat["observer.type"]
    cls = REGISTRY[typ]
    vals = {k[len(typ) + 1:]: v for k, v in flat.items() if k.startswith(typ + ".")}
    vals.update(override)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ob = cls(resolve(cls.PARAMS, vals, typ + "."))
    return ob, flat.get("observer.initial_estimate") or None


def load_bag(bag: Path, system: str):
    ys, xs = {}, {}
    for topic, t_ns, msg in read_messages(bag):
        if topic == f"/{system}/measured_output":
            ys[t_ns] = float(msg.data[0])
        elif topic == f"/{system}/true_state":
            xs[t_ns] = np.array(msg.data, dtype=float)
    ts = sorted(ys)
    return np.array(ts) / 1e9, np.array([ys[t] for t in ts]), np.array([xs[t] for t in ts])


def drive(ob, x0_hat, t, y, X):
    ob.reset(float(t[0]), x0_hat)
    est = np.empty_like(X)
    for i, (ti, yi) in enumerate(zip(t, y)):
        ob.update(float(ti), np.array([yi]), np.zeros(0))
        est[i] = ob.estimate
    rel = np.linalg.norm(X - est, axis=1) / (1.0 + np.linalg.norm(X, axis=1))
    return est, rel


def main():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = []
    t, y, X = load_bag(ROOT / "bags/cubic_escape", "cubic_escape")
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, cfg, kw in (("global_norm", "cubic_escape_global_norm", {}),
                          ("high_gain L=20, M=10", "cubic_escape_high_gain", {}),
                          ("high_gain L=20, no saturation", "cubic_escape_high_gain",
                           {"saturation": 0.0})):
        ob, x0h = build(ROOT / "config" / f"{cfg}.yaml", **kw)
        _, rel = drive(ob, x0h, t, y, X)
        ax.semilogy(t, np.maximum(rel, 1e-16), label=name)
        at = [np.searchsorted(t, v) for v in (0.5, 1.0, 2.0, 3.0, 3.5, 3.7, 3.8)]
        rows.append(("cubic_escape", name, [rel[min(i, len(t) - 1)] for i in at]))
    ax.axvline(ESCAPE, color="k", ls="--", label=f"escape t_e = {ESCAPE} s")
    ax.axvline(t[-1], color="gray", ls=":", label=f"bag ends {t[-1]:.2f} s")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("|x - x_hat| / (1 + |x|)")
    ax.set_title("cubic_escape: x0' = x1, x1' = -x1 + x0^3, x(0) = (0.6, 0), x_hat(0) = 0")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(ROOT / "docs/global_norm_cubic_escape.png", dpi=110)
    print("cubic_escape: |x| at", [f"t={v}: {np.linalg.norm(X[np.searchsorted(t, v) - (v == 3.8)]):.4g}"
                                   for v in (0.5, 1, 2, 3, 3.5, 3.7, 3.8)])

    t, y, X = load_bag(ROOT / "bags/van_der_pol", "van_der_pol")
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, cfg, kw in (("global_norm", "van_der_pol_global_norm", {}),
                          ("global_norm (reduced form)", "van_der_pol_global_norm", {"form": "reduced"}),
                          ("high_gain L=20, M=5", "van_der_pol_high_gain", {})):
        ob, x0h = build(ROOT / "config" / f"{cfg}.yaml", **kw)
        _, rel = drive(ob, x0h, t, y, X)
        ax.semilogy(t, np.maximum(rel, 1e-16), label=name)
        at = [np.searchsorted(t, v) for v in (0.05, 0.1, 0.2, 0.5, 1.0, 5.0, 10.0)]
        rows.append(("van_der_pol", name, [rel[min(i, len(t) - 1)] for i in at]))
    ax.set_xlabel("t (s)")
    ax.set_ylabel("|x - x_hat| / (1 + |x|)")
    ax.set_title("van_der_pol: x(0) = (2, 0), x_hat(0) = (10, -10)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(ROOT / "docs/global_norm_van_der_pol.png", dpi=110)
    print("| bag | observer | relative error at the times |")
    for bag, name, vals in rows:
        print(f"| {bag} | {name} | " + " | ".join(f"{v:.2e}" for v in vals) + " |")


if __name__ == "__main__":
    main()
