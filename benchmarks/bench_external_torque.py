"""External joint torques and collisions of the 7-joint arm: the windowed momentum estimator
(observer family ``external_torque``) against the generalized-momentum observer (family
``momentum_observer``, backward-difference velocity), accuracy and cost per sample, measured
in one run.

Each family is built by ``Runner`` from the node's parameters (urdf/arm7.urdf, the seven
joints, collision.false_alarms_per_hour 1e-2, the rest the defaults: calibration over the
first 2 s of estimates) and fed the committed bags (bags/arm7_*) message by message as the
replay feeds them (benchmarks/arm_runs.py: the JointState intake, ``process_block``); per
(estimator, bag), with the replay's rules:

- velocity RMS error (rad/s, every joint, t >= 0.5 s);
- tau_ext RMS error in free motion (Nm, worst joint): on the contact-free bag (and the long
  run), t >= 0.5 s, outside each contact and the 0.3 s after it;
- tau_ext max error in free motion (Nm, the same samples);
- detection delay after each contact's start (ms: a joint's contact flag rising);
  false alarms (rises outside [start, end + 0.3 s));
- settling: from the contact's start until the estimate of its largest joint torque stays
  within 10 % of that torque's peak until the contact ends (ms; inf: never);
- cost: the runner's wall time per message (us, the whole block call: intake rows excluded).

The comparisons: the momentum observer's gain is swept; for each gain, the least noisy
window whose detection delay (or settling time) is at most the observer's on both contact
bags, and the ratio of their free-motion RMS errors. ``--long S`` adds S s of contact-free
motion simulated here (seed 21; not committed) for the false alarms of the chosen
estimators; ``--long-cache FILE`` keeps that simulation.

    PYTHONPATH=. python benchmarks/bench_external_torque.py [--long 600] [--json FILE]
        [--windows 0.02,0.03,...] [--gains 2,5,...]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.arm_runs import arm_runner, feed, score  # noqa: E402
from fto_ros.cli.arm_bag import read_arm_bag  # noqa: E402

URDF = ROOT / "urdf" / "arm7.urdf"
JOINTS = [f"joint_a{i}" for i in range(1, 8)]
BAGS = ("arm7_contact_link6", "arm7_contact_tool", "arm7_free")
BOUND = 1e-2


def configs(windows, gains) -> dict:
    out = {f"window T={T * 1e3:.0f} ms": ("external_torque", {"external_torque__window": T})
           for T in windows}
    out.update({f"GMO K={K:g}": ("momentum_observer", {"momentum_observer__gain": K})
                for K in gains})
    return out


def evaluate(family: str, params: dict, run, meta) -> dict:
    r = arm_runner(family, JOINTS, urdf=URDF, collision__false_alarms_per_hour=BOUND, **params)
    cols = [list(run.names).index(j) for j in JOINTS]
    out = score(feed(r, run), run, meta, cols)
    obs = r.observer
    out["per_joint"] = [dict(joint=JOINTS[j], peak=peak, measured_ms=1e3 * got)
                        for j, peak, got in out["per_joint"]]
    out["z"] = obs.z
    return out


def _numbers(text: str) -> list[float]:
    return [float(x) for x in text.split(",")]


def main(argv=None):
    p = argparse.ArgumentParser()
    p.add_argument("--long", type=float, default=0.0, metavar="S")
    p.add_argument("--long-cache", metavar="FILE", help="npz of the long run (made if missing)")
    p.add_argument("--json", metavar="FILE")
    p.add_argument("--windows", type=_numbers, default=[0.02, 0.03, 0.04, 0.05, 0.06, 0.08])
    p.add_argument("--gains", type=_numbers, default=[2, 5, 10, 20, 50, 100, 200])
    args = p.parse_args(argv)
    runs = {b: read_arm_bag(ROOT / "bags" / b) for b in BAGS}
    makers = configs(args.windows, args.gains)
    results = {}
    started = time.perf_counter()
    for name, (family, params) in makers.items():
        results[name] = {b: evaluate(family, params, run, meta) for b, (run, meta) in runs.items()}
    print(f"(bags: {time.perf_counter() - started:.0f} s, load "
          f"{Path('/proc/loadavg').read_text().split()[0]})", file=sys.stderr)
    contact_bags = list(BAGS[:2])

    def summary(name):
        r = results[name]
        return {"delay": max(d for b in contact_bags for d in r[b]["delays_ms"]),
                "settling": max(x for b in contact_bags for x in r[b]["settling_ms"]),
                "rms": r["arm7_free"]["free_rms_worst"],
                "velocity": max(r[b]["velocity_rms"] for b in BAGS),
                "max": r["arm7_free"]["max_error"],
                "false_alarms": sum(r[b]["false_alarms"] for b in BAGS),
                "us": float(np.median([r[b]["us_per_sample"] for b in BAGS]))}

    print("| estimator | velocity RMS err (rad/s) | tau_ext RMS err in free motion, worst "
          "joint (Nm) | max err in free motion (Nm) | detection delay link6 / tool (ms) | "
          "settling link6 / tool (ms) | false alarms (3 bags) | runner us per message |")
    print("|---|---|---|---|---|---|---|---|")
    for name in results:
        m = summary(name)
        dl = " / ".join(f"{x:.0f}" for b in contact_bags for x in results[name][b]["delays_ms"])
        st = " / ".join(f"{x:.0f}" for b in contact_bags for x in results[name][b]["settling_ms"])
        print(f"| {name} | {m['velocity']:.2e} | {m['rms']:.3g} | {m['max']:.3g} | {dl} | {st} "
              f"| {m['false_alarms']} | {m['us']:.1f} |")
    windows = [n for n in results if n.startswith("window")]
    for key, what in (("delay", "detection delay"), ("settling", "settling time")):
        print(f"\n**At the same {what}**: for each GMO gain, the least noisy window whose "
              f"{what} is at most the GMO's on both contact bags.\n")
        print(f"| GMO | its {what} (ms) | its RMS (Nm) | window | its {what} (ms) | its RMS "
              f"(Nm) | RMS ratio window / GMO |")
        print("|---|---|---|---|---|---|---|")
        for g in [n for n in results if n.startswith("GMO")]:
            theirs = summary(g)
            ok = [(summary(w)["rms"], w) for w in windows if summary(w)[key] <= theirs[key]]
            cells = [g, f"{theirs[key]:.0f}", f"{theirs['rms']:.3g}"]
            if ok:
                rms, w = min(ok)
                cells += [w, f"{summary(w)[key]:.0f}", f"{rms:.3g}", f"{rms / theirs['rms']:.2g}"]
            else:
                cells += ["none is as fast", "", "", ""]
            print("| " + " | ".join(cells) + " |")
    if args.long > 0:
        results["long"] = long_run(args, makers)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))


def long_run(args, makers) -> dict:
    from fto_ros.arm import load_model
    from fto_ros.models.arm import ArmRun, ArmSettings, simulate_arm
    t0 = time.perf_counter()
    cache = Path(args.long_cache) if args.long_cache else None
    if cache and cache.exists():
        d = np.load(cache)
        run = ArmRun(**{k: d[k] for k in d.files})
    else:
        run = simulate_arm(load_model(JOINTS, urdf=URDF), ArmSettings(duration=args.long, seed=21))
        if cache:
            np.savez(cache, **{k: v for k, v in run.__dict__.items() if v is not None})
    run.names = tuple(JOINTS)
    run.stamp_ns = np.round(run.t * 1e9).astype(np.int64)
    run.effort = run.tau
    print(f"(long run ready in {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    dur = run.t[-1]
    print(f"\n{dur:.0f} s contact-free (seed 21), bound {BOUND} per hour "
          f"({BOUND * dur / 3600:.2g} expected at most):\n")
    print("| estimator | false alarms | tau_ext RMS err, worst joint (Nm) | max err (Nm) |")
    print("|---|---|---|---|")
    out = {}
    for name in [n for n in ("window T=60 ms", "window T=30 ms", "GMO K=2") if n in makers]:
        r = out[name] = evaluate(*makers[name], run, {"contacts": []})
        print(f"| {name} | {r['false_alarms']} | {r['free_rms_worst']:.3g} | "
              f"{r['max_error']:.3g} |", flush=True)
    return out


if __name__ == "__main__":
    main()
