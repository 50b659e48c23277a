"""A sweep's results: one row per run, ``results.csv``, the best settings and the summary.

Rows are plain dicts of Python values (numbers, strings, None); :func:`write_csv` writes
them with every float at full precision (``repr``), None as an empty cell, and a
convergence time of ``inf`` for "never below the tolerance".

**Best** (:func:`best_per_bag`, :func:`best_overall`): the setting with the least
*score*, the mean over the states of the RMS error after the settle time (state units; the
``mean_rms_err`` column), ties broken by the earlier measured convergence time, then by
grid order.  Over all bags: the least mean score over the bags, among the settings that ran
(with ground truth) on every bag; ties by mean convergence time.  Baselines take part in
neither: they are the yardstick the summary and the plots set beside the best.
"""
from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable, Sequence

from .grid import Axis, Setting
from .tasks import CONFIG, Outcome, Run

SWEEP, BASELINE = "sweep", "baseline"
#: columns whose values depend on where and when a run executed, not on its inputs
TIMING_COLUMNS = ("replay_speed_x_realtime", "wall_s", "cpu_s", "worker")
_HEAD = ("status", "observer", "convergence_time_s", "mean_rms_err")
_TAIL = ("rejected", "restarts", "guaranteed_time_s", "settle_time_s", *TIMING_COLUMNS,
         "run", "role", "error")


def make_row(run: Run, setting: Setting | None, outcome: Outcome, axes: Sequence[Axis]) -> dict:
    """The row of one run (``setting`` None for a baseline)."""
    m = outcome.metrics
    row: dict[str, Any] = {"bag": run.bag, "params": ",".join(run.params)}
    for a in axes:
        row[a.name] = setting.texts[a.name] if setting is not None else None
    row.update(status="ok" if m is not None else "error", observer=m and m["observer_type"],
               convergence_time_s=None, mean_rms_err=None)
    per_state = ((m or {}).get("errors") or {}).get("per_state") or {}
    if per_state:
        conv = m["convergence_time_s"]
        row["convergence_time_s"] = math.inf if conv is None else conv
        rms = [e["rms_after_settle"] for e in per_state.values()]
        row["mean_rms_err"] = None if None in rms else sum(rms) / len(rms)
        for name, e in per_state.items():
            row[f"rms_err.{name}"] = e["rms_after_settle"]
        for name, e in per_state.items():
            row[f"max_err.{name}"] = e["max_abs_after_settle"]
    row.update(
        rejected=m and m["samples_rejected"], restarts=m and m["restarts"],
        guaranteed_time_s=m and m["guaranteed_time_s"], settle_time_s=m and m["settle_time_s"],
        replay_speed_x_realtime=m and m["replay_speed_x_realtime"],
        wall_s=round(outcome.wall_s, 4), cpu_s=round(outcome.cpu_s, 4), worker=outcome.worker,
        run=run.index,
        role=BASELINE if setting is None else SWEEP, error=outcome.error)
    # not written: what the summary needs to group and judge rows
    row["_setting"] = setting.label() if setting is not None else ",".join(run.params)
    row["_kind"] = outcome.kind
    return row


def columns(rows: Sequence[dict], axes: Sequence[Axis]) -> list[str]:
    """bag, params, the swept parameters, the head metrics, every state's errors (in order of
    first appearance), the rest."""
    states = list(dict.fromkeys(k for r in rows for k in r if k.startswith(("rms_err.", "max_err."))))
    states.sort(key=lambda k: not k.startswith("rms_err."))  # stable: the RMS errors first
    return ["bag", "params", *(a.name for a in axes), *_HEAD, *states, *_TAIL]


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "inf" if v == math.inf else repr(v)
    return str(v)


def write_csv(path: Path, rows: Sequence[dict], axes: Sequence[Axis]) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        cols = columns(rows, axes)
        w.writerow(cols)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in cols])


# --------------------------------------------------------------------------------- best
def _judged(rows: Iterable[dict], role: str = SWEEP) -> list[dict]:
    return [r for r in rows if r["role"] == role and r["mean_rms_err"] is not None]


def best_per_bag(rows: Sequence[dict]) -> dict[str, dict]:
    """``{bag: best row}`` over the sweep rows with an error score."""
    best: dict[str, dict] = {}
    for r in sorted(_judged(rows),
                    key=lambda r: (r["mean_rms_err"], r["convergence_time_s"], r["run"])):
        best.setdefault(r["bag"], r)
    return best


