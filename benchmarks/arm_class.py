"""The arm class of issues 25 and 26, measured: the BEFORE baselines on our own simulated arm.

The arm: urdf/panda_gripper.urdf (a Franka-Panda-class 7-joint arm with a parallel gripper,
two prismatic fingers, the second a <mimic> of the first; scripts/make_panda_urdf.py),
simulated by ``fto-simulate --urdf`` for DURATION s at 1 kHz, encoder noise 1e-5 rad
quantised to 2^-18 rad, the fingers opening and closing every 6 s, velocity reversals on
every joint (the 1 - cos trajectory), two pushes of the 10 Nm class (CONTACTS: 50 N on
link 4 at 6 s, 20 N on the hand at 11 s, 0.1 s each), effort = the commanded torque.

Conditions (CONDITIONS), each with SEEDS (the encoder/stream seed and the model seed):
clean stamps and exact model; +-50 us jitter; 0.2 % lost messages; both; 5 % model error
with unknown friction (0.5-1 N m s/rad viscous, 0.5-1 Nm Coulomb); all of them.

Measured per driven joint (every figure from the bags this run simulates):

- velocity: the RMS error of the backward difference of the stream's positions over its
  stamps, (q_k - q_k-1) / (s_k - s_k-1), against the true velocity at the actual instant
  (rad/s, every received message but the first);
- torques through the arm families as the node and the replay run them (benchmarks/arm_runs.py:
  built by the Runner from the node's parameters, fed every received message through the
  runner's JointState intake and process_block on the stamps as recorded plus 1 s, the
  fingers' positions from the message): ``external_torque`` (window T = 60 ms) and
  ``momentum_observer`` (K = 50/s), each with its own contact detection (false-alarm bound
  1e-2 per hour): the fraction of received samples with an estimate, tau_ext RMS error in
  free motion (t >= 0.5 s, outside each contact and the 0.3 s after it; Nm), the delay of
  each push (ms after its start; a joint's contact flag rising), false alarms.

The BEFORE tables of docs/arm_class.md were measured with the earlier torque pipeline
(runner/torque_loop.py, removed); this script measures the families that replaced it.

    PYTHONPATH=. python benchmarks/arm_class.py --out DIR [--seeds 1,2] [--duration 15]
        [--conditions clean,jitter,...] [--reuse] [--json FILE]

Importable: simulate_condition, score_velocity, score_torque.
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

from fto_ros.cli.arm_bag import read_arm_bag  # noqa: E402
from fto_ros.cli.simulate_arm import main as simulate_main  # noqa: E402

URDF = ROOT / "urdf" / "panda_gripper.urdf"
ARM = [f"panda_joint{i}" for i in range(1, 8)]
FINGERS = ["panda_finger_joint1", "panda_finger_joint2"]
RATE, DURATION, SEEDS = 1000.0, 15.0, (1, 2)
CONTACTS = ["panda_link4,6.0,0.1,0,50,0", "panda_hand,11.0,0.1,0,0,-20"]
BASE = ["--gripper-period", "6", *sum((["--contact", c] for c in CONTACTS), [])]
JITTER, LOSS = ["--jitter", "50"], ["--loss", "0.002"]
MISMATCH = ["--model-error", "0.05", "--friction", "0.5,1,0.5,1"]
CONDITIONS = {
    "clean": [],
    "jitter": JITTER,
    "loss": LOSS,
    "jitter+loss": JITTER + LOSS,
    "model+friction": MISMATCH,
    "all": JITTER + LOSS + MISMATCH,
}
#: the families measured (flat parameters beside the URDF and the joints)
FAMILIES = {"external_torque": {"external_torque.window": 0.06},
            "momentum_observer": {"momentum_observer.gain": 50.0}}
STAMP_OFFSET_S = 1.0                 # a real stream never has stamp 0


def simulate_condition(name: str, seed: int, out_dir, duration: float = DURATION,
                       reuse: bool = False, extra=()) -> Path:
    """The bag of condition ``name`` with ``seed`` (the model seed too) under ``out_dir``
    (``reuse``: keep a bag already there); extra: more fto-simulate arguments."""
    bag = Path(out_dir) / f"{name.replace('+', '_')}_s{seed}"
    if reuse and (bag / "metadata.yaml").is_file():
        return bag
    argv = ["--urdf", str(URDF), "--out", str(bag), "--overwrite", "--duration", str(duration),
            "--seed", str(seed), "--model-seed", str(seed), *BASE, *CONDITIONS[name], *extra]
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = simulate_main(argv)
    if code != 0:
        raise RuntimeError(f"fto-simulate {' '.join(argv)}: exit {code}: {err.getvalue()}")
    return bag


def arm_columns(run) -> np.ndarray:
    return np.array([list(run.names).index(j) for j in ARM])


def score_velocity(run) -> np.ndarray:
    """Per arm joint, the RMS error (rad/s) of the stamps' backward difference."""
    c = arm_columns(run)
    dt = np.diff(run.stamp_ns) * 1e-9
    v = np.diff(run.q_measured[:, c], axis=0) / dt[:, None]
    return np.sqrt(np.mean((v - run.v[1:, c]) ** 2, axis=0))


