"""The arm's external-torque families (external_torque, momentum_observer) run as users run
them, for the arm benchmarks: built by ``Runner`` from the node's flat parameters, fed a
recorded arm stream (an ``ArmRun`` read by ``fto_ros.cli.arm_bag.read_arm_bag``) through the
runner's JointState intake (runner/arm_intake.py, by joint name) and ``process_block``, one
INPUT row (the efforts and passive positions) then one PAIRED row (the positions) per
message, as the replay plans a JointState (replay/blocks.py); then scored against the bag's
truth with the replay's rules (replay/arm_metrics.py: free motion from FREE_START s, outside
each contact and the AFTER_CONTACT s after it; a detection is a joint's contact flag rising).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fto_ros.arm import detect as DT
from fto_ros.replay.arm_metrics import AFTER_CONTACT, FREE_START
from fto_ros.runner import loop as L
from fto_ros.runner.runner import Runner

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test" / "support"))
from arm_families import flat  # noqa: E402


def arm_runner(family: str, joints, *, urdf=None, text=None, **params) -> Runner:
    """A Runner of ``family`` on a URDF file or text; ``params``: more flat parameters with
    '__' for '.' (external_torque__window=0.03), read as the tests read them
    (test/support/arm_families.py)."""
    return Runner(flat(family, urdf, text, joints, **params))


def rows(runner: Runner, run, offset: float = 0.0):
    """(kind, t, values) of ``run``'s messages for ``runner`` (module doc); the stamps are the
    messages' header stamps plus ``offset`` s."""
    take = runner.intake.take
    N = len(run.t)
    width = max(runner.observer.n_inputs, runner.observer.n_outputs)
    kind = np.empty(2 * N, np.int8)
    kind[0::2], kind[1::2] = L.INPUT, L.PAIRED
    t = np.repeat(run.stamp_ns * 1e-9 + offset, 2)
    values = np.zeros((2 * N, width))
    effort = run.effort if run.effort is not None else run.tau
    for k in range(N):
        got = take(run.names, run.q_measured[k], effort[k])
        if isinstance(got, str):
            raise SystemExit(f"message {k} refused by the intake: {got}")
        y, u = got
        values[2 * k, :u.size] = u
        values[2 * k + 1, :y.size] = y
    return kind, t, values


@dataclass
class Fed:
    """Per message (N rows): tau_ext (NaN where the family has none), the velocity estimate,
    the contact flags and lower levels; the runner's wall time per message (us)."""
    tau: np.ndarray
    velocity: np.ndarray
    flags: np.ndarray
    lower: np.ndarray
    us_per_sample: float


def feed(runner: Runner, run, offset: float = 0.0) -> Fed:
    """``run`` through ``runner.process_block`` in one call (module doc)."""
    kind, t, values = rows(runner, run, offset)
    t0 = time.perf_counter()
    blk = runner.process_block(kind, t, values)
    us = (time.perf_counter() - t0) / len(run.t) * 1e6
    return _outputs(runner, blk, us)


def _outputs(runner: Runner, blk, us: float) -> Fed:
    n = runner.observer.n_joints
    status = blk.status[1::2, 0]
    conv = blk.convergence[1::2, 0]
    base = list(runner.convergence_fields).index("tau_ext_valid")
    ok = (status == L.OUTPUT) & (conv[:, base + DT.X_VALID] > 0.5)
    tau = np.where(ok[:, None], blk.unknown_input[1::2, 0, :n], np.nan)
    vel = np.where((status == L.OUTPUT)[:, None], blk.estimate[1::2, 0, n:2 * n], np.nan)
    h = base + DT.X_HEAD
    flags = np.where((status == L.OUTPUT)[:, None], conv[:, h:h + n], 0.0)
    lower = conv[:, h + 2 * n:h + 3 * n]
    return Fed(tau, vel, flags, lower, us)


def contact_windows(run, meta) -> list[tuple[float, float]]:
    """(start, end) s of each contact: the bag's metadata, else where the truth is not 0."""
    if meta.get("contacts") is not None:
        return [(c["t"], c["t"] + c["duration"]) for c in meta["contacts"]]
    on = np.any(np.abs(run.tau_ext) > 1e-9, axis=1)
    edges = np.flatnonzero(np.diff(on.astype(int)))
    starts = [run.t[e + 1] for e in edges if not on[e]]
    ends = [run.t[e + 1] for e in edges if on[e]]
    return list(zip(starts, ends + [run.t[-1]] * (len(starts) - len(ends))))


def free_mask(t, windows) -> np.ndarray:
    free = t >= t[0] + FREE_START
    for a, b in windows:
        free &= ~((t >= a) & (t < b + AFTER_CONTACT))
    return free


def score(fed: Fed, run, meta, cols) -> dict:
    """The replay's figures of one fed run (module doc), plus the velocity's RMS error and
    each contact's settling time: from its start until the estimate of its largest joint
    torque stays within 10 % of that torque's peak until the contact ends (ms; inf: never)."""
    t = run.t
    truth = run.tau_ext[:, cols]
    windows = contact_windows(run, meta)
    free = free_mask(t, windows) & np.all(np.isfinite(fed.tau), axis=1)
    err = (fed.tau - truth)[free]
    rms = np.sqrt(np.mean(err ** 2, axis=0)) if free.any() else np.full(len(cols), np.nan)
    late = (t >= t[0] + FREE_START) & np.all(np.isfinite(fed.velocity), axis=1)
    vrms = float(np.sqrt(np.mean((fed.velocity - run.v[:, cols])[late] ** 2)))
    prev = np.vstack([np.zeros((1, fed.flags.shape[1])), fed.flags[:-1]])
    rise = np.flatnonzero(((fed.flags > 0.5) & (prev < 0.5)).any(axis=1))
    events = t[rise]
    delays, settling, per_joint = [], [], []
    for a, b in windows:
        hits = events[(events >= a) & (events < b + AFTER_CONTACT)]
        delays.append(1e3 * (hits.min() - a) if hits.size else math.inf)
        inside = (t >= a) & (t < b)
        j = int(np.argmax(np.abs(truth[inside]).max(axis=0)))
        peak = float(np.abs(truth[inside, j]).max())
        bad = np.flatnonzero(~(np.abs(fed.tau[inside, j] - truth[inside, j]) <= 0.1 * peak))
        ti = t[inside]
        if bad.size == 0:
            settling.append(0.0)
        elif bad[-1] + 1 < ti.size:
            settling.append(1e3 * (ti[bad[-1] + 1] - a))
        else:
            settling.append(math.inf)
        per_joint.append((j, peak, hits.min() - a if hits.size else math.inf))
    false = int(sum(1 for e in events if not any(a <= e < b + AFTER_CONTACT
                                                   for a, b in windows)))
    return {"rms": rms.tolist(), "free_rms_worst": float(np.max(rms)),
            "max_error": float(np.abs(err).max()) if err.size else math.nan,
            "velocity_rms": vrms, "delays_ms": delays, "settling_ms": settling,
            "false_alarms": false, "per_joint": per_joint,
            "estimate_fraction": float(np.mean(np.all(np.isfinite(fed.tau), axis=1))),
            "us_per_sample": fed.us_per_sample}
