"""The main job's external-torque table: this package's windowed-momentum estimator, the
generalized-momentum observer and a finite difference on the arm's bags (velocity error,
tau_ext error in free motion, detection delay and false alarms), and the evaluation
benchmarks/bench_external_torque.py sweeps.

Per estimator and bag (bags/arm7_*, ``fto-simulate --urdf``), with the detector of
fto_ros.arm.collision at a bound of 1e-2 false alarms per hour, its residual divided by
||M_i,:(q)||, calibrated on the bag's own estimates over t in [0.5, 2.5] s.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..arm import load_model
from ..arm.collision import CollisionDetector, detection_time
from ..arm.external_torque import FiniteDifference, MomentumObserver, WindowEstimator, run_over
from .simulate_arm import read_arm_bag

BAGS = ("arm7_contact_link6", "arm7_contact_tool", "arm7_free")
JOINTS = [f"joint_a{i}" for i in range(1, 8)]
BOUND = 1e-2
CALIBRATION = (0.5, 2.5)
#: the main job's three: this package's estimator, the standard baseline, the naive one
MAIN_JOB = {"window T = 60 ms (this package)": lambda m: WindowEstimator(m, window=0.06),
            "momentum observer K = 2 (difference velocity)":
                lambda m: MomentumObserver(m, gain=2, velocity="difference"),
            "finite difference": lambda m: FiniteDifference(m, 1e-3)}


def contact_intervals(run):
    on = run.contact[:, 0] > 0
    edges = np.flatnonzero(np.diff(on.astype(int)))
    starts = [run.t[i + 1] for i in edges if not on[i]]
    ends = [run.t[i + 1] for i in edges if on[i]]
    return list(zip(starts, ends))


def evaluate(est, run):
    E, V = run_over(est, run.t, run.q_measured, run.tau)
    t = run.t
    contacts = contact_intervals(run)
    free = t >= 0.5
    for a, b in contacts:
        free &= ~((t >= a) & (t < b + 0.3))
    det = CollisionDetector(run.q.shape[1], rate=1000.0, false_alarms_per_hour=BOUND,
                            calibration=CALIBRATION[1] - CALIBRATION[0])
    alarms = []
    for k in np.flatnonzero(t >= CALIBRATION[0]):
        if np.all(np.isfinite(E[k])):
            scale = np.linalg.norm(est.model.mass_matrix(run.q_measured[k]), axis=1)
            ev = det.update(t[k], E[k], scale)
            if ev is not None:
                alarms.append(ev)
    delays, settling, per_joint = [], [], []
    false_alarms = sum(1 for ev in alarms if not any(a <= ev.t < b + 0.3 for a, b in contacts))
    for a, b in contacts:
        hits = [ev.t for ev in alarms if a <= ev.t < b + 0.3]
        delays.append((min(hits) - a) * 1e3 if hits else math.inf)
        if hasattr(est, "step_response"):           # per joint: measured and guaranteed
            k0 = int(np.searchsorted(t, a))
            gain = np.linalg.norm(est.model.mass_matrix(run.q_measured[k0]), axis=1)
            peak = np.abs(run.tau_ext[(t >= a) & (t < b)]).max(axis=0)
            for i in np.flatnonzero(peak > 1e-6):
                fired = [ev.t for ev in alarms if a <= ev.t < b + 0.3 and i in ev.joints]
                per_joint.append({
                    "joint": int(i), "peak": float(peak[i]),
                    "threshold": float(det.threshold[i] * gain[i]),
                    "guaranteed_ms": 1e3 * detection_time(est.step_response, peak[i],
                                                          det.threshold[i] * gain[i],
                                                          det.sigma[i] * gain[i]),
                    "measured_ms": (min(fired) - a) * 1e3 if fired else math.inf})
        inside = (t >= a) & (t < b)
        j = int(np.argmax(np.abs(run.tau_ext[inside]).max(axis=0)))
        bad = np.flatnonzero(inside & ~(np.abs(E[:, j] - run.tau_ext[:, j])
                                        <= 0.1 * np.abs(run.tau_ext[inside, j]).max()))
        settling.append((t[bad[-1] + 1] - a) * 1e3 if bad.size and t[bad[-1]] < b - 2e-3
                        else (0.0 if not bad.size else math.inf))
    err = E - run.tau_ext
    rms = np.sqrt(np.nanmean(err[free] ** 2, axis=0))
    return {"velocity_rms": float(np.sqrt(np.mean((V - run.v)[t >= 0.5] ** 2))),
            "free_rms_joints": rms.tolist(), "free_rms_worst": float(rms.max()),
            "max_error": float(np.nanmax(np.abs(err[free]))),
            "delays_ms": delays, "settling_ms": settling, "false_alarms": false_alarms,
            "per_joint": per_joint,
            "sigma": det.sigma.tolist()}


def table(bags_dir: Path, urdf: Path) -> str | None:
    """The markdown table of MAIN_JOB over the arm bags in ``bags_dir`` (None without them
    or without the URDF)."""
    bags = [b for b in BAGS if (Path(bags_dir) / b).is_dir()]
    if not bags or not Path(urdf).is_file():
        return None
    model = load_model(JOINTS, urdf=urdf)
    runs = {b: read_arm_bag(Path(bags_dir) / b)[0] for b in bags}
    lines = ["| estimator | bag | velocity RMS err (rad/s) | tau_ext RMS err in free motion, "
             "worst joint (Nm) | max err in free motion (Nm) | detection delay (ms) | "
             "false alarms |", "|---|---|---|---|---|---|---|"]
    for name, make in MAIN_JOB.items():
        for b, run in runs.items():
            r = evaluate(make(model), run)
            delays = " / ".join(f"{d:.0f}" for d in r["delays_ms"]) or "no contact"
            lines.append(f"| {name} | {b} | {r['velocity_rms']:.3g} | {r['free_rms_worst']:.3g} | "
                         f"{r['max_error']:.3g} | {delays} | {r['false_alarms']} |")
    return "\n".join(lines)
