"""Offline replay: run a recorded bag through the runner, exactly as the live node would.

``replay(bag, params, out)`` reads the bag, feeds the messages in log-time
order to :class:`~fto_ros.runner.runner.Runner` (the very adapter the live node
uses), writes the node's outputs to ``out`` as a rosbag2 MCAP bag, and
compares the estimate with the bag's ground truth: ``out/metrics.json`` and
``out/replay.png``.  No rclpy, no DDS; deterministic.

How the messages drive the runner (what the node does on live topics):

- ``source: topics``: a message on ``topics.input`` calls
  ``runner.set_input(t, msg.data)``, one on ``topics.measured_output`` calls
  ``runner.process(t, msg.data)``; ``t`` is the message's log time in seconds
  (the node stamps Float64MultiArray on receipt; a bag's log time is the
  receipt time).  At equal log times inputs go first: an input stamped t
  applies from t on.
- ``source: joint_states``: each JointState is turned into ``(t, y, u)`` by
  :func:`~fto_ros.runner.messages.joint_state_sample` (``t`` = header stamp);
  a stamp more than ``time.future_tolerance`` ahead of the log time (the sim
  clock) is rejected as ``future_stamp``; ``u`` (when input joints are
  configured) is set before ``y`` is processed, and a rejected ``u`` drops the
  sample.
- Every accepted sample publishes ``state_estimate`` and ``convergence``
  (Float64MultiArray with one labelled layout dimension, like the node; a
  non-finite value, i.e. guaranteed_time = inf, is published as -1),
  ``unknown_input_estimate`` (observers that have one) and
  ``estimated_joint_states`` (when configured) under ``/<node name>/``, with
  log time = sample time.  ``/diagnostics`` gets ``runner.status(t)`` every
  ``diagnostics.period`` seconds of bag time (1 s by default), plus a final one.

Speed: the bag is read through its MCAP indexes, each topic cut out and decoded at once
with numpy (anything unusual falls back to :class:`~fto_ros.bag.BagReader`); the outputs
of each window of samples are encoded as byte blocks, checked once against the rosbags
serialiser, and written a topic's block at a time (replay/outputs.py, bag/mcap_write.py).
``metrics.json`` reports the measured speed and where the time went.
"""
from __future__ import annotations

import gc
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..bag.writer import warm_up
from ..core.command_line import one_line
from ..core.output_dir import OutputIncomplete, abandon, check_output
from ..plant.block import units_of
from ..runner.params_file import load_params_files
from ..runner.runner import Runner
from ..runner.status import LEVEL_NAMES
from . import arm_metrics as AM
from . import joint_metrics as JM
from . import metrics as M
from .run import _Run, _run
from .topics import DEFAULT_NODE_NAME, ReplayError, node_fqn  # noqa: F401 (public names)

DEFAULT_TOLERANCE = 1e-2
METRICS_SCHEMA = "fto_ros/replay-metrics/1"
#: a replay that accepts fewer than this fraction of its measurement samples fails (exit 1)
DEFAULT_MIN_ACCEPTED = 0.5

_ROLE_NAMES = {"measured_output": "measured_output", "input": "input",
               "joint_states": "joint_states", "truth": "true_state",
               "truth_ui": "true_unknown_input", "clock": "clock", "truth_joints": "true_state"}


