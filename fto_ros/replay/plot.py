"""The replay plot: estimate vs truth per state and the error norm (one PNG).

Uses matplotlib's Agg canvas directly (no pyplot, no global backend change,
no display needed).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ..plant.block import labelled

#: at most this many points per line (evenly decimated; the plot is for reading, not data)
MAX_POINTS = 20000


def _decimate(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    n = len(arrays[0])
    if n <= MAX_POINTS:
        return arrays
    step = int(math.ceil(n / MAX_POINTS))
    return tuple(a[::step] for a in arrays)


def _label(name: str, units: Sequence[str], i: int) -> str:
    return labelled(name, units[i] if i < len(units) else "")


def plot_replay(path: str | Path, *, t: np.ndarray, estimate: np.ndarray,
                state_names: Sequence[str], truth_t: np.ndarray | None = None,
                truth: np.ndarray | None = None, err_t: np.ndarray | None = None,
                err_norm: np.ndarray | None = None, guaranteed_time: float = math.inf,
                settle_time: float | None = None, tolerance: float | None = None,
                t_start: float = 0.0, title: str = "",
                ui_t: np.ndarray | None = None, ui_estimate: np.ndarray | None = None,
                ui_truth_t: np.ndarray | None = None, ui_truth: np.ndarray | None = None,
                ui_names: Sequence[str] = (), units: Sequence[str] = (),
                ui_units: Sequence[str] = ()) -> Path:
    """Write the replay figure to ``path`` (PNG) and return the path.

    Times are seconds since the start of the bag.  ``t``/``estimate``: the
    accepted samples (N,), (N, n); ``truth_t``/``truth``: ground truth (may be
    None); ``err_t``/``err_norm``: the error norm at the matched samples.
    ``ui_*``: the unknown-input estimate (and its truth, may be None), one more
    panel per component, drawn like the states.
    ``guaranteed_time`` (seconds after ``t_start``, the observer's first
    sample) is marked by a labelled vertical line; inf means no guarantee.
    ``units``, ``ui_units``: the unit of each state and unknown input ('' or missing: none),
    in the axis labels (the plant block's ``plant.units``).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t = np.asarray(t, dtype=float)
    estimate = np.asarray(estimate, dtype=float)
    n = estimate.shape[1] if estimate.ndim == 2 else max(len(state_names), 1)
    estimate = estimate.reshape(len(t), n)
    has_truth = truth is not None and truth_t is not None and len(truth_t) > 0
    has_err = err_norm is not None and err_t is not None and len(err_t) > 0
    has_ui = ui_estimate is not None and ui_t is not None and len(ui_t) > 0
    n_ui = 0
    if has_ui:
        ui_estimate = np.asarray(ui_estimate, dtype=float).reshape(len(ui_t), -1)
        n_ui = ui_estimate.shape[1]
    rows = n + n_ui + (1 if has_err else 0)
    fig = Figure(figsize=(9.0, 1.9 * rows + 0.8), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    if title:
        fig.suptitle(title, fontsize=10, y=0.995)

    guaranteed = math.isfinite(guaranteed_time)
    t_mark = t_start + guaranteed_time if guaranteed else None

    def mark(ax, label: bool) -> None:
        if t_mark is not None:
            ax.axvline(t_mark, color="tab:red", linestyle="--", linewidth=1.0,
                       label=f"guaranteed time {guaranteed_time:g} s" if label else None)

    te, xe = _decimate(t, estimate)
    if has_truth:
        tt = np.asarray(truth_t, dtype=float)
        xt = np.asarray(truth, dtype=float).reshape(len(tt), -1)
        tt, xt = _decimate(tt, xt)
    for i in range(n):
        ax = axes[i]
        name = state_names[i] if i < len(state_names) else f"x{i}"
        clipped = False
        if has_truth and i < xt.shape[1]:
            ax.plot(tt, xt[:, i], color="black", linewidth=1.0, label="truth")
            lo, hi = float(np.min(xt[:, i])), float(np.max(xt[:, i]))
            pad = max(0.5 * (hi - lo), 0.05 * max(abs(lo), abs(hi)), 1e-6)
            ylim = (lo - pad, hi + pad)
            # the start-up transient may be orders of magnitude larger: keep the truth readable
            clipped = bool(np.any(xe[:, i] < ylim[0]) or np.any(xe[:, i] > ylim[1]))
        ax.plot(te, xe[:, i], color="tab:blue", linewidth=0.9,
                linestyle="--" if has_truth else "-", label="estimate")
        if clipped:
            ax.set_ylim(*ylim)
            ax.text(0.99, 0.04, "estimate clipped (transient off scale)", transform=ax.transAxes,
                    fontsize=7, ha="right", va="bottom", color="tab:blue")
        mark(ax, label=(i == 0))
        ax.set_ylabel(_label(name, units, i))
        ax.grid(True, alpha=0.3)
        if i == 0:  # one legend for the state panels, above them: it hides no curve
            handles, labels = ax.get_legend_handles_labels()
            fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=8,
                       bbox_to_anchor=(0.5, 0.965), frameon=False)
    if has_ui:
        ue_t, ue = _decimate(np.asarray(ui_t, float), ui_estimate)
        has_ui_truth = ui_truth is not None and ui_truth_t is not None and len(ui_truth_t) > 0
        if has_ui_truth:
            ut = np.asarray(ui_truth_t, dtype=float)
            ux = np.asarray(ui_truth, dtype=float).reshape(len(ut), -1)
            ut, ux = _decimate(ut, ux)
        for j in range(n_ui):
            ax = axes[n + j]
            name = ui_names[j] if j < len(ui_names) else f"zeta{j}"
            clipped = False
            if has_ui_truth and j < ux.shape[1]:
                ax.plot(ut, ux[:, j], color="black", linewidth=1.0)
                lo, hi = float(np.min(ux[:, j])), float(np.max(ux[:, j]))
                pad = max(0.5 * (hi - lo), 0.05 * max(abs(lo), abs(hi)), 1e-6)
                ylim = (lo - pad, hi + pad)
                clipped = bool(np.any(ue[:, j] < ylim[0]) or np.any(ue[:, j] > ylim[1]))
            ax.plot(ue_t, ue[:, j], color="tab:orange", linewidth=0.9,
                    linestyle="--" if has_ui_truth else "-")
            if clipped:
                ax.set_ylim(*ylim)
                ax.text(0.99, 0.04, "estimate clipped (transient off scale)",
                        transform=ax.transAxes, fontsize=7, ha="right", va="bottom",
                        color="tab:orange")
            mark(ax, label=False)
            ax.set_ylabel(f"{_label(name, ui_units, j)}\n(unknown input)", fontsize=8)
            ax.grid(True, alpha=0.3)
    if has_err:
        ax = axes[-1]
        et, en = _decimate(np.asarray(err_t, float), np.asarray(err_norm, float))
        floor = np.finfo(float).tiny
        ax.semilogy(et, np.maximum(en, floor), color="tab:purple", linewidth=0.9,
                    label="|x - x_hat| (2-norm)")
        if tolerance is not None and tolerance > 0:
            ax.axhline(tolerance, color="gray", linestyle=":", linewidth=1.0,
                       label=f"tolerance {tolerance:g}")
        if settle_time is not None:
            ax.axvline(t_start + settle_time, color="tab:green", linestyle=":", linewidth=1.0,
                       label=f"settle time {settle_time:g} s")
        mark(ax, label=True)
        same = set(units[:n]) if len(units) >= n else {""}
        ax.set_ylabel("error norm" + (f" [{same.pop()}]" if len(same) == 1 and "" not in same
                                      else " (mixed units)" if any(units) else ""))
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, framealpha=0.8)
    if len(t) == 0:
        axes[0].text(0.5, 0.5, "no accepted samples", transform=axes[0].transAxes,
                     ha="center", va="center", fontsize=12, color="tab:red")
    if not guaranteed:
        axes[0].text(0.01, 0.95, "no guaranteed convergence time",
                     transform=axes[0].transAxes, fontsize=8, va="top", color="tab:red")
    axes[-1].set_xlabel("bag time (s)")
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.955))
    path = Path(path)
    fig.savefig(path, format="png")
    return path
