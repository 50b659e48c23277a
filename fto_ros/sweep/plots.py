"""The sweep's figures (matplotlib's Agg canvas, no pyplot, no display):

- ``error_vs_<NAME>.png`` per swept parameter: the score (mean over the states of the RMS
  error after settling) of every run against the parameter's value, one colour per bag, a
  line through the best value at each point (the other parameters at their best), the
  bag's baselines as dashed horizontal lines;
- ``pareto.png``: convergence time against score, one panel per bag (with more than
  MAX_PANELS bags one panel of each setting's means over the bags, for the settings judged
  on every bag); the Pareto front (the settings no other one beats on both) joined and
  drawn; every point labelled with its setting (the front's only, with more than
  MAX_LABELS), the baselines as stars named by their tuning file; a run that never got
  below the tolerance is drawn apart, an open triangle in a "never" column right of the
  time axis (alone when no run converged), never at a made-up time.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Sequence

from .grid import Axis
from .results import BASELINE, SWEEP, aggregate, pareto_front

#: at most this many bags get a legend entry
MAX_LEGEND = 10
#: at most this many front points get a text label
MAX_LABELS = 12
#: up to this many bags the Pareto figure has one panel per bag, else one of the means
MAX_PANELS = 6


def _figure(width=7.5, height=4.8, rows=None):
    """A figure and its axes (a list of ``rows`` axes when ``rows`` is given)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(width, height), dpi=110)
    FigureCanvasAgg(fig)
    if rows is None:
        return fig, fig.subplots()
    return fig, list(fig.subplots(rows, 1, squeeze=False)[:, 0])


def _numeric(values: Sequence[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
               for v in values)


def _positive_log(ax, which: str, values: Sequence[float]) -> None:
    if values and min(values) > 0 and max(values) / min(values) >= 20:
        getattr(ax, f"set_{which}scale")("log")


def bag_labels(rows: Sequence[dict]) -> dict[str, str]:
    """``{bag: label}``: the bags' own names when they are unique, else the paths as given."""
    bags = list(dict.fromkeys(r["bag"] for r in rows))
    names = [Path(b).name for b in bags]
    return dict(zip(bags, names if len(set(names)) == len(names) else bags))


def file_name(name: str) -> str:
    return "error_vs_" + re.sub(r"[^A-Za-z0-9_.-]", "_", name) + ".png"


def error_vs_parameter(path: Path, axis: Axis, rows: Sequence[dict]) -> Path:
    """The figure of the score against ``axis``'s values."""
    fig, ax = _figure()
    numeric = _numeric(axis.values)
    pos = {t: (v if numeric else i) for i, (t, v) in enumerate(zip(axis.texts, axis.values))}
    labels = bag_labels(rows)
    bags = list(labels)
    colours = [f"C{i % 10}" for i in range(len(bags))]
    scores: list[float] = []
    failed = 0
    for k, (bag, colour) in enumerate(zip(bags, colours)):
        mine = [r for r in rows if r["bag"] == bag and r["role"] == SWEEP]
        ok = [r for r in mine if r["mean_rms_err"] is not None]
        xs = [pos[r[axis.name]] for r in ok]
        ys = [r["mean_rms_err"] for r in ok]
        scores += ys
        ax.scatter(xs, ys, s=14, color=colour, alpha=0.45, linewidths=0)
        bad = [pos[r[axis.name]] for r in mine if r["mean_rms_err"] is None]
        ax.scatter(bad, [0.02] * len(bad), marker="x", color="tab:red",
                   transform=ax.get_xaxis_transform(), label="failed" if bad and not failed else None)
        failed += len(bad)
        best = {}
        for x, y in zip(xs, ys):
            best[x] = min(y, best.get(x, math.inf))
        bx = sorted(best)
        ax.plot(bx, [best[x] for x in bx], "-o", color=colour, markersize=4, linewidth=1.2,
                label=labels[bag] if k < MAX_LEGEND else None)
        for r in rows:
            if r["bag"] == bag and r["role"] == BASELINE and r["mean_rms_err"] is not None:
                ax.axhline(r["mean_rms_err"], color=colour, linestyle="--", linewidth=0.9)
                scores.append(r["mean_rms_err"])
    if not numeric:
        ax.set_xticks(range(len(axis.texts)), axis.texts, rotation=30, ha="right", fontsize=8)
    else:
        _positive_log(ax, "x", [float(v) for v in axis.values])
    _positive_log(ax, "y", scores)
    ax.set_xlabel(axis.name)
    ax.set_ylabel("mean RMS error after settle (state units)")
    title = f"error against {axis.name} (line: best over the other parameters"
    title += "; dashed: baselines)" if any(r["role"] == BASELINE for r in rows) else ")"
    if failed:
        title += f"\nx: {failed} run(s) failed or without error metrics"
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    if bags and ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, format="png")
    return path


def baseline_name(params: str) -> str:
    """A baseline's legend name: its tuning file's stem (the last params file), not the
    comma-separated file list."""
    return Path(params.split(",")[-1].strip()).stem or params


