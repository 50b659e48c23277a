"""External joint torques and collisions of the 7-joint arm: the package's windowed momentum
estimator against the generalized-momentum observer (GMO, on backward-difference or
differentiator velocities) and finite differences, measured in one run.

Per estimator and bag (bags/arm7_*), with the detector of fto_ros.rigid.collision calibrated
on the bag's estimates over t in [0.5, 2.5] s (no contact there) at a bound of 1e-2 false
alarms per hour:

- velocity RMS error (rad/s, every joint, t >= 0.5 s);
- tau_ext RMS error in free motion (Nm; t >= 0.5 s, outside [contact start, end + 0.3 s]):
  the worst joint and the RMS over the joints;
- tau_ext max error (Nm, t >= 0.5 s, contacts included);
- detection delay after the contact's start (ms) and false alarms outside the contacts.

"At the same detection delay": the GMO's gain is swept; for the estimator's delay D, the
GMO settings whose delay is <= D on every contact bag are compared, the least noisy one.
``--long S`` adds S s of contact-free motion simulated here (seed 21; not committed) for the
false alarms of each estimator at its calibrated thresholds.

    PYTHONPATH=. python benchmarks/bench_external_torque.py [--long 600] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fto_ros.cli.simulate_arm import read_arm_bag  # noqa: E402
from fto_ros.models.arm import ArmSettings, simulate_arm  # noqa: E402
from fto_ros.rigid import load_model  # noqa: E402
from fto_ros.rigid.collision import CollisionDetector  # noqa: E402
from fto_ros.rigid.external_torque import (FiniteDifference, MomentumObserver,  # noqa: E402
                                           WindowEstimator)

BAGS = ["arm7_contact_link6", "arm7_contact_tool", "arm7_free"]
URDF = ROOT / "urdf" / "arm7.urdf"
JOINTS = [f"joint_a{i}" for i in range(1, 8)]
BOUND = 1e-2
CALIBRATION = (0.5, 2.5)


def contact_intervals(run):
    on = run.contact[:, 0] > 0
    edges = np.flatnonzero(np.diff(on.astype(int)))
    starts = [run.t[i + 1] for i in edges if not on[i]]
    ends = [run.t[i + 1] for i in edges if on[i]]
    return list(zip(starts, ends))


def estimate(est, run):
    N, n = run.t.size, run.q.shape[1]
    E, V = np.full((N, n), np.nan), np.zeros((N, n))
    for k in range(N):
        out = est.update(run.t[k], run.q_measured[k], run.tau[k])
        if out is not None:
            E[k] = out
        V[k] = est.velocity
    return E, V


def evaluate(est, run):
    E, V = estimate(est, run)
    t = run.t
    contacts = contact_intervals(run)
    free = t >= 0.5
    for a, b in contacts:
        free &= ~((t >= a) & (t < b + 0.3))
    cal = (t >= CALIBRATION[0]) & (t < CALIBRATION[1])
    det = CollisionDetector(run.q.shape[1], rate=1000.0, false_alarms_per_hour=BOUND,
                            sigma=None, calibration=CALIBRATION[1] - CALIBRATION[0])
    for k in np.flatnonzero(cal):
        det.update(t[k], E[k])
    alarms = []
    for k in np.flatnonzero(t >= CALIBRATION[1]):
        ev = det.update(t[k], E[k])
        if ev is not None:
            alarms.append(ev)
    delays, false_alarms = [], 0
    for ev in alarms:
        inside = [a for a, b in contacts if a <= ev.t < b + 0.3]
        if not inside:
            false_alarms += 1
    for a, b in contacts:
        hits = [ev.t for ev in alarms if a <= ev.t < b + 0.3]
        delays.append((min(hits) - a) * 1e3 if hits else math.inf)
    err = E - run.tau_ext
    rms = np.sqrt(np.nanmean(err[free] ** 2, axis=0))
    return {"velocity_rms": float(np.sqrt(np.mean((V - run.v)[t >= 0.5] ** 2))),
            "free_rms_joints": rms.tolist(), "free_rms_worst": float(rms.max()),
            "free_rms_all": float(np.sqrt(np.mean(rms ** 2))),
            "max_error": float(np.nanmax(np.abs(err[t >= 0.5]))),
            "delays_ms": delays, "false_alarms": false_alarms,
            "thresholds": det.threshold.tolist()}


def configs(model):
    out = {f"window T={T * 1e3:.0f} ms": (lambda T=T: WindowEstimator(model, window=T))
           for T in (0.02, 0.03, 0.04, 0.05)}
    for source, short in (("difference", "diff"), ("differentiator", "RED")):
        for K in (5, 10, 20, 50, 100, 200, 500):
            out[f"GMO K={K} ({short} velocity)"] = (
                lambda K=K, s=source: MomentumObserver(model, gain=K, velocity=s))
    out["finite difference"] = lambda: FiniteDifference(model, 1e-3)
    return out


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("--long", type=float, default=0.0, metavar="S")
    p.add_argument("--json", metavar="FILE")
    args = p.parse_args(argv)
    model = load_model(JOINTS, urdf=URDF)
    runs = {b: read_arm_bag(ROOT / "bags" / b)[0] for b in BAGS}
    results = {}
    started = time.perf_counter()
    for name, make in configs(model).items():
        results[name] = {b: evaluate(make(), run) for b, run in runs.items()}
    print(f"(bags: {time.perf_counter() - started:.0f} s)", file=sys.stderr)

    def summary(name):
        r = results[name]
        delay = max(d for b in BAGS for d in r[b]["delays_ms"])
        return (delay, max(r[b]["free_rms_worst"] for b in BAGS),
                max(r[b]["free_rms_all"] for b in BAGS),
                max(r[b]["velocity_rms"] for b in BAGS), max(r[b]["max_error"] for b in BAGS),
                sum(r[b]["false_alarms"] for b in BAGS))

    print("| estimator | velocity RMS err (rad/s) | tau_ext RMS err free, worst joint (Nm) | "
          "RMS over joints (Nm) | max err (Nm) | detection delay link6 / tool (ms) | "
          "false alarms (3 bags) |")
    print("|---|---|---|---|---|---|---|")
    for name in results:
        d, worst, allj, vel, mx, fa = summary(name)
        dl = " / ".join(f"{x:.0f}" for b in BAGS[:2] for x in results[name][b]["delays_ms"])
        print(f"| {name} | {vel:.2e} | {worst:.3g} | {allj:.3g} | {mx:.3g} | {dl} | {fa} |")
    print()
    print("| window | its delay (ms) | its worst-joint RMS | best GMO with delay <= it | "
          "that GMO's RMS | ratio |")
    print("|---|---|---|---|---|---|")
    chosen = {}
    for name in [n for n in results if n.startswith("window")]:
        d, worst, *_ = summary(name)
        ok = [(summary(g)[1], g) for g in results if g.startswith("GMO") and summary(g)[0] <= d]
        if ok:
            rms, g = min(ok)
            chosen[name] = g
            print(f"| {name} | {d:.0f} | {worst:.3g} | {g} | {rms:.3g} | {worst / rms:.2f} |")
        else:
            fastest = min((summary(g)[0], summary(g)[1], g) for g in results if g.startswith("GMO"))
            print(f"| {name} | {d:.0f} | {worst:.3g} | none (fastest: {fastest[2]}, "
                  f"{fastest[0]:.0f} ms) | {fastest[1]:.3g} | n/a |")
    if args.long > 0:
        t0 = time.perf_counter()
        run = simulate_arm(model, ArmSettings(duration=args.long, seed=21))
        print(f"\n(simulated {args.long:.0f} s in {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
        print(f"\n{args.long:.0f} s contact-free, thresholds calibrated on [0.5, 2.5] s, bound "
              f"{BOUND} per hour ({BOUND * args.long / 3600:.2g} expected at most):\n")
        print("| estimator | false alarms | tau_ext RMS err, worst joint (Nm) | max err (Nm) |")
        print("|---|---|---|---|")
        long_names = ["window T=30 ms", "window T=40 ms", *sorted(set(chosen.values())),
                      "GMO K=10 (diff velocity)"]
        results["long"] = {}
        for name in dict.fromkeys(long_names):
            r = evaluate(configs(model)[name](), run)
            results["long"][name] = r
            print(f"| {name} | {r['false_alarms']} | {r['free_rms_worst']:.3g} | "
                  f"{r['max_error']:.3g} |")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
