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

#: the roles in merge order (stable at equal time and rank): the clock, the source's topics
#: (by their keys), the ground truth
ROLES = ("clock", "input", "measured_output", "joint_states", "truth", "truth_ui",
         "truth_joints")
#: the rank at equal log times of the roles that are not a source's (which ranks its own)
RANK = {"clock": 0, "truth": 2, "truth_ui": 2, "truth_joints": 2}


@dataclass
class Events:
    """Events in processing order: log time (ns), kind (an index into ``roles``), index in
    the kind's stream."""

    t: np.ndarray
    kind: np.ndarray
    idx: np.ndarray
    roles: tuple = ROLES


def order_events(streams, ranks: dict) -> Events:
    """The events of every stream of ``streams`` (replay/streams.py) in processing order;
    ``ranks``: the source's topics' ranks (TopicIn.rank) by key."""
    rank_of = {**RANK, **ranks}
    times = [streams.times(role) for role in ROLES]
    t_all = np.concatenate(times)
    rank = np.concatenate([np.full(t.size, rank_of.get(role, 1), np.int8)
                           for t, role in zip(times, ROLES)])
    order = np.lexsort((rank, t_all))
    kind = np.concatenate([np.full(t.size, k, np.int8) for k, t in enumerate(times)])
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