# --------------------------------------------------------------------------------------
def replay(bag_path, params_path, out_dir, *, node_name: str | None = None,
           overwrite: bool = False, progress: bool = True, after: float | None = None,
           tolerance: float = DEFAULT_TOLERANCE, plot: bool = True,
           overrides: dict[str, Any] | None = None,
           min_accepted: float = DEFAULT_MIN_ACCEPTED) -> dict[str, Any]:
    """Replay ``bag_path`` through the observer of ``params_path``; write ``out_dir``.

    Args:
        bag_path: rosbag2 bag (directory or .mcap file).
        params_path: ROS 2 params file, or a list of them merged in order (later
            files override earlier ones, as several ``--params-file`` do); the
            blocks for ``node_name`` (and ``/**``) are used.
        out_dir: output bag directory; also receives ``metrics.json`` and
            ``replay.png``.  Must not exist unless ``overwrite``, and then it must be
            an output fto_ros wrote (:mod:`fto_ros.core.output_dir`); never the input
            bag, inside it or a folder holding it.
        node_name: node name for the params block and the output topic
            namespace (default ``observer_node``).
        progress: draw a progress bar on stderr (only on a terminal, and only
            once the replay has taken half a second).
        after: settle time (s after the observer's (re)start) for the
            "after settling" errors; default guaranteed_time + 0.01 s, or
            0.11 s for observers without a guarantee.
        tolerance: error bound (state units) for the measured convergence time.
        plot: write ``replay.png``.
        overrides: ``{full parameter name: value}`` applied after the files
            (``-p NAME:=VALUE``; ``fto-sweep --set``).
        min_accepted: the replay fails (ReplayError, after writing its outputs
            and metrics) when it accepts fewer than this fraction of the bag's
            measurement samples, or none at all: a bag of junk is not a result.

    Returns the metrics (also written to ``metrics.json``).
    Raises ConfigError (params), OutputError (an output path that is refused),
    OutputExists (an existing output without ``overwrite``), BagError (bags),
    ReplayError (anything else that stops the replay), each with a one-line message.
    """
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) \
            or not (math.isfinite(tolerance) and tolerance > 0):
        raise ReplayError(f"tolerance must be a positive number, got {tolerance!r}")
    if after is not None and not (isinstance(after, (int, float)) and math.isfinite(after)
                                  and after >= 0):
        raise ReplayError(f"after must be a finite number >= 0, got {after!r}")
    if not (isinstance(min_accepted, (int, float)) and 0.0 <= min_accepted <= 1.0):
        raise ReplayError(f"min_accepted must be a fraction in [0, 1], got {min_accepted!r}")
    params_paths = ([Path(p) for p in params_path] if isinstance(params_path, (list, tuple))
                    else [Path(params_path)])
    inputs = (bag_path, *params_paths)
    bag_path = Path(bag_path)
    params_path = params_paths[-1]          # the tuning file, in titles and names
    fqn = node_fqn(node_name)
    flat = load_params_files(params_paths, node_name, overrides)
    runner = Runner(flat)
    warm_up()  # one-time library set-up (rosbags' serialisers, ~0.1 s), not part of the replay
    obs = runner.observer
    out_dir = check_output(out_dir, "bag", overwrite=overwrite, inputs=inputs)
    custom = {"fto_ros.replay.bag": str(bag_path),
              "fto_ros.replay.params": ", ".join(str(p) for p in params_paths),
              "fto_ros.replay.observer": obs.TYPE}
    # the replay allocates many small objects and frees none: the cyclic GC would only
    # rescan them again and again (it cost up to 2x in the read phase)
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        run = _run(runner, bag_path, out_dir, fqn, overwrite, progress, custom, inputs)
    finally:
        if gc_was_enabled:
            gc.enable()
    try:                   # the bag is written; an output without its metrics is none
        m0 = time.perf_counter()
        metrics, plot_data = _metrics(runner, run, bag_path, params_path, out_dir, fqn, after,
                                      tolerance, units_of(flat))
        metrics["params_files"] = [str(p) for p in params_paths]
        metrics["overrides"] = dict(overrides or {})
        metrics["timing_s"]["metrics"] = time.perf_counter() - m0
        if plot:
            p0 = time.perf_counter()
            from .plot import plot_replay
            units, ui_units, _ = units_of(flat)
            plot_replay(out_dir / "replay.png", **plot_data, units=units, ui_units=ui_units,
                        title=f"{obs.TYPE}: {params_path.name} on {bag_path.name}")
            metrics["plot"] = "replay.png"
            metrics["timing_s"]["plot"] = time.perf_counter() - p0
        (out_dir / "metrics.json").write_text(
            json.dumps(M.json_safe(metrics), indent=2, allow_nan=False) + "\n")
    except OSError as err:
        what = abandon(out_dir, "bag", f"{err.strerror or err}")
        raise OutputIncomplete(f"cannot complete the output {out_dir}: "
                               f"{err.strerror or one_line(err)}; {what}") from None
    _check_accepted(metrics, min_accepted)
    return metrics