def contact_windows(meta) -> list[tuple[float, float]]:
    """(start, end) s of each contact in the bag's metadata."""
    return [(c["t"], c["t"] + c["duration"]) for c in meta.get("contacts", [])]


def score_torque(run, meta, params=None) -> dict:
    """Each family of FAMILIES through the runner (module doc): arm_runs.score's figures."""
    from benchmarks.arm_runs import arm_runner, feed, score
    out = {}
    for family, own in FAMILIES.items():
        runner = arm_runner(family, ARM, urdf=URDF,
                            **{k.replace(".", "__"): v for k, v in {**own, **(params or {})}.items()})
        res = score(feed(runner, run, STAMP_OFFSET_S), run, meta, arm_columns(run))
        res["restarts"] = int(sum(runner.resets.values()))
        res["rejected"] = int(sum(runner.rejected.values()))
        out[family] = res
    return out


def measure(name: str, seed: int, out_dir, duration: float = DURATION, reuse: bool = False):
    bag = simulate_condition(name, seed, out_dir, duration, reuse)
    run, meta = read_arm_bag(bag)
    res = {"condition": name, "seed": seed, "bag": str(bag), "lost": meta["stream"]["lost"],
           "velocity_rms": score_velocity(run).tolist(), "torque": score_torque(run, meta)}
    return res


def _pool(values) -> np.ndarray:
    """RMS over seeds of per-seed RMS values (equal sample counts; NaN: none had one)."""
    sq = np.square(np.asarray(values, dtype=float))
    have = np.isfinite(sq).sum(axis=0)
    return np.sqrt(np.where(have > 0, np.nansum(sq, axis=0) / np.maximum(have, 1), np.nan))


def _fmt(x, digits=3) -> str:
    return "-" if not np.isfinite(x) else f"{x:.{digits}g}"


def tables(results: list[dict]) -> str:
    """The markdown tables of docs/arm_class.md."""
    by = {}
    for r in results:
        by.setdefault(r["condition"], []).append(r)
    head = "| condition | " + " | ".join(f"j{i}" for i in range(1, 8)) + " |"
    rule = "|---|" + "---|" * 7
    out = ["**Backward difference over the stamps: velocity RMS error (rad/s), per joint**", "",
           head, rule]
    for name, rs in by.items():
        out.append(f"| {name} | " + " | ".join(_fmt(x) for x in _pool(
            [r["velocity_rms"] for r in rs])) + " |")
    for family, label in (("momentum_observer", "momentum_observer K = 50/s"),
                          ("external_torque", "external_torque T = 60 ms")):
        out += ["", f"**{label}: tau_ext RMS error in free motion (Nm), per joint**", "",
                head[:-1] + "| samples with an estimate |", rule + "---|"]
        for name, rs in by.items():
            frac = np.mean([r["torque"][family]["estimate_fraction"] for r in rs])
            row = _pool([r["torque"][family]["rms"] for r in rs])
            out.append(f"| {name} | " + " | ".join(_fmt(x) for x in row)
                       + f" | {100 * frac:.1f} % |")
    out += ["", "**Detections (ms after each push; seeds in order) and false alarms**", "",
            "| condition | external_torque: delays | false alarms | momentum_observer: delays "
            "| false alarms | restarts (external_torque) | lost |", "|---|---|---|---|---|---|---|"]
    for name, rs in by.items():
        cells = [name]
        for family in ("external_torque", "momentum_observer"):
            cells.append("; ".join("/".join("missed" if not np.isfinite(d) else f"{d:.0f}"
                                            for d in r["torque"][family]["delays_ms"])
                                   for r in rs))
            cells.append("; ".join(str(r["torque"][family]["false_alarms"]) for r in rs))
        cells.append("; ".join(str(r["torque"]["external_torque"]["restarts"]) for r in rs))
        cells.append("; ".join(str(r["lost"]) for r in rs))
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="folder for the simulated bags")
    p.add_argument("--seeds", default=",".join(map(str, SEEDS)))
    p.add_argument("--duration", type=float, default=DURATION)
    p.add_argument("--conditions", default=",".join(CONDITIONS))
    p.add_argument("--reuse", action="store_true", help="keep bags already in --out")
    p.add_argument("--json", metavar="FILE", help="also write the raw results")
    args = p.parse_args(argv)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    results = []
    for name in args.conditions.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            t0 = time.perf_counter()
            results.append(measure(name, seed, args.out, args.duration, args.reuse))
            print(f"({name}, seed {seed}: {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    print(tables(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
