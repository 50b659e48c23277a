"""Error metrics of a replay, from plain numpy arrays (no ROS, no bag I/O).

Times are integer nanoseconds (bag log times) or float seconds as each
function says; estimates and truths are ``(N, n)`` float arrays.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import BadArgument


def match_truth(t_est_ns: np.ndarray, t_truth_ns: np.ndarray,
                x_truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The truth at each estimate time: ``(mask, x_at)``.

    An estimate whose time equals a truth time (to the nanosecond) takes that
    truth sample exactly; one strictly between two truth samples takes the
    linear interpolation; one outside ``[t_truth[0], t_truth[-1]]`` is left out
    (``mask`` False, its row of ``x_at`` is NaN).  ``t_truth_ns`` must be
    non-decreasing; for repeated truth stamps the last sample wins.
    """
    t_est = np.asarray(t_est_ns, dtype=np.int64).reshape(-1)
    t_tr = np.asarray(t_truth_ns, dtype=np.int64).reshape(-1)
    x_tr = np.asarray(x_truth, dtype=float)
    if x_tr.ndim == 1:
        x_tr = x_tr.reshape(-1, 1)
    n = x_tr.shape[1] if x_tr.ndim == 2 else 0
    x_at = np.full((t_est.size, n), np.nan)
    mask = np.zeros(t_est.size, dtype=bool)
    if t_tr.size == 0 or t_est.size == 0:
        return mask, x_at
    if np.any(np.diff(t_tr) < 0):
        raise BadArgument("truth times must be non-decreasing")
    # index of the last truth sample <= t_est
    hi = np.searchsorted(t_tr, t_est, side="right") - 1
    inside = (hi >= 0) & (t_est <= t_tr[-1])
    exact = inside & (t_tr[np.clip(hi, 0, None)] == t_est)
    x_at[exact] = x_tr[hi[exact]]
    between = inside & ~exact
    if np.any(between):
        i0 = hi[between]
        i1 = i0 + 1
        # integer differences first: no precision lost on large absolute stamps
        w = ((t_est[between] - t_tr[i0]).astype(float)
             / (t_tr[i1] - t_tr[i0]).astype(float))[:, None]
        x_at[between] = (1.0 - w) * x_tr[i0] + w * x_tr[i1]
    mask[inside] = True
    return mask, x_at


def _rms(a: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(a * a))) if a.size else None


def _max_abs(a: np.ndarray) -> float | None:
    return float(np.max(np.abs(a))) if a.size else None


def error_stats(err: np.ndarray, state_names: Sequence[str],
                settled: np.ndarray, units: Sequence[str] | None = None) -> dict[str, Any]:
    """Per-state and norm statistics of the error rows ``err`` (N, n).

    ``settled`` marks the rows after the settle time.  Returns
    ``{"per_state": {name: {rms, max_abs, rms_after_settle, max_abs_after_settle}},
    "norm": {...same, for the Euclidean norm of the error}}``; a statistic over
    no samples is None.  With ``units`` (one per state): ``"units"`` {name: unit}, and no
    norm when they differ (rad, rad/s and N m are never added up).
    """
    err = np.asarray(err, dtype=float)
    settled = np.asarray(settled, dtype=bool)
    per_state = {}
    for i, name in enumerate(state_names):
        e = err[:, i]
        per_state[name] = {
            "rms": _rms(e), "max_abs": _max_abs(e),
            "rms_after_settle": _rms(e[settled]), "max_abs_after_settle": _max_abs(e[settled]),
        }
    out: dict[str, Any] = {"per_state": per_state}
    if units is not None and len(units) == len(state_names):
        out["units"] = dict(zip(state_names, units))
        if len(set(units)) > 1:
            out["norm_note"] = "no norm: the states have different units"
            return out
    norm = np.sqrt(np.sum(err * err, axis=1)) if err.size else np.zeros(0)
    out["norm"] = {"rms": _rms(norm), "max": _max_abs(norm),
                   "rms_after_settle": _rms(norm[settled]),
                   "max_after_settle": _max_abs(norm[settled])}
    return out


def convergence_time(t: np.ndarray, err_max_abs: np.ndarray, tolerance: float) -> float | None:
    """First time from which ``err_max_abs`` stays below ``tolerance`` to the end.

    ``t`` (seconds, non-decreasing) and ``err_max_abs`` (the largest absolute
    error over all states at each time) have equal length.  Returns ``t`` of the
    first sample of the final run of samples below tolerance, or None when the
    last sample is not below it (never converged) or there are no samples.
    A non-finite error counts as above tolerance.
    """
    t = np.asarray(t, dtype=float)
    e = np.asarray(err_max_abs, dtype=float)
    if t.size == 0:
        return None
    bad = ~(e < tolerance)  # NaN counts as bad
    if not np.any(bad):
        return float(t[0])
    last_bad = int(np.flatnonzero(bad)[-1])
    if last_bad == t.size - 1:
        return None
    return float(t[last_bad + 1])


def percentiles_us(samples_us: np.ndarray | Sequence[float]) -> dict[str, Any]:
    """``{count, p50, p99, mean, max}`` of a list of durations in microseconds."""
    a = np.asarray(samples_us, dtype=float)
    if a.size == 0:
        return {"count": 0, "p50": None, "p99": None, "mean": None, "max": None}
    return {"count": int(a.size), "p50": float(np.percentile(a, 50)),
            "p99": float(np.percentile(a, 99)), "mean": float(a.mean()), "max": float(a.max())}


def default_settle_time(guaranteed_time: float, margin: float = 0.01,
                        fallback: float = 0.11) -> tuple[float, str]:
    """(settle time, how it was chosen): the guarantee plus a margin, else a fixed fallback."""
    if math.isfinite(guaranteed_time):
        return guaranteed_time + margin, f"guaranteed_time + {margin:g} s"
    return fallback, f"fixed {fallback:g} s (the observer has no guaranteed time)"


def json_safe(obj: Any) -> Any:
    """``obj`` with numpy scalars/arrays turned into Python values and non-finite floats into None.

    JSON has no NaN or Infinity; ``json.dumps(..., allow_nan=False)`` then succeeds.
    """
    if isinstance(obj, Mapping):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def composition(t_s: np.ndarray, conv: np.ndarray, fields: Sequence[str]) -> dict[str, Any]:
    """The acquire-then-track figures of a run from the ``mode`` column of its
    ``convergence`` rows (0 acquiring, 1 tracking, 2 re-acquiring) at times ``t_s`` (s since
    the observer's first sample): the acquisition time (the first row tracking), and the
    hand-overs (rows entering mode 1) and re-acquisitions (rows entering mode 2), counted
    and timed (the first 20 of each) over the whole run, across restarts."""
    mode = conv[:, list(fields).index("mode")] if conv.size else np.zeros(0)
    prev = np.concatenate(([0.0], mode[:-1]))
    hand = np.flatnonzero((mode == 1.0) & (prev != 1.0))
    re = np.flatnonzero((mode == 2.0) & (prev != 2.0))
    return {
        "acquisition_time_s": float(t_s[hand[0]]) if hand.size else None,
        "handovers": int(hand.size),
        "reacquisitions": int(re.size),
        "handover_times_s": [float(t_s[i]) for i in hand[:20]],
        "reacquisition_times_s": [float(t_s[i]) for i in re[:20]],
        "definition": "times in s since the observer's first accepted sample; acquisition "
                      "time = the first sample published from the tracker; counted from "
                      "the published mode over the whole run (restarts included)",
    }