def _pareto_panel(ax, points: Sequence[tuple[str, float, float]],
                  baselines: Sequence[tuple[str, float, float]], title: str) -> None:
    """One panel: (label, convergence time, score) points, their front, the baselines.  Runs
    that never got below the tolerance are drawn apart, in a 'never' column right of the
    time axis (or alone, when none converged), with their own marker."""
    finite = [c for _, c, _ in (*points, *baselines) if math.isfinite(c)]
    t_max = max(finite, default=0.0)
    never_x = 1.2 * t_max if t_max > 0 else 1.0

    def x_of(c):
        return c if math.isfinite(c) else never_x

    done = [p for p in points if math.isfinite(p[1])]
    never = [p for p in points if not math.isfinite(p[1])]
    ax.scatter([c for _, c, _ in done], [e for _, _, e in done], s=18, color="0.55",
               label=f"setting ({len(done)})" if done else None)
    ax.scatter([never_x] * len(never), [e for _, _, e in never], s=26, marker="v",
               facecolors="none", edgecolors="tab:red",
               label=f"setting, never below the tolerance ({len(never)})" if never else None)
    front = [done[i] for i in pareto_front([(c, e) for _, c, e in done])]
    if front:
        ax.plot([c for _, c, _ in front], [e for _, _, e in front], "-o", color="tab:blue",
                drawstyle="steps-post", markersize=5, label="Pareto front")
    named = list(points) if len(points) <= MAX_LABELS else front[:MAX_LABELS]
    for k, (label, c, e) in enumerate(baselines):
        ax.scatter([x_of(c)], [e], marker="*", s=120, color=f"C{(k + 1) % 10}",
                   edgecolors="black", linewidths=0.5, zorder=5,
                   label=f"baseline {baseline_name(label)}"
                   + ("" if math.isfinite(c) else " (never below the tolerance)"))
    some_never = len(finite) < len(points) + len(baselines)
    ax.set_xlim(0.0, (1.3 * t_max if t_max > 0 else 2.0) if some_never
                else 1.1 * t_max if t_max > 0 else 1.0)
    if some_never:
        if finite:
            ax.axvline(1.1 * t_max, color="tab:red", linestyle=":", linewidth=1.0)
            ticks = [t for t in ax.get_xticks() if 0 <= t <= t_max * (1 + 1e-9)]
            ax.set_xticks(ticks + [never_x], [f"{t:g}" for t in ticks] + ["never"])
        else:
            ax.set_xticks([never_x], ["never"])
    scores = [e for _, _, e in (*points, *baselines)]
    _positive_log(ax, "y", scores)
    if scores and ax.get_yscale() == "linear":
        lo, hi = min(scores), max(scores)
        pad = max(0.1 * (hi - lo), 0.1 * max(abs(lo), abs(hi)), 1e-12)
        ax.set_ylim(lo - pad, hi + pad)
    _annotate(ax, [(label, x_of(c), e) for label, c, e in named])
    ax.set_title(title + ("" if points else ": no setting ran with ground truth"), fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:          # (matplotlib warns on an empty legend)
        ax.legend(fontsize=6, loc="best")


def _annotate(ax, named: Sequence[tuple[str, float, float]]) -> None:
    """Label every point; labels of points drawn within a few pixels of each other are
    stacked instead of printed over each other."""
    placed: list[tuple[float, float]] = []
    for label, x, y in sorted(named, key=lambda p: (p[2], p[1])):
        px, py = ax.transData.transform((x, y))
        k = sum(1 for qx, qy in placed if abs(qx - px) < 40 and abs(qy - py) < 8)
        placed.append((px, py))
        ax.annotate(label, (x, y), fontsize=6, xytext=(4, 4 + 8 * k), textcoords="offset points",
                    arrowprops=dict(arrowstyle="-", color="0.7", linewidth=0.5) if k else None)


def pareto(path: Path, rows: Sequence[dict]) -> Path:
    """The Pareto figure: one panel per bag (up to MAX_PANELS bags), else one panel of the
    settings' means over the bags (those judged on every bag)."""
    labels = bag_labels(rows)
    bags = list(labels)
    if len(bags) <= MAX_PANELS:
        panels = []
        for bag in bags:
            mine = [r for r in rows if r["bag"] == bag and r["mean_rms_err"] is not None]
            panels.append((
                [(r["_setting"], r["convergence_time_s"], r["mean_rms_err"]) for r in mine
                 if r["role"] == SWEEP],
                [(r["_setting"], r["convergence_time_s"], r["mean_rms_err"]) for r in mine
                 if r["role"] == BASELINE], labels[bag]))
        xlabel = "measured convergence time (s)"
    else:
        def points(role):
            return [(a["setting"], a["convergence_time_s"], a["mean_rms_err"])
                    for a in aggregate(rows, role)]
        panels = [(points(SWEEP), points(BASELINE), f"mean over {len(bags)} bags")]
        xlabel = f"measured convergence time (s), mean over {len(bags)} bags"
    fig, axs = _figure(7.5, 1.0 + 3.6 * len(panels), len(panels))
    for ax, (pts, base, title) in zip(axs, panels):
        _pareto_panel(ax, pts, base, title)
        ax.set_ylabel("mean RMS error after settle", fontsize=8)
    axs[-1].set_xlabel(xlabel)
    fig.suptitle("convergence time against steady-state error", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, format="png")
    return path


def write_all(out: Path, axes: Sequence[Axis], rows: Sequence[dict]) -> list[Path]:
    """Every figure of the sweep into ``out``; their paths."""
    paths = [error_vs_parameter(out / file_name(a.name), a, rows) for a in axes]
    paths.append(pareto(out / "pareto.png", rows))
    return paths
