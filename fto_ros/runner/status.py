"""The runner's /diagnostics: one Status per joint (and a summary over several), assembled
from the compiled loop's counters, the health windows and the observer's own
``diagnostics()``.  ROS-free.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.reasons import RESTARTS
from . import gate as G
from . import loop as L
from .health import FAILURES

OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}


@dataclass
class Status:
    """One /diagnostics status: level, a one-line message, key-values a person can read."""
    level: int
    message: str
    values: list[tuple[str, str]]


def state_name(runner, j: int) -> str:
    """'waiting', 'converging', 'converged' or 'diverging' (joint j of ``runner``)."""
    rs = runner._mem.rs[j]
    if rs[L.HAS_OUT] == 0.0 or math.isnan(rs[L.T0]):
        return "waiting"
    if not rs[L.LAST_CONV]:
        return "converging"
    if rs[L.LAST_RES] > runner.settings["convergence.residual_threshold"]:
        return "diverging"
    return "converged"


def update_time_us(times) -> tuple[float, float]:
    """(p50, p99) of the per-sample processing times ``times`` (us; nan before any)."""
    if not times:
        return float("nan"), float("nan")
    a = np.fromiter(times, float)
    return float(np.percentile(a, 50)), float(np.percentile(a, 99))


def statuses(runner, now: float | None) -> list[Status]:
    """[the status] with one joint; [summary, joint 1, ..., joint J] with several; the
    window of accepted samples (the measured rate) starts afresh at ``now``."""
    J = len(runner.observers)
    each = [joint_status(runner, now, j) for j in range(J)]
    runner._window_start = now
    runner._mem.rs[:, L.WIN_ACCEPTED] = 0.0
    if J == 1:
        return each
    worst = max(st.level for st in each)
    bad = [f"{name}: {st.message}" for name, st in zip(runner.joints, each) if st.level > OK]
    values = [("observer", runner.observer.TYPE), ("joints", ", ".join(runner.joints)),
              ("samples accepted", str(runner.accepted)),
              ("samples rejected", str(sum(runner.rejected.values())))]
    values += [(f"{name}: state", state_name(runner, j)) for j, name in enumerate(runner.joints)]
    p50, p99 = update_time_us(runner._update_us)
    values.append(("update time p50/p99 (us, all joints)", f"{p50:.1f} / {p99:.1f}"))
    message = "all joints OK" if not bad else "; ".join(bad)
    return [Status(worst, message, values)] + each


def take_health(runner, j: int) -> None:
    """Move the compiled loop's health bucket of joint j into its health window."""
    row, health = runner._mem.rc[j], runner._health[j]
    for name_, idx in (("accepted", L.HW_ACCEPTED), ("rejected", L.HW_REJECTED),
                       ("rebase", L.HW_REBASE)):
        if row[idx]:
            health.count(name_, int(row[idx]))
    for i, name_ in enumerate(RESTARTS):
        v = row[L.HW_RESTARTS + i]
        if v and name_ != "other":
            health.count(name_, int(v))
    row[L.HW:] = 0


def joint_status(runner, now: float | None, j: int) -> Status:
    """The status of joint j (see statuses)."""
    obs, s = runner.observers[j], runner.settings
    take_health(runner, j)
    state = state_name(runner, j)
    recent = runner._health[j].close(now)
    rs = runner._mem.rs[j]
    values: list[tuple[str, str]] = [("observer", obs.TYPE), ("state", state)]
    if runner.joints:
        values.insert(0, ("joint", runner.joints[j]))
    level, problems = OK, []
    if rs[L.HAS_OUT] != 0.0:
        gt = float(rs[L.LAST_GT])
        values += [("time since start (s)", f"{float(rs[L.LAST_SINCE]):.4f}"),
                   ("guaranteed convergence time (s)",
                    "none" if math.isinf(gt) else f"{gt:.4g}"),
                   ("output residual", f"{float(rs[L.LAST_RES]):.4g}")]
    accepted = int(rs[L.ACCEPTED])
    rejected = runner.rejected_of(j)
    values += [("samples accepted", str(accepted)),
               ("samples rejected", str(sum(rejected.values())))]
    values += [(f"rejected: {k}", str(v)) for k, v in sorted(rejected.items())]
    values += [(f"restarts: {k}", str(v)) for k, v in sorted(runner.resets_of(j).items())]
    rebases = int(rs[L.REBASES])
    gate = G.summary(rs[runner._mem.rl[L.L_GATE]:], *runner._mem.gate_args)
    values.append(("outlier gate", gate + (f"; re-based {rebases} time(s)" if rebases else "")))
    if obs.n_inputs:
        t_in = rs[L.T_INPUT]
        age = (now - t_in) if (now is not None and not math.isnan(t_in)) else None
        values.append(("input age (s)", "never received" if math.isnan(t_in) else
                       (f"{age:.4f}" if age is not None else "n/a")))
    p50, p99 = update_time_us(runner._update_us)
    values.append(("update time p50/p99 (us)", f"{p50:.1f} / {p99:.1f}"))
    win = rs[L.WIN_ACCEPTED]
    if now is not None and runner._window_start is not None and now > runner._window_start:
        rate = win / (now - runner._window_start)
        values.append(("measurement rate (Hz)", f"{rate:.1f}"))
        exp = s["diagnostics.expected_rate"]
        if exp > 0:
            values.append(("expected rate (Hz)", f"{exp:.1f}"))
            if rate < 0.8 * exp:
                level = WARN
                problems.append(f"rate {rate:.0f} Hz below expected {exp:.0f} Hz")
    values += [(k, str(v)) for k, v in obs.diagnostics().items()]
    window = f"last {s['diagnostics.window']:g} s"
    values.append((f"rejected ({window})", str(recent.get("rejected", 0))))
    failures = sum(recent.get(r, 0) for r in FAILURES)
    values.append((f"observer failures ({window})", str(failures)))
    if recent.get("rejected"):
        level = WARN
        problems.append(f"{recent['rejected']} sample(s) rejected in the {window} "
                        f"(last: {runner.last_rejection_of(j)})")
    if recent.get("rebase"):
        level = WARN
        problems.append("the outlier gate accepted a persisting change of the signal")
    own = getattr(obs, "warnings", None)      # the arm's method (global_norm's is a list)
    for warning in (own() if callable(own) else ()):        # the observer's own
        level = max(level, WARN)
        problems.append(warning)
    if state == "diverging":
        level = WARN
        problems.append("output residual above convergence.residual_threshold after the guaranteed time")
    if state == "waiting":
        level = WARN
        problems.append("no accepted measurement yet" if accepted == 0 else "restarted, waiting for a sample")
    idle = runner._health[j].idle_for(now)
    if accepted and idle > s["diagnostics.stale_after"]:
        level = WARN
        problems.append(f"no measurement accepted for {idle:.1f} s")
    if runner.last_error:
        values.append(("last observer error", runner.last_error))
    if failures:
        level = ERROR
        problems.append(f"the observer failed (non-finite or implausible values, or an internal "
                        f"error) and was restarted in the {window}")
    message = state if not problems else f"{state}: " + "; ".join(problems)
    return Status(level, message, values)
