"""The interface between the replay and the runner: blocks of samples in, blocks of
outputs out.

The replay hands the runner one window of events at a time (replay/events.py: inputs and
samples in processing order, up to a diagnostics boundary) and gets back an
:class:`OutputBlock`: one row per accepted sample (its time, estimate, unknown-input
estimate, convergence values) and a status per sample.  Today :func:`run_window` makes
the runner's per-sample calls (``set_input``, ``process``), exactly as the live node
does; a block runner replaces that one function, and the writer side (replay/outputs.py)
already takes the arrays.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..runner.messages import joint_state_sample
from ..runner.runner import HELD
from . import events as E

#: per-sample status codes
ACCEPTED, IS_HELD, REJECTED = 0, 1, 2


@dataclass
class OutputBlock:
    """What the runner produced for one window: k accepted samples, e samples in all."""

    t_ns: np.ndarray          # (k,) int64: sample times (log time, or a JointState's stamp)
    x: np.ndarray             # (k, n): estimates
    w: np.ndarray             # (k, r): unknown-input estimates (NaN where a sample has none)
    has_w: np.ndarray         # (k,) bool: the sample has an unknown-input estimate
    c: np.ndarray             # (k, ncf): convergence values (guaranteed_time inf: none)
    js: tuple | None          # (position (j, a), velocity (j, b), effort (j, c)), or None
    js_rows: np.ndarray       # (j,): the rows that have estimated joint states
    js_names: list | None     # the estimated joint states' names
    status: np.ndarray        # (e,) int8: ACCEPTED, IS_HELD or REJECTED, per sample event
    reasons: list             # the rejection reason of each REJECTED sample, in order
    proc_s: np.ndarray        # (k,) s: wall time of each Runner.process call with an output


class SampleLists:
    """A replay's sample streams as the per-sample calls take them (lists of floats)."""

    def __init__(self, streams):
        self.inputs = _rows(streams.inputs[1])
        self.meas = _rows(streams.meas[1])
        self.joints = streams.joints[1]


def _rows(values) -> list:
    return values.tolist() if isinstance(values, np.ndarray) else values


def _no_output(why: str, status: list, reasons: list) -> None:
    """Record a sample without an output: held at a time jump, or rejected for ``why``."""
    status.append(IS_HELD if why == HELD else REJECTED)
    if why != HELD:
        reasons.append(why)


def run_window(runner, ev: E.Events, start: int, stop: int, samples: SampleLists,
               n: int, r: int, ncf: int) -> tuple[OutputBlock, float]:
    """(the OutputBlock of the events ``[start, stop)``, seconds spent in the runner)."""
    settings = runner.settings
    set_input, process, reject = runner.set_input, runner.process, runner.reject
    inputs, meas, joints = samples.inputs, samples.meas, samples.joints
    perf = time.perf_counter
    t_out, x, w, has_w, c, status, reasons, proc_s = [], [], [], [], [], [], [], []
    js, js_rows = [], []
    no_w = [float("nan")] * r
    runner_s = 0.0
    for t_ns, kind, i in zip(ev.t[start:stop].tolist(), ev.kind[start:stop].tolist(),
                             ev.idx[start:stop].tolist()):
        if kind == E.MEAS:
            c0 = perf()
            out = process(t_ns / 1e9, meas[i])
            c1 = perf()
            runner_s += c1 - c0
            if out.__class__ is str:
                _no_output(out, status, reasons)
                continue
            s_ns, dt = t_ns, c1 - c0
        elif kind == E.INPUT:
            c0 = perf()
            set_input(t_ns / 1e9, inputs[i])
            runner_s += perf() - c0
            continue
        elif kind != E.JOINT:       # the clock, the ground truth: copied only
            continue
        else:  # a JointState (source: joint_states); its sample time is the header stamp
            msg = joints[i]
            c0 = perf()
            # the node's intake; the stamp is checked against the log time (receipt time)
            sample = joint_state_sample(msg, settings, t_ns * 1e-9)
            s_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if sample.__class__ is str:
                why = sample
                reject(why)
                runner_s += perf() - c0
                _no_output(why, status, reasons)
                continue
            t, y, u = sample
            if u is not None:
                why = set_input(t, u)
                if why is not None:          # counted by the runner; never pair y with a bad u
                    runner_s += perf() - c0
                    _no_output(why, status, reasons)
                    continue
            c1 = perf()
            out = process(t, y)
            c2 = perf()
            runner_s += c2 - c0
            if out.__class__ is str:
                _no_output(out, status, reasons)
                continue
            dt = c2 - c1                     # process alone, as for a measurement
        status.append(ACCEPTED)
        proc_s.append(dt)
        t_out.append(s_ns)
        x.append(out.estimate)
        c.append(out.convergence)
        ui = out.unknown_input
        has_w.append(ui is not None)
        w.append(no_w if ui is None else ui)
        if out.joint_state is not None:
            js.append(out.joint_state)
            js_rows.append(len(t_out) - 1)
    k = len(t_out)
    block = OutputBlock(
        t_ns=np.asarray(t_out, dtype=np.int64),
        x=np.array(x, dtype=float).reshape(k, n), w=np.array(w, dtype=float).reshape(k, r),
        has_w=np.asarray(has_w, dtype=bool), c=np.array(c, dtype=float).reshape(k, ncf),
        js=None, js_rows=np.asarray(js_rows, dtype=np.int64), js_names=None,
        status=np.asarray(status, dtype=np.int8), reasons=reasons,
        proc_s=np.asarray(proc_s, dtype=float))
    if js:
        block.js_names = list(js[0][0])
        block.js = tuple(np.array([j[f] for j in js], dtype=float).reshape(len(js), len(js[0][f]))
                         for f in (1, 2, 3))
    return block, runner_s