def aggregate(rows: Sequence[dict], role: str = SWEEP) -> list[dict]:
    """Per setting (or per baseline), the mean score and mean convergence time over the
    bags, for those judged on every bag of the sweep; in grid order."""
    bags = list(dict.fromkeys(r["bag"] for r in rows))
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in _judged(rows, role):
        groups[r["_setting"]].append(r)
    out = []
    for label, group in groups.items():
        if sorted(r["bag"] for r in group) != sorted(bags):
            continue
        out.append({"setting": label, "order": min(r["run"] for r in group),
                    "mean_rms_err": sum(r["mean_rms_err"] for r in group) / len(group),
                    "convergence_time_s": sum(r["convergence_time_s"] for r in group) / len(group)})
    return sorted(out, key=lambda a: a["order"])


def best_overall(rows: Sequence[dict]) -> dict | None:
    """The best setting over all bags (see the module doc), or None."""
    return min(aggregate(rows), default=None,
               key=lambda a: (a["mean_rms_err"], a["convergence_time_s"], a["order"]))


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points not dominated in (convergence time, error), both minimised,
    sorted by convergence time; of equal points the first is kept."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1], i))
    front, best_err = [], math.inf
    for i in order:
        if points[i][1] < best_err:
            front.append(i)
            best_err = points[i][1]
    return front


# ------------------------------------------------------------------------------ summary
def _g(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.4g}"


def _time(v: float | None) -> str:
    return "n/a" if v is None else "never" if v == math.inf else f"{v:.4g} s"


def _judgement(r: dict, mean: str = "") -> str:
    return (f"mean RMS error {_g(r['mean_rms_err'])}, {mean}convergence "
            f"{_time(r['convergence_time_s'])}")


def summary(rows: Sequence[dict], n_settings: int, engine: str, wall_s: float,
            tolerance: float) -> str:
    """The text summary (also printed)."""
    sweep = [r for r in rows if r["role"] == SWEEP]
    baseline = [r for r in rows if r["role"] == BASELINE]
    failed = [r for r in rows if r["status"] != "ok"]
    bags = list(dict.fromkeys(r["bag"] for r in rows))
    lines = [f"fto-sweep: {len(sweep)} run(s) = {n_settings} setting(s) x {len(bags)} bag(s)"
             + (f", + {len(baseline)} baseline run(s)" if baseline else "")
             + f": {len(rows) - len(failed)} ok, {len(failed)} failed; {engine}, "
               f"{wall_s:.1f} s wall",
             "best = least mean over the states of the RMS error after the settle time (state "
             f"units); ties: earlier convergence (largest error below {tolerance:g} to the end)",
             "best per bag:"]
    best = best_per_bag(rows)
    for bag in bags:
        b = best.get(bag)
        lines.append(f"  {bag}: " + (f"{b['_setting']}: {_judgement(b)}" if b else
                                     "no setting ran with ground truth"))
        for r in baseline:
            if r["bag"] == bag:
                lines.append(f"    baseline {r['params']}: "
                             + (_judgement(r) if r["mean_rms_err"] is not None
                                else f"FAILED: {r['error']}" if r["error"] else "no error metrics"))
    if len(bags) > 1:
        overall = best_overall(rows)
        lines.append("best over all bags (least mean over the bags, among the settings judged on "
                     "every bag): " + (f"{overall['setting']}: {_judgement(overall, 'mean ')}"
                                       if overall else "none ran on every bag"))
    if failed:
        lines.append(f"failed runs ({len(failed)}; the 'error' column of results.csv):")
        for r in failed[:10]:
            what = r["_setting"] if r["role"] == SWEEP else f"baseline {r['params']}"
            lines.append(f"  {r['bag']}, {what}: {r['error']}")
        if len(failed) > 10:
            lines.append(f"  ... and {len(failed) - 10} more")
    return "\n".join(lines)


def exit_code(rows: Sequence[dict]) -> int:
    """0: every run ran, or some were refused for their parameters while others ran (a grid's
    bad corners are results); 2: every run was refused for its parameters; 1: a run failed
    for its bag or at run time."""
    failed = [r for r in rows if r["status"] != "ok"]
    if any(r["_kind"] != CONFIG for r in failed):
        return 1
    return 2 if failed and len(failed) == len(rows) else 0