def _check_accepted(m: dict, min_accepted: float) -> None:
    """ReplayError when the replay accepted no sample, or fewer than ``min_accepted`` of them."""
    total, accepted = m["sample_count"], m["samples_accepted"]
    reasons = ", ".join(f"{k}: {v}" for k, v in sorted(m["rejected_by_reason"].items(),
                                                       key=lambda kv: -kv[1])[:4])
    why = f" (rejected: {reasons})" if reasons else ""
    if accepted == 0:
        raise ReplayError(f"{m['bag']}: no sample accepted of {total}{why}; outputs in "
                          f"{m['output_bag']}")
    if accepted < min_accepted * total:
        raise ReplayError(f"{m['bag']}: only {accepted} of {total} samples accepted "
                          f"({accepted / total:.1%} < {min_accepted:.0%}){why}; outputs in "
                          f"{m['output_bag']}")


def _metrics(runner: Runner, run: _Run, bag_path: Path, params_path: Path, out_dir: Path,
             fqn: str, after: float | None, tolerance: float,
             units: tuple = ([], [], [])) -> tuple[dict, dict]:
    """(metrics dict, plot arguments) of a finished run; ``units``: plant.block.units_of."""
    obs, settings, inp = runner.observer, runner.settings, run.inputs
    info, streams = inp.info, inp.streams
    names = list(obs.state_names)
    n = obs.n_states
    t_est_ns, x_est, conv = run.est_t, run.est_x, run.est_conv
    gt = float(obs.guaranteed_time)
    if after is not None:
        settle, settle_rule = float(after), "given (after= / --after)"
    elif settings["metrics.settle_time"] > 0.0:
        settle, settle_rule = settings["metrics.settle_time"], "params file (metrics.settle_time)"
    else:
        settle, settle_rule = M.default_settle_time(gt)
    t_start_ns = int(t_est_ns[0]) if t_est_ns.size else None

    truth_note = inp.truth_note
    truth_t = truth_x = None
    joint_errors = None
    if runner.joints and "truth_joints" in inp.roles:   # per joint: by joint name
        joint_errors, truth_note = JM.joint_errors(run.source.plan, run, streams.truth_joints,
                                                   settle, units[0], units[1])
    if "truth" in inp.roles:
        truth_t, truth_x, why = _truth_rows(streams.truth, inp.truth_topic, n, "",
                                            f"the observer has {n} states")
        truth_note = why or truth_note
    arm_ui = None
    if runner.intake is not None and "truth_joints" in inp.roles:     # an arm's, by name
        truth_t, truth_x, arm_w, why = AM.truth(streams.truth_joints, obs)
        truth_note = why or truth_note
        arm_ui = None if truth_t is None else (truth_t, arm_w)
    errors = conv_time = err_t = err_norm = None
    if truth_x is not None and not t_est_ns.size:
        truth_note = "no accepted samples: nothing to compare with the ground truth"
    elif truth_x is not None:
        mask, x_at = M.match_truth(t_est_ns, truth_t, truth_x)
        err = x_at[mask] - x_est[mask]
        settled = conv[mask, 0] >= settle - 1e-9  # time since (re)start, float round-off
        state_units = units[0] if len(units[0]) == n else None
        errors = M.error_stats(err, names, settled, state_units)
        errors.update(
            matched_samples=int(mask.sum()), settled_samples=int(settled.sum()),
            unmatched_samples=int((~mask).sum()),
            definition="error = truth - estimate, the truth taken at each estimate's log time "
                       "(exact ns match, else linear interpolation; estimates outside the "
                       "truth's time range are left out); 'after_settle' = samples whose time "
                       "since the observer's (re)start is >= settle_time_s")
        if mask.any():
            t_rel = (t_est_ns[mask] - t_start_ns) / 1e9
            conv_time = M.convergence_time(t_rel, np.max(np.abs(err), axis=1), tolerance)
            err_t = (t_est_ns[mask] - info.start_ns) / 1e9
            err_norm = np.sqrt(np.sum(err * err, axis=1))
        elif truth_note is None:
            truth_note = "no estimate lies within the ground truth's time range"
    ui_errors, ui_note, ui_plot = _unknown_input_errors(obs, run, t_est_ns, conv, settle, arm_ui)
    p50_obs, p99_obs = runner.update_time_us()
    duration_s = info.duration_ns / 1e9
    wall = run.timing["replay_total"]
    source = run.source
    metrics: dict[str, Any] = {
        "schema": METRICS_SCHEMA,
        "bag": str(bag_path),
        "params_file": str(params_path),
        "node_name": fqn,
        "observer_type": obs.TYPE,
        "state_names": names,
        "source": settings["source"],
        "input_topics": {_ROLE_NAMES[k]: v for k, v in inp.roles.items()},
        "output_bag": str(out_dir),
        "output_topics": dict(sorted(run.counts.items())),
        "plot": None,
        "bag_start_s": info.start_ns / 1e9,
        "bag_duration_s": duration_s,
        # with joints, a sample is one joint's entry of a message
        "sample_count": runner.n_joints * sum(streams.times(t.key).size
                                              for t in source.topics if t.samples),
        "input_count": streams.times("input").size,
        "samples_accepted": runner.accepted,
        "samples_rejected": sum(runner.rejected.values()),
        "rejected_by_reason": dict(sorted(runner.rejected.items())),
        "restarts": sum(runner.resets.values()),
        "restarts_by_reason": dict(sorted(runner.resets.items())),
        "guaranteed_time_s": gt if math.isfinite(gt) else None,
        "guarantee": f"exact {gt:g} s after each (re)start" if math.isfinite(gt)
        else "none",
        "settle_time_s": settle,
        "settle_time_rule": settle_rule,
        "tolerance": float(tolerance),
        "convergence_time_s": conv_time,
        "convergence_time_definition": (
            "first time (s after the observer's first accepted sample) from which the largest "
            "absolute error over all states stays below 'tolerance' to the end of the bag; "
            "null if it never does or there is no ground truth"),
        "observer_start_s": None if t_start_ns is None else t_start_ns / 1e9,
        "truth_topic": inp.truth_topic if "truth" in inp.roles else None,
        "errors": errors,
        "errors_note": truth_note,
        "update_time_us": {
            **M.percentiles_us(run.proc_s * 1e6),
            "definition": "wall time of each Runner.process call that produced an output "
                          "(validation + observer update + output building), over every "
                          "accepted sample of the run"},
        "observer_update_time_us": {
            "p50": p50_obs, "p99": p99_obs,
            "definition": "Runner.update_time_us(): the observer's update() alone, over the "
                          "last 2000 updates (what /diagnostics shows)"},
        "replay_speed_x_realtime": duration_s / wall if wall > 0 else None,
        "replay_speed_definition": (
            "bag duration / wall time of the whole replay: opening, reading and decoding the "
            "bag, the runner, serialising and writing the output bag and closing it "
            "(excluded: params loading, one-time library set-up such as imports and the rosbags "
            "type store, the metrics and the plot; timing_s has the parts)"),
        "timing_s": dict(run.timing),
        "reader": streams.reader,
        "decoded_by_rosbags": source.by_fallback,
        "diagnostics_levels": dict(run.status_levels),
        "final_status": {"level": LEVEL_NAMES.get(run.final_status.level,
                                                  str(run.final_status.level)),
                         "message": run.final_status.message},
        "observer_diagnostics": {
            str(k): (v if isinstance(v, (int, float, str, bool)) or v is None else str(v))
            for k, v in obs.diagnostics().items()},
    }
    if runner.joints:                           # the per-joint source's figures
        metrics.update(joints=list(runner.joints), joint_errors=joint_errors,
                       truth_topic=inp.truth_topic if "truth_joints" in inp.roles else None)
    if runner.intake is not None:                      # an arm's external torques
        metrics["arm"] = AM.metrics(runner, run, *(arm_ui or (None, None)),
                                    streams.times("joint_states").size)
    if "mode" in runner.convergence_fields:            # a composition (track)
        t_rel = (t_est_ns - t_start_ns) / 1e9 if t_start_ns is not None else np.zeros(0)
        metrics["composition"] = M.composition(t_rel, conv, runner.convergence_fields)
    if ui_plot is not None or "truth_ui" in inp.roles:
        # only for observers that identify an unknown input, or bags that carry its truth
        metrics.update(
            unknown_input_topic=inp.truth_ui_topic if "truth_ui" in inp.roles else None,
            unknown_input_errors=ui_errors, unknown_input_errors_note=ui_note)
    t0 = info.start_ns
    plot_data = dict(
        t=(t_est_ns - t0) / 1e9, estimate=x_est, state_names=names,
        truth_t=None if truth_x is None else (truth_t - t0) / 1e9, truth=truth_x,
        err_t=err_t, err_norm=err_norm, guaranteed_time=gt, settle_time=settle,
        tolerance=tolerance if truth_x is not None else None,
        t_start=0.0 if t_start_ns is None else (t_start_ns - t0) / 1e9)
    if ui_plot is not None:
        ui_t, ui_est, ui_truth_t, ui_truth, ui_names = ui_plot
        plot_data.update(ui_t=(ui_t - t0) / 1e9, ui_estimate=ui_est,
                         ui_truth_t=None if ui_truth_t is None else (ui_truth_t - t0) / 1e9,
                         ui_truth=ui_truth, ui_names=ui_names)
    return metrics, plot_data


