"""The bag's messages as one time-ordered sequence of events, as the node would receive
them, and the windows the replay processes them in.

At equal log times the clock and the inputs come first (an input stamped t applies from
t on), then the samples, then the ground truth; otherwise in each topic's order.  A
window ends at a diagnostics boundary (one status per period of bag time, emitted before
the first event at or after it) or after ``max_events``: what the runner is handed as one
block.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: event kinds (the stream each event comes from)
INPUT, MEAS, JOINT, TRUTH, CLOCK, TRUTH_UI, TRUTH_JOINTS = 0, 1, 2, 3, 4, 5, 6
#: the stream role of each kind
ROLE = {INPUT: "inputs", MEAS: "meas", JOINT: "joints", TRUTH: "truth", CLOCK: "clock",
        TRUTH_UI: "truth_ui", TRUTH_JOINTS: "truth_joints"}
#: the rank of each kind at equal log times
_RANK = {CLOCK: 0, INPUT: 0, MEAS: 1, JOINT: 1, TRUTH: 2, TRUTH_UI: 2, TRUTH_JOINTS: 2}
#: the order the streams are merged in (stable at equal time and rank)
_ORDER = (CLOCK, INPUT, MEAS, JOINT, TRUTH, TRUTH_UI, TRUTH_JOINTS)


@dataclass
class Events:
    """Events in processing order: log time (ns), kind, index in the kind's stream."""

    t: np.ndarray
    kind: np.ndarray
    idx: np.ndarray


def order_events(streams) -> Events:
    """The events of every stream of ``streams`` (replay/streams.py) in processing order."""
    times = [getattr(streams, ROLE[k])[0] for k in _ORDER]
    t_all = np.concatenate(times)
    rank = np.concatenate([np.full(t.size, _RANK[k], np.int8) for t, k in zip(times, _ORDER)])
    order = np.lexsort((rank, t_all))
    kind = np.concatenate([np.full(t.size, k, np.int8) for t, k in zip(times, _ORDER)])
    idx = np.concatenate([np.arange(t.size) for t in times])
    return Events(t_all[order], kind[order], idx[order])


def windows(ev: Events, t_first: int, period_ns: int, max_events: int):
    """Yield ``(start, stop, boundary)``: the events ``[start, stop)`` form one window;
    ``boundary`` is the diagnostics time due after it (None: none is, the window was cut
    at ``max_events`` or the events ended before the boundary)."""
    n = ev.t.size
    next_diag = t_first + period_ns
    start = 0
    while start < n:
        stop = min(int(np.searchsorted(ev.t, next_diag, "left")), start + max_events)
        due = next_diag if stop < n and ev.t[stop] >= next_diag else None
        yield start, stop, due
        if due is not None:
            # one status per period; across a forward jump of the log time one at the first
            # boundary, then the next boundary after the jump: O(1)
            next_diag += period_ns
            if ev.t[stop] >= next_diag:
                next_diag += (int(ev.t[stop]) - next_diag) // period_ns * period_ns + period_ns
        start = stop
