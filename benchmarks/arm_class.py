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
- torques through runner/torque_loop.py's TorqueLoop exactly as the external-torque node
  runs it (URDF as given, fingers locked at 0.02 m, window T = 60 ms, momentum observer
  K = 50/s on backward-difference velocities, collision bound 1e-2 per hour, calibrated over
  the first 2 s of estimates): the fraction of received samples with a window estimate,
  restarts, tau_ext RMS error in free motion (t >= 0.5 s, outside [start, end + 0.3 s) of
  each contact; Nm) of the window estimator and of the momentum observer, detection delays
  (ms after each contact's start; the window: the node's detector; the momentum observer:
  the same rule, its residual over ||M_i,:(q)||, calibrated on [0.5, 2.5] s), false alarms.
  Stamps are fed as recorded (plus 1 s: a real stream never has stamp 0) and, for jittered
  conditions, snapped to the 1 kHz grid as a user would do by hand ("grid").

    PYTHONPATH=. python benchmarks/arm_class.py --out DIR [--seeds 1,2] [--duration 15]
        [--conditions clean,jitter,...] [--reuse] [--json FILE]

Importable: simulate_condition, score_velocity, score_torque (later helpers reuse them for
the AFTER numbers).
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
#: the torque loop's settings (the node's parameters), the fingers locked mid-range
TORQUE_PARAMS = {"plant.urdf": str(URDF), "plant.joints": ARM, "plant.locked_joints": FINGERS,
                 "plant.locked_positions": [0.02, 0.02], "sample_period": 1.0 / RATE,
                 "external_torque.momentum_gain": 50.0}
FREE_START, AFTER_CONTACT, GMO_CALIBRATION = 0.5, 0.3, (0.5, 2.5)
STAMP_OFFSET_NS = 1_000_000_000


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
    return [(c["t"], c["t"] + c["duration"]) for c in meta.get("contacts", [])]


def free_mask(t, windows) -> np.ndarray:
    free = t >= FREE_START
    for a, b in windows:
        free &= ~((t >= a) & (t < b + AFTER_CONTACT))
    return free


def _detections(event_times, windows, calibrated_from: float):
    """(delay in ms per contact (inf: missed), false alarms)."""
    delays = []
    for a, b in windows:
        hits = [t for t in event_times if a <= t < b + AFTER_CONTACT]
        delays.append(1e3 * (min(hits) - a) if hits else math.inf)
    false = sum(1 for t in event_times if t >= calibrated_from
                and not any(a <= t < b + AFTER_CONTACT for a, b in windows))
    return delays, false


def run_torque_loop(run, grid: bool = False, params=None):
    """Feed every received message to a TorqueLoop (the node's path); returns (window
    estimates, momentum estimates: (N, 7), NaN where none; detection times (actual time of
    the sample); the loop). The TorqueLoop was removed on integ2 (the arm families run on the
    runner now): imported here, so the rest of this module stays importable."""
    from fto_ros.runner.torque_loop import TorqueLoop
    from fto_ros.runner.torque_settings import build
    loop = TorqueLoop(build(dict(TORQUE_PARAMS, **(params or {}))))
    c = arm_columns(run)
    N = run.t.size
    E, G = np.full((N, len(c)), np.nan), np.full((N, len(c)), np.nan)
    stamps = run.stamp_ns
    if grid:
        h_ns = round(1e9 / RATE)
        stamps = np.round(stamps / h_ns).astype(np.int64) * h_ns
    names = list(run.names)
    events = []
    for k in range(N):
        res = loop.process(int(stamps[k]) + STAMP_OFFSET_NS, names, run.q_measured[k],
                           run.effort[k])
        if res is None:
            continue
        if res.tau_ext is not None:
            E[k] = res.tau_ext
        if res.momentum is not None:
            G[k] = res.momentum
        if res.collision is not None:
            events.append(run.t[k])
    return E, G, events, loop


def _gmo_detections(run, G, model):
    """The momentum observer's detection times under the window's rule (module doc)."""
    from fto_ros.arm.collision import CollisionDetector
    det = CollisionDetector(G.shape[1], rate=RATE, false_alarms_per_hour=1e-2,
                            calibration=GMO_CALIBRATION[1] - GMO_CALIBRATION[0])
    c = arm_columns(run)
    events = []
    for k in np.flatnonzero((run.t >= GMO_CALIBRATION[0]) & np.all(np.isfinite(G), axis=1)):
        scale = np.linalg.norm(model.mass_matrix(run.q_measured[k, c]), axis=1)
        if det.update(run.t[k], G[k], scale) is not None:
            events.append(run.t[k])
    return events, det.sigma is not None


