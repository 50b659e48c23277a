"""The per-joint mode's error metrics: each joint's published position, velocity and effort
(the per-joint plan's ``estimated_joint_states``, runner/sources/plan.py) against a ground truth JointState mapped by joint name, as a
user records it (``topics.true_state`` of type sensor_msgs/JointState: its position,
velocity and effort of each joint, in any order), per joint and over all joints.

A truth message without one of the joints, or whose field is not as long as its names,
gives no truth for that joint at that time (the estimate is left out, counted as
unmatched); a field the truth leaves empty has no error metrics.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from . import metrics as M

FIELDS = ("position", "velocity", "effort")


def _truth_columns(msgs, joints) -> dict[str, np.ndarray]:
    """Per field, the truth (N, J) by joint name (NaN: none in that message)."""
    out = {f: np.full((len(msgs), len(joints)), np.nan) for f in FIELDS}
    where: dict = {}
    for i, msg in enumerate(msgs):
        names = tuple(msg.name)
        idx = where.get(names)
        if idx is None:
            pos = {n: k for k, n in enumerate(names)} if len(set(names)) == len(names) else {}
            idx = where[names] = np.array([pos.get(j, -1) for j in joints])
        have = idx >= 0
        for f in FIELDS:
            vals = np.asarray(getattr(msg, f), dtype=float)
            if vals.size == len(names) and have.any():
                out[f][i, have] = vals[idx[have]]
    return out


def field_units(spec, units: Sequence[str], ui_units: Sequence[str]) -> dict[str, str]:
    """The unit of each field of the plan's ``estimated_joint_states`` ``spec`` (the plant's
    unit of the state or unknown input it publishes); '' where the plant gives none."""
    out = {}
    for f, field in zip(FIELDS, spec.fields):
        unit = ""
        if field is not None and len(field[1]):
            src, i = field[0], int(field[1][0])
            names = units if src == "x" else ui_units
            unit = names[i] if 0 <= i < len(names) else ""
        out[f] = unit
    return out


def joint_errors(plan, run, truth, settle: float, units: Sequence[str] = (),
                 ui_units: Sequence[str] = ()) -> tuple[dict[str, Any] | None, str | None]:
    """({"per_joint": {joint: error_stats of its fields}, "all_joints": error_stats of every
    joint's errors together, "units": {field: unit}, ...}, None), or (None, why there are
    none); ``plan`` the per-joint source's output plan.  Each field in its own unit: no norm
    over the fields (rad, rad/s, N m)."""
    t_truth, msgs = truth
    if not len(msgs):
        return None, "no ground truth: the truth topic has no messages"
    spec = next(s for s in plan.specs if s.topic == "estimated_joint_states")
    names = list(spec.labels)
    cols = _truth_columns(msgs, names)
    x, w = run.est_xj, run.est_w
    est = {}
    for f, field in zip(FIELDS, spec.fields):     # (k, J) per field the plan fills
        if field is not None:
            src, c = field
            est[f] = {"x": x, "w": w}[src][:, spec.rows, c]
    fields = [f for f in FIELDS if f in est and np.isfinite(cols[f]).any()]
    if not fields or not run.est_t.size:
        return None, "no estimate and truth field in common"
    per_joint: dict[str, Any] = {}
    all_err, all_settled = [], []
    matched = unmatched = 0
    for j, name in enumerate(names):
        rows = np.flatnonzero(run.est_ok[:, j])
        truth_j = np.column_stack([cols[f][:, j] for f in fields])
        good = np.all(np.isfinite(truth_j), axis=1)
        mask, at = M.match_truth(run.est_t[rows], t_truth[good], truth_j[good])
        rows = rows[mask]
        err = at[mask] - np.column_stack([est[f][rows, j] for f in fields])
        settled = run.est_cj[rows, j, 0] >= settle - 1e-9
        per_joint[name] = _by_field(err, fields, settled)
        per_joint[name]["matched_samples"] = int(rows.size)
        matched += int(rows.size)
        unmatched += int((~mask).sum())
        all_err.append(err)
        all_settled.append(settled)
    overall = _by_field(np.concatenate(all_err), fields, np.concatenate(all_settled))
    fu = field_units(spec, units, ui_units)
    return {"fields": fields, "units": {f: fu[f] for f in fields}, "per_joint": per_joint,
            "all_joints": overall,
            "matched_samples": matched, "unmatched_samples": unmatched,
            "definition": "error = truth - estimate per joint and field (the JointState the "
                          "replay publishes: position, velocity, effort), the truth JointState "
                          "mapped by joint name and taken at each estimate's stamp (exact ns "
                          "match, else linear interpolation); 'all_joints' pools every joint's "
                          "errors field by field; 'after_settle' as in 'errors'; no norm "
                          "over the fields (each in its own unit, 'units')"}, None


def _by_field(err: np.ndarray, fields, settled) -> dict[str, Any]:
    """error_stats per field, without a norm across the fields."""
    out = M.error_stats(err, fields, settled)
    del out["norm"]
    return out

