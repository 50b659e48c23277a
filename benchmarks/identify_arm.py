"""fto-identify measured on the arm class (docs/identify.md): fitted on one bag, scored on
another.

Bags (benchmarks/arm_class.py's simulate_condition, condition ``all``: the Panda-class URDF,
+-5 % masses and inertias and centres of mass moved by up to 5 mm (--model-error 0.05),
unknown friction 0.5-1 N m s/rad and 0.5-1 Nm, +-50 us jitter, 0.2 % lost messages, two
pushes of the 10 Nm class, the fingers moving), one true arm (model seed 1) for all:

- FIT: stream seed 1, the default trajectory, 15 s;
- SCORE: stream seed 2, another trajectory (other amplitudes and periods), 15 s;
- GRASP: stream seed 3, 4 s, the arm carrying a 0.8 kg payload at panda_hand.

fto-identify (its main, the command's path) fits FIT with --inertia base, scale and none
(friction only); --payload-only on GRASP with the base result merged after the plant file.
Scored on SCORE with the window estimator as the node and the replay run it: the observer
family ``external_torque`` (T = 60 ms, its collision detection at a false-alarm bound of 1e-2
per hour, calibrated over the first 2 s of estimates) built by ``Runner`` from the merged
params files (the plant file, then the identified one; or the exact model: the simulator's
perturbed URDF as robot_description and its true friction), the fingers passive (their
positions from the stream), fed the stream's JointStates through the runner's intake and
``process_block`` on the recorded stamps (plus 1 s; benchmarks/arm_runs.py): tau_ext RMS
error in free motion per joint (t >= 0.5 s, outside each push and the 0.3 s after it), the
delay of each push (a joint's contact flag rising), false alarms. And the parameters against
the simulator's truth (bag metadata): friction, the base parameters (the true arm's base
combinations, fto_ros/arm/identify_base.py), the payload.

    PYTHONPATH=. python benchmarks/identify_arm.py --out DIR [--reuse] [--json FILE]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.arm_class import ARM, URDF, simulate_condition  # noqa: E402
from benchmarks.arm_runs import feed, score as score_fed  # noqa: E402
from fto_ros.arm.identify_base import moving_bodies, structural_base  # noqa: E402
from fto_ros.arm.identify_params import prior_model, read  # noqa: E402
from fto_ros.cli.arm_bag import read_arm_bag  # noqa: E402
from fto_ros.cli.identify import main as identify_main  # noqa: E402
from fto_ros.models.arm_urdf import perturbed  # noqa: E402
from fto_ros.runner.params_file import load_params_files  # noqa: E402
from fto_ros.runner.runner import Runner  # noqa: E402

OTHER_TRAJECTORY = ["--amplitude", "0.4,0.4,0.6,0.3,0.5,0.6,0.7",
                    "--period", "3.7,4.3,3.1,5.2,2.7,3.9,2.9"]
PAYLOAD = ("panda_hand", 0.8, (0.01, -0.01, 0.06), (0.002, 0.003, 0.004))
PLANT = f"""/**:
  ros__parameters:
    plant:
      urdf: {URDF}
      locked_joints: [panda_finger_joint1, panda_finger_joint2]
      locked_positions: [0.02, 0.02]
    joints: [{', '.join(ARM)}]
    effort:
      meaning: commanded
"""


def bags(out: Path, reuse: bool) -> dict[str, Path]:
    (out / "score").mkdir(parents=True, exist_ok=True)
    (out / "grasp").mkdir(parents=True, exist_ok=True)
    frame, mass, com, mom = PAYLOAD
    pay = ",".join(map(str, (frame, mass, *com, *mom)))
    return {"fit": simulate_condition("all", 1, out, reuse=reuse),
            "score": simulate_condition("all", 2, out / "score", reuse=reuse,
                                        extra=["--model-seed", "1", *OTHER_TRAJECTORY]),
            "grasp": simulate_condition("all", 3, out / "grasp", duration=4.0, reuse=reuse,
                                        extra=["--model-seed", "1", "--payload", pay])}


def run_identify(argv: list[str]) -> tuple[int, str, float]:
    buf, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(err):
        code = identify_main(argv)
    if code != 0:
        raise RuntimeError(f"fto-identify {' '.join(argv)}: exit {code}: {err.getvalue()}")
    return code, buf.getvalue(), time.perf_counter() - t0


def merged_model(files):
    return prior_model(read(load_params_files([str(f) for f in files])))


def exact_model(meta, plant: Path):
    return prior_model(read(exact_params(meta, plant)))


def exact_params(meta, plant: Path) -> dict:
    """The flat params of the simulator's true arm: its perturbed URDF as robot_description,
    its true friction (the plant file's joints, locks and effort meaning)."""
    text, _ = perturbed(Path(URDF).read_text(), meta["model_error"]["error"],
                        meta["model_error"]["seed"])
    fr = meta["friction"]
    flat = load_params_files([plant])
    flat.pop("plant.urdf", None)
    flat.update({"robot_description": text, "plant.viscous_friction": fr["viscous"][:7],
                 "plant.coulomb_friction": fr["coulomb"][:7]})
    return flat


#: the family's settings beside the params files' (module doc)
ESTIMATOR = {"observer.type": "external_torque", "external_torque.window": 0.06,
             "collision.false_alarms_per_hour": 1e-2, "collision.calibration": 2.0}


def score(bag: Path, flat: dict) -> dict:
    """The external_torque family and its collision detection on ``bag`` (module doc);
    ``flat``: the merged params."""
    run, meta = read_arm_bag(bag)
    runner = Runner({**flat, **ESTIMATOR})
    cols = [list(run.names).index(j) for j in ARM]
    got = score_fed(feed(runner, run, offset=1.0), run, meta, cols)
    return {"rms": got["rms"], "delays_ms": got["delays_ms"],
            "false_alarms": got["false_alarms"], "calibrated": runner.observer.calibrated,
            "estimate_fraction": got["estimate_fraction"]}


def parameter_truth(files, meta, output: str) -> dict:
    """Fitted against true: friction (relative errors, |error| / standard error), base
    parameters (the true arm's base combinations: theta_I + K theta_D)."""
    fitted = merged_model(files)
    prior = merged_model(files[:1])
    exact = exact_model(meta, files[0])
    se = _standard_errors(output)
    out = {}
    for kind, fit, true in (("viscous", fitted.viscous, exact.viscous),
                            ("coulomb", fitted.coulomb, exact.coulomb)):
        z = [abs(f - t) / se.get(f"{kind} {j}", math.nan) for j, f, t in zip(ARM, fit, true)]
        out[kind] = {"max_rel_error": float(np.max(np.abs(fit - true) / true)),
                     "max_z": float(np.nanmax(z)) if np.isfinite(z).any() else math.nan}
    bodies = moving_bodies(prior)
    indep, dep, K = structural_base(prior, [b for b, _ in bodies])
    rows = [b for b, _ in bodies]
    theta = lambda m: np.concatenate([m.tree.base[b] for b in rows])   # noqa: E731
    t_urdf, t_true, t_fit = theta(prior), theta(exact), theta(fitted)
    base_true = t_true[indep] + K @ (t_true[dep] - t_urdf[dep])
    err = t_fit[indep] - base_true
    names = [f"{bodies[c // 10][1]} {('m', 'mx', 'my', 'mz', 'ixx', 'iyy', 'izz', 'iyz', 'ixz', 'ixy')[c % 10]}"
             for c in indep]
    zs = [abs(e) / se[n] for e, n in zip(err, names) if n in se and np.isfinite(se[n])]
    out["base"] = {"count": len(indep), "fitted": len(zs),
                   "rms_error_vs_urdf_error": float(np.sqrt(np.mean(err ** 2)) /
                                                    np.sqrt(np.mean((t_urdf[indep] - base_true) ** 2))),
                   "median_z": float(np.median(zs)) if zs else math.nan,
                   "max_z": float(np.max(zs)) if zs else math.nan}
    return out


def _standard_errors(output: str) -> dict:
    out = {}
    for line in output.splitlines():
        line = line.strip()
        if "->" in line and "+-" in line and ":" in line:
            name, rest = line.split(":", 1)
            try:
                out[name] = float(rest.split("+-")[1].split()[0])
            except (IndexError, ValueError):
                out[name] = math.nan
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder for the bags and the params files")
    p.add_argument("--reuse", action="store_true", help="keep bags already in --out")
    p.add_argument("--json", metavar="FILE")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    b = bags(out, args.reuse)
    plant = out / "plant.yaml"
    plant.write_text(PLANT)
    _, meta = read_arm_bag(b["score"])
    results = {"exact": score(b["score"], exact_params(meta, plant)),
               "urdf": score(b["score"], load_params_files([plant]))}
    for form in ("base", "scale", "none"):
        target = out / f"identified_{form}.yaml"
        _, text, took = run_identify([str(b["fit"]), "--params", str(plant), "--out",
                                      str(target), "--overwrite", "--inertia", form])
        results[form] = score(b["score"], load_params_files([plant, target]))
        results[form]["seconds"] = took
        results[form]["truth"] = parameter_truth([plant, target], meta, text)
        results[form]["summary"] = text.splitlines()[0]
        results[form]["contacts"] = next((line for line in text.splitlines()
                                          if line.startswith("windows left out")), "none left out")
    target = out / "payload.yaml"
    _, text, took = run_identify([str(b["grasp"]), "--params", str(plant),
                                  str(out / "identified_base.yaml"), "--out", str(target),
                                  "--overwrite", "--payload-only", "--frame", PAYLOAD[0]])
    got = load_params_files([str(target)])
    results["payload"] = {"true": {"mass": PAYLOAD[1], "com": PAYLOAD[2], "moments": PAYLOAD[3]},
                          "fitted": {k: got[f"payload.{k}"] for k in ("mass", "com", "inertia")},
                          "seconds": took, "summary": text.splitlines()[0]}
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))
    return 0


def _f(x) -> str:
    return "missed" if not np.isfinite(x) else f"{x:.3g}"


def _windows(summary: str) -> str:
    """'1453 (684)' from fto-identify's first line."""
    try:
        used = summary.split(" windows of ")[0].rsplit(";", 1)[1].strip()
        eff = summary.split("(")[1].split(" effective")[0]
        return f"{used} ({eff})"
    except IndexError:
        return "?"


def table(r: dict) -> str:
    ex = max(r["exact"]["rms"])
    lines = ["| model | tau_ext RMS in free motion per joint (Nm) | worst / exact's worst | "
             "largest per-joint ratio to exact | push delays (ms) | false alarms |",
             "|---|---|---|---|---|---|"]
    for key, label in (("exact", "exact (the simulator's arm)"), ("urdf", "URDF as given"),
                       ("base", "identified, --inertia base"),
                       ("scale", "identified, --inertia scale"),
                       ("none", "identified, friction only")):
        s = r[key]
        ratio = max(a / b for a, b in zip(s["rms"], r["exact"]["rms"]))
        lines.append(f"| {label} | {' / '.join(_f(x) for x in s['rms'])} | "
                     f"{max(s['rms']) / ex:.2f} | {ratio:.2f} | "
                     f"{' / '.join(_f(d) for d in s['delays_ms'])} | {s['false_alarms']} |")
    lines += ["", "| fit | viscous: max rel. error, max abs(z) | Coulomb: max rel. error, max "
              "abs(z) | base parameters: error RMS / URDF's, median and max abs(z) | seconds | "
              "windows (effective) | contact windows left out |",
              "|---|---|---|---|---|---|---|"]
    for key in ("base", "scale", "none"):
        t = r[key]["truth"]
        lines.append(f"| {key} | {t['viscous']['max_rel_error']:.2%}, {t['viscous']['max_z']:.1f} "
                     f"| {t['coulomb']['max_rel_error']:.2%}, {t['coulomb']['max_z']:.1f} | "
                     f"{t['base']['rms_error_vs_urdf_error']:.3f}, {t['base']['median_z']:.1f}, "
                     f"{t['base']['max_z']:.1f} | {r[key]['seconds']:.0f} | "
                     f"{_windows(r[key]['summary'])} | {r[key]['contacts']} |")
    p = r["payload"]
    lines += ["", f"payload: true {p['true']}; fitted {p['fitted']} ({p['seconds']:.0f} s)"]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