def score_torque(run, meta, grid: bool = False, params=None) -> dict:
    """The window estimator and the momentum observer through the TorqueLoop (module doc)."""
    E, G, events, loop = run_torque_loop(run, grid, params)
    c = arm_columns(run)
    windows = contact_windows(meta)
    free = free_mask(run.t, windows)
    truth = run.tau_ext[:, c]
    out = {"received": int(run.t.size), "samples": int(meta.get("samples", run.t.size)),
           "restarts": int(sum(loop.restarts.values())),
           "rejected": int(sum(loop.rejected.values()))}
    for key, est in (("window", E), ("momentum", G)):
        has = np.all(np.isfinite(est), axis=1)
        err = (est - truth)[free & has]
        out[key] = {"estimate_fraction": float(has.mean()),
                    "free_rms": (np.sqrt(np.mean(err ** 2, axis=0)).tolist() if len(err)
                                 else [math.nan] * len(c))}
    cal = loop.detector.sigma is not None
    delays, false = _detections(events, windows, 0.0)
    out["window"].update(delays_ms=delays, false_alarms=false, calibrated=cal)
    g_events, g_cal = _gmo_detections(run, G, loop.model)
    delays, false = _detections(g_events, windows, GMO_CALIBRATION[1])
    out["momentum"].update(delays_ms=delays, false_alarms=false, calibrated=g_cal)
    out["peak_tau_ext"] = [float(np.abs(truth[(run.t >= a) & (run.t < b)]).max(initial=0.0))
                           for a, b in windows]
    return out


def measure(name: str, seed: int, out_dir, duration: float = DURATION, reuse: bool = False):
    bag = simulate_condition(name, seed, out_dir, duration, reuse)
    run, meta = read_arm_bag(bag)
    res = {"condition": name, "seed": seed, "bag": str(bag), "lost": meta["stream"]["lost"],
           "velocity_rms": score_velocity(run).tolist(), "stamps": score_torque(run, meta)}
    if "jitter" in name or "all" == name:
        res["grid"] = score_torque(run, meta, grid=True)
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
    for est, label in (("momentum", "momentum observer K = 50/s"),
                       ("window", "window estimator T = 60 ms")):
        out += ["", f"**{label} through TorqueLoop: tau_ext RMS error in free motion (Nm), per "
                    f"joint**", "", head[:-1] + "| samples with an estimate |", rule + "---|"]
        for name, rs in by.items():
            for mode in ("stamps", "grid"):
                if mode not in rs[0]:
                    continue
                frac = np.mean([r[mode][est]["estimate_fraction"] for r in rs])
                row = _pool([r[mode][est]["free_rms"] for r in rs])
                out.append(f"| {name}{' (stamps snapped to the grid)' if mode == 'grid' else ''}"
                           f" | " + " | ".join(_fmt(x) for x in row) + f" | {100 * frac:.1f} % |")
    out += ["", "**Detections (ms after each push; seeds in order) and false alarms**", "",
            "| condition | peak |tau_ext| of the pushes (Nm) | window: delays | window: false "
            "alarms | window: calibrated | momentum: delays | momentum: false alarms | restarts "
            "| lost |", "|---|---|---|---|---|---|---|---|---|"]
    for name, rs in by.items():
        for mode in ("stamps", "grid"):
            if mode not in rs[0]:
                continue
            cells = [f"{name}{' (grid)' if mode == 'grid' else ''}",
                     "; ".join("/".join(f"{p:.1f}" for p in r[mode]["peak_tau_ext"]) for r in rs)]
            for est in ("window", "momentum"):
                cells.append("; ".join("/".join("missed" if not np.isfinite(d) else f"{d:.0f}"
                                                for d in r[mode][est]["delays_ms"]) for r in rs))
                cells.append("; ".join(str(r[mode][est]["false_alarms"]) for r in rs))
                if est == "window":
                    cells.append("; ".join(str(r[mode][est]["calibrated"]).lower() for r in rs))
            cells.append("; ".join(str(r[mode]["restarts"]) for r in rs))
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
