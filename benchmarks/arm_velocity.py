"""Issue 26 item 1, measured: joint velocities of the Panda-class arm by ``arm_kalman`` (the
Kalman filter on the URDF's rigid-body model, observers/arm_kalman) beside the driver's
backward difference, per joint, on the conditions of benchmarks/arm_class.py (clean; +-50 us
jitter and 0.2 % lost messages; 5 % inertia error and unknown friction; all of them).

The estimator runs through the runner exactly as the node and fto-replay run it
(runner.Runner on config/panda_arm_kalman.yaml's parameters, one JointState message per
received sample, stamps as recorded); the error is against the simulator's true velocity at
the actual instant, over every received sample after the first WARMUP s (the filter starts
at v = 0), rad/s RMS per joint; the backward difference over the same samples. Peak error
and its duration (above 3x the joint's RMS) near the pushes and the velocity reversals are
printed beside.

    PYTHONPATH=. python benchmarks/arm_velocity.py --out DIR [--seeds 1,2] [--duration 15]
        [--conditions clean,jitter+loss,model+friction,all] [--reuse] [--set NAME=VALUE ...]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from arm_class import ARM, _pool, arm_columns, contact_windows, simulate_condition  # noqa: E402
from fto_ros.cli.arm_bag import read_arm_bag  # noqa: E402
from fto_ros.runner.params_file import load_params_file  # noqa: E402
from fto_ros.runner.runner import Runner  # noqa: E402

CONFIG = ROOT / "config" / "panda_arm_kalman.yaml"
CONDITIONS = ("clean", "jitter+loss", "model+friction", "all")
WARMUP = 0.5


def run_filter(run, overrides=None) -> np.ndarray:
    """The filter's velocity estimate (N, 7) at every received sample (NaN: none)."""
    flat = load_params_file(CONFIG)
    flat["plant.urdf"] = str(ROOT / flat["plant.urdf"])
    flat.update(overrides or {})
    r = Runner(flat)
    obs = r.observer
    names = list(run.names)
    ci = [names.index(j) for j in obs.joints]
    pi = [names.index(j) for j in obs.passive_joints]
    y = run.q_measured[:, ci]
    u = np.hstack([run.effort[:, ci], run.q_measured[:, pi]])
    n = len(ci)
    V = np.full((run.t.size, n), np.nan)
    t = run.stamp_ns * 1e-9 + 1.0
    for k in range(run.t.size):
        try:
            obs.update(float(t[k]), y[k], u[k])
        except Exception:                 # a rejected sample: no estimate there
            continue
        V[k] = obs.estimate[n:]
    return V


def score(run, meta, overrides=None) -> dict:
    c = arm_columns(run)
    V = run_filter(run, overrides)
    truth = run.v[:, c]
    keep = (run.t >= WARMUP) & np.all(np.isfinite(V), axis=1)
    err = V - truth
    dt = np.diff(run.stamp_ns) * 1e-9
    bd = np.vstack([np.full((1, len(c)), np.nan),
                    np.diff(run.q_measured[:, c], axis=0) / dt[:, None]]) - truth
    rms = np.sqrt(np.mean(err[keep] ** 2, axis=0))
    rms_bd = np.sqrt(np.mean(bd[keep] ** 2, axis=0))
    peaks = []
    for a, b in contact_windows(meta):
        w = keep & (run.t >= a) & (run.t < b + 0.3)
        e = np.abs(err[w])
        above = (e > 3 * rms).any(axis=1)
        peaks.append((float(e.max()), 1e3 * above.sum() / 1000.0))
    return {"rms": rms.tolist(), "bd": rms_bd.tolist(), "peaks": peaks}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True)
    p.add_argument("--seeds", default="1,2")
    p.add_argument("--duration", type=float, default=15.0)
    p.add_argument("--conditions", default=",".join(CONDITIONS))
    p.add_argument("--reuse", action="store_true")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    args = p.parse_args(argv)
    over = {}
    for s in args.set:
        k, v = s.split("=", 1)
        over[k] = [float(x) for x in v.split(",")] if "," in v or k.endswith(
            ("noise", "rate", "resolution")) else float(v)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    print("| condition | estimator | " + " | ".join(f"j{i}" for i in range(1, 8))
          + " | worst ratio |")
    print("|---|---|" + "---|" * 8)
    for name in args.conditions.split(","):
        res = []
        for seed in (int(s) for s in args.seeds.split(",")):
            t0 = time.perf_counter()
            bag = simulate_condition(name, seed, args.out, args.duration, args.reuse)
            run, meta = read_arm_bag(bag)
            res.append(score(run, meta, over))
            print(f"({name} seed {seed}: {time.perf_counter() - t0:.0f} s; pushes: peak error "
                  f"(rad/s), ms above 3x RMS: {res[-1]['peaks']})", file=sys.stderr)
        kf, bd = _pool([r["rms"] for r in res]), _pool([r["bd"] for r in res])
        print(f"| {name} | backward difference | " + " | ".join(f"{x:.3g}" for x in bd) + " | |")
        print(f"| {name} | arm_kalman | " + " | ".join(f"{x:.3g}" for x in kf)
              + f" | {np.max(kf / bd):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