def _truth_rows(stream, topic: str, width: int, kind: str, has: str):
    """(stamps, rows, None) of a ground-truth stream whose messages all carry ``width``
    values, or (None, None, why there are no error metrics)."""
    t, rows = stream
    lengths = {rows.shape[1]} if isinstance(rows, np.ndarray) else {len(v) for v in rows}
    if not t.size:
        return None, None, f"no {kind}ground truth: topic {topic} has no messages"
    if lengths != {width}:
        return None, None, (f"no {kind}error metrics: {topic} carries {sorted(lengths)} value(s) "
                            f"per message, {has}")
    return t, np.asarray(rows, dtype=float), None


def _unknown_input_errors(obs, run: _Run, t_est_ns: np.ndarray, conv: np.ndarray,
                          settle: float, given=None) -> tuple[dict | None, str | None, tuple | None]:
    """(errors like 'errors' but for the unknown input, a note, plot data) of a finished run;
    ``given``: its truth (stamps, rows) when not a topic of its own (an arm's)."""
    if not run.est_ui.size:
        note = None if not obs.has_unknown_input else \
            "the observer published no unknown-input estimate"
        return None, note, None
    idx, ui = run.est_ui_idx, run.est_ui
    t_ui = t_est_ns[idx]
    q = ui.shape[1]
    names = list(getattr(obs, "unknown_input_names", None) or [f"zeta{j}" for j in range(q)])
    truth_t = truth_x = None
    note = run.inputs.truth_ui_note
    if given is not None:
        (truth_t, truth_x), note = given, None
    elif "truth_ui" in run.inputs.roles:
        truth_t, truth_x, why = _truth_rows(run.inputs.streams.truth_ui,
                                            run.inputs.truth_ui_topic, q,
                                            "unknown-input ", f"the estimate has {q}")
        note = why or note
    errors = None
    if truth_x is not None:
        mask, x_at = M.match_truth(t_ui, truth_t, truth_x)
        if mask.any():
            err = x_at[mask] - ui[mask]
            settled = conv[idx[mask], 0] >= settle - 1e-9
            errors = M.error_stats(err, names, settled)
            errors.update(
                matched_samples=int(mask.sum()), settled_samples=int(settled.sum()),
                definition="error = true unknown input - unknown_input_estimate, matched and "
                           "settled as 'errors'")
        else:
            note = "no unknown-input estimate lies within its ground truth's time range"
    return errors, note, (t_ui, ui, truth_t, truth_x, names)
