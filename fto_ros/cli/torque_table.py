"""The main job's external-torque table, from the replays ``fto-report`` made of the arm's
bags (bags/arm7_*) through the arm's external-torque families (config/arm7_external_torque.yaml,
config/arm7_momentum_observer.yaml: replays like any observer's, with ``metrics.json``'s
``arm`` section, replay/arm_metrics.py).

Per (estimator, bag): the velocity's RMS error (the estimate's ``<joint>_dot`` against the
truth, after the settle time, worst joint), tau_ext's RMS and largest error in free motion
(worst joint), each contact's detection delay (a joint's lower level crossed), the false
alarms, the samples that carry an estimate, and the model-mismatch check.
"""
from __future__ import annotations

import math


def is_arm(pair) -> bool:
    """Whether a report pair is a replay of an arm's external-torque family."""
    return bool(pair.metrics and pair.metrics.get("arm"))


def _g(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.{digits}g}"


def _velocity(m: dict) -> float | None:
    per = ((m.get("errors") or {}).get("per_state") or {})
    vals = [v["rms_after_settle"] for k, v in per.items() if k.endswith("_dot")
            and v.get("rms_after_settle") is not None]
    return max(vals) if vals else None


def row(pair) -> list[str]:
    """One row of the table (module doc)."""
    m = pair.metrics
    a = m["arm"]
    delays = " / ".join("missed" if c["delay_ms"] is None else f"{c['delay_ms']:.0f}"
                        for c in a.get("contacts", [])) or "no contact"
    mismatch = ", ".join(a.get("mismatched_joints") or []) or "none"
    return [f"{m['observer_type']} ({pair.config.stem})", pair.bag.name, _g(_velocity(m)),
            _g(a.get("free_rms_worst_Nm")), _g(a.get("free_max_Nm")), delays,
            str(a.get("false_alarms", "n/a")), f"{100 * a['estimate_fraction']:.1f} %", mismatch]


HEAD = ["estimator", "bag", "velocity RMS err, worst joint (rad/s)",
        "tau_ext RMS err in free motion, worst joint (Nm)", "max err in free motion (Nm)",
        "detection delay (ms)", "false alarms", "samples with an estimate",
        "model-mismatch WARN"]


def table(pairs) -> str | None:
    """The markdown table of the arm families' replays among ``pairs`` (None: none)."""
    rows = [row(p) for p in pairs if is_arm(p)]
    if not rows:
        return None
    lines = ["| " + " | ".join(HEAD) + " |", "|" + "---|" * len(HEAD)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)
