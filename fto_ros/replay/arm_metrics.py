"""What a replay of an arm's external-torque family (external_torque, momentum_observer)
measures against the bag's truth: a JointState topic by joint name (``topics.true_state``;
``fto-simulate --urdf`` writes /<system>/true_joint_states: the true positions, velocities
and, in effort, the true external torques).

- ``truth``: the truth of the estimate x = [q, v] and of the unknown input tau_ext;
- ``metrics``: the samples that carry an estimate, tau_ext's RMS error per joint in free
  motion (from FREE_START s after the first truth sample, outside each contact and the
  AFTER_CONTACT s after it; a contact is where the true tau_ext is not zero), the
  detections (a joint's contact flag rising: the lower level crossed) with each contact's
  delay, the false alarms (detections outside the contacts), the latched collisions, the
  calibration and the model-mismatch check.  No rclpy.
"""
from __future__ import annotations

import math

import numpy as np

from ..arm import detect as DT
from .metrics import match_truth

FREE_START, AFTER_CONTACT = 0.5, 0.3


def truth(stream, obs):
    """(t_ns, X (N, 2n), W (N, n), None) of the truth JointStates, or (None,) * 3 + (why)."""
    t, msgs = stream
    joints = list(obs.joints)
    n = len(joints)
    X, W, keep = [], [], []
    for k, msg in enumerate(msgs):
        names = list(msg.name)
        try:
            idx = [names.index(j) for j in joints]
        except ValueError:
            continue
        if len(msg.position) != len(names) or len(msg.velocity) != len(names) \
                or len(msg.effort) != len(names):
            continue
        p, v, e = (np.asarray(f, dtype=float) for f in (msg.position, msg.velocity, msg.effort))
        X.append(np.concatenate([p[idx], v[idx]]))
        W.append(e[idx])
        keep.append(k)
    if not keep:
        return None, None, None, ("no ground truth: no message of the truth topic carries "
                                  f"position, velocity and effort of {', '.join(joints)}")
    return np.asarray(t)[keep], np.asarray(X).reshape(-1, 2 * n), np.asarray(W).reshape(-1, n), \
        None


def contacts(t_ns: np.ndarray, W: np.ndarray) -> list[tuple[int, int, float]]:
    """(start ns, end ns, peak |tau_ext|) of every stretch where the true tau_ext is not 0."""
    on = np.any(np.abs(W) > 1e-9, axis=1)
    out, k = [], 0
    while k < on.size:
        if not on[k]:
            k += 1
            continue
        j = k
        while j < on.size and on[j]:
            j += 1
        end = int(t_ns[j]) if j < on.size else int(t_ns[-1])
        out.append((int(t_ns[k]), end, float(np.abs(W[k:j]).max())))
        k = j
    return out


def onsets(t_ns: np.ndarray, flags: np.ndarray) -> list[tuple[int, list[int]]]:
    """(t ns, joints) where a joint's contact flag rose (from one output to the next)."""
    prev = np.vstack([np.zeros((1, flags.shape[1])), flags[:-1]])
    rise = (flags > 0.5) & (prev < 0.5)
    return [(int(t_ns[k]), np.flatnonzero(rise[k]).tolist()) for k in np.flatnonzero(rise.any(1))]


def metrics(runner, run, truth_t, truth_w, samples: int) -> dict:
    """The arm's figures of a finished replay (module doc)."""
    obs = runner.observer
    n = obs.n_joints
    fields = list(runner.convergence_fields)
    base = fields.index("tau_ext_valid")
    conv, t_est = run.est_conv, run.est_t
    valid = conv[:, base + DT.X_VALID] > 0.5 if conv.size else np.zeros(0, bool)
    flags = conv[:, base + DT.X_HEAD:base + DT.X_HEAD + n] if conv.size else np.zeros((0, n))
    latched = conv[:, base + DT.X_HEAD + n:base + DT.X_HEAD + 2 * n] if conv.size else flags
    ui = np.full((t_est.size, n), np.nan)
    ui[run.est_ui_idx] = run.est_ui
    out = {"samples": samples, "samples_with_estimate": int(valid.sum()),
           "estimate_fraction": float(valid.sum() / samples) if samples else 0.0,
           "joints": list(obs.joints)}
    events = onsets(t_est, flags)
    out["detections"] = [{"t_s": t / 1e9, "joints": [obs.joints[i] for i in js]}
                         for t, js in events]
    out["collisions_latched"] = [obs.joints[i] for i in np.flatnonzero(
        latched[-1] > 0.5)] if latched.shape[0] else []
    out["calibrated"] = bool(obs.calibrated)
    out["model_mismatch"] = obs.mismatch_message()
    out["mismatched_joints"] = [j for j, _ in obs.mismatch()]
    if truth_t is None:
        out["note"] = "no ground truth: no errors, delays or false alarms"
        return out
    windows = contacts(truth_t, truth_w)
    after = int(AFTER_CONTACT * 1e9)
    start = int(truth_t[0]) + int(FREE_START * 1e9)
    mask, w_at = match_truth(t_est, truth_t, truth_w)
    free = mask & valid & (t_est >= start)
    for a, b, _ in windows:
        free &= ~((t_est >= a) & (t_est < b + after))
    err = (ui - w_at)[free]
    rms = np.sqrt(np.mean(err ** 2, axis=0)) if err.size else np.full(n, math.nan)
    out["free_rms_Nm"] = dict(zip(obs.joints, rms.tolist()))
    out["free_rms_worst_Nm"] = float(np.nanmax(rms)) if err.size else None
    out["free_max_Nm"] = float(np.abs(err).max()) if err.size else None
    out["free_samples"] = int(free.sum())
    cs = []
    for a, b, peak in windows:
        hits = [t for t, _ in events if a <= t < b + after]
        cs.append({"start_s": a / 1e9, "end_s": b / 1e9, "peak_Nm": peak,
                   "delay_ms": (min(hits) - a) / 1e6 if hits else None})
    out["contacts"] = cs
    out["false_alarms"] = sum(1 for t, _ in events if t >= start and not any(
        a <= t < b + after for a, b, _ in windows))
    out["definitions"] = (
        f"free motion: from {FREE_START} s after the first truth sample, outside each contact "
        f"(true tau_ext not 0) and the {AFTER_CONTACT} s after it; a detection: a joint's contact "
        f"flag rising (its lower level crossed); delay: the first detection in [start, end + "
        f"{AFTER_CONTACT} s) after the contact's start; false alarm: a detection elsewhere "
        f"(from {FREE_START} s on)")
    return out
