"""``fto-design PARAMS --suggest-from BAG``: hosm's M measured on a recording.

M[i] bounds the N_i-th time derivative of the output error e_i = y_i - c_i z that
differentiator i differentiates (N_i = r_i, or r_i + k + 1 when identifying: rad/s^3 for a
joint angle with k = 0).  The recording shows how large that derivative gets: the tuning
file's hosm runs on the bag (its Luenberger part z does not depend on M), e_i is recorded
at every accepted sample from ten time constants of the slowest Luenberger pole after each
(re)start on, and core/derivative_bound.py estimates max |e_i^(N_i)| (local polynomial fits
on the shortest window at which the noise is below a tenth of the estimate).  The
suggestion is SAFETY times that: the bound must hold on data the recording did not see.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..bag import BagReader
from ..core.derivative_bound import derivative_bound
from ..plant.block import units_of
from ..replay.topics import node_fqn, resolve_topic
from ..runner import Output, Runner
from ..runner.messages import joint_state_sample

#: suggested M = SAFETY x the largest derivative seen
SAFETY = 3.0
#: e is recorded from this many time constants of the slowest Luenberger pole on
SETTLE_TIME_CONSTANTS = 10.0


def _events(bag: Path, runner: Runner, fqn: str):
    """(t, 'u' | 'y', values) of the bag as the runner reads it, inputs first at equal times."""
    s = runner.settings
    out = []
    with BagReader(bag) as reader:
        if s["source"] == "joint_states":
            for _, _, msg in reader.messages([resolve_topic(s["topics.joint_states"], fqn)]):
                sample = joint_state_sample(msg, s)
                if not isinstance(sample, str):
                    t, y, u = sample
                    if u is not None:
                        out.append((t, "u", u))
                    out.append((t, "y", y))
        else:
            meas = resolve_topic(s["topics.measured_output"], fqn)
            inp = resolve_topic(s["topics.input"], fqn) if runner.observer.n_inputs else None
            for topic, t_ns, msg in reader.messages([meas] + ([inp] if inp else [])):
                out.append((t_ns / 1e9, "u" if topic == inp else "y", list(msg.data)))
    out.sort(key=lambda e: (e[0], e[1] != "u"))
    return out


def suggest_m(flat: dict, bag: Path, node_name: str | None = None) -> list[str]:
    """The lines fto-design prints for the hosm configuration ``flat`` on ``bag``."""
    runner = Runner(flat)
    obs = runner.observer
    slowest = float(np.min(np.abs(np.real(obs.closed_loop_poles))))
    settle = SETTLE_TIME_CONSTANTS / slowest
    times, errors = [], []
    for t, kind, v in _events(Path(bag), runner, node_fqn(node_name)):
        if kind == "u":
            runner.set_input(t, v)
            continue
        out = runner.process(t, v)
        if isinstance(out, Output) and out.convergence[0] >= settle:
            times.append(t)
            errors.append(obs.differentiated_signal)
    _, _, out_units = units_of(flat)
    lines = [f"  M suggested from {bag} ({len(times)} samples from {settle:.3g} s after each "
             f"start: {SETTLE_TIME_CONSTANTS:g} time constants of the slowest Luenberger pole):"]
    if len(times) < 20:
        return lines + ["    too few samples to measure a derivative"]
    t = np.array(times)
    # a restart leaves a gap in t: each run's samples are fitted on their own
    runs = np.split(np.arange(len(t)), np.flatnonzero(np.diff(t) > 10 * np.median(np.diff(t))) + 1)
    suggested = []
    for i, N in enumerate(obs.bounded_orders):
        e = np.array([row[i] for row in errors])
        found = [derivative_bound(t[r], e[r], N) for r in runs if len(r) >= 4 * (N + 5)]
        if not found:
            return lines + ["    too few samples in one run to measure a derivative"]
        b = max(found, key=lambda f: f.bound)
        unit = f"{out_units[i]}/s^{N}" if i < len(out_units) and out_units[i] else \
            f"(units of y{i})/s^{N}"
        m = float(f"{SAFETY * b.bound:.2g}")
        suggested.append(m)
        how = (f"below the noise at every window: at most {b.bound:.3g} at {b.window_s:.3g} s"
               if b.noise_limited else f"window {b.window_s * 1e3:.3g} ms, noise {b.noise:.2g}")
        lines.append(f"    output {i}: max |d^{N}/dt^{N} (y{i} - c{i} z)| = {b.bound:.3g} {unit} "
                     f"({how}); M[{i}] = {m:g} {unit} ({SAFETY:g} x); configured "
                     f"{obs.M[i]:g}")
    lines.append(f"    hosm.M: [{', '.join(f'{m:g}' for m in suggested)}]")
    return lines
