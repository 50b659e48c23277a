"""Which publisher owns a data topic (its samples are taken from it), and how many of its
messages never reached the observer.

rclpy 7.1.6 does not pass the publisher's GID with a message (its message info holds the
source and receipt timestamps and the publication sequence number only), so a publisher
is told from another by what it sends: a DDS writer numbers its messages 1, 2, 3, ... and
its clock goes on.  A message *continues* the topic's owner when its sequence number is
above the owner's last one and its time (the header stamp of a JointState; the writer's
source timestamp of a Float64MultiArray) lies within [last - time.jump_threshold,
last + time.max_gap].  What does not continue it is

- with one publisher on the topic (the graph says so): still the owner's (a time jump, a
  restarted driver): taken, and the runner judges its stamp as the replay does;
- with two or more: another source, rejected as ``second_source`` (``input_second_source``
  on the input topic) and never given to the observer.  The owner (the first publisher
  seen) keeps the topic until it has been silent, nothing continuing it, for
  ``time.max_gap`` of wall time; then the next message's publisher owns it and the
  observer restarts (``restarts: source_change``).

Two writers whose sequence numbers and clocks run together (two drivers started at once on
one machine) cannot be told apart this way; two robots with their own clocks can.

Loss: the owner's sequence numbers skipped are messages it sent that the node never
processed (dropped by the middleware, in transport or overwritten in the subscription's
queue): ``lost``.  The middleware's own message-lost event counts only the transport
losses (it stays 0 for a small-message stream that overflows the queue), see observer_core.
"""
from __future__ import annotations

import time
from typing import Callable

#: publication sequence numbers outside (0, 2^63) mean "not supported by this rmw"
_SEQ_MAX = 2 ** 63
#: how long a publisher count from the graph is reused (s)
COUNT_TTL_S = 0.1

SECOND_SOURCE = "second_source"
SOURCE_CHANGE = "source_change"


class TopicOwner:
    """One data topic's owner and its losses (see the module docstring)."""

    def __init__(self, count_publishers: Callable[[], int], max_gap: float, jump_threshold: float):
        self._count_publishers = count_publishers
        self.set_limits(max_gap, jump_threshold)
        self.lost = 0               # sequence numbers of the owner never seen
        self._seq = 0               # the owner's last sequence number (0: no owner yet)
        self._t = 0                 # ... its time (ns)
        self._steady = 0.0          # ... when it was last taken (monotonic s)
        self._count = 1
        self._count_at = -1.0

    def set_limits(self, max_gap: float, jump_threshold: float) -> None:
        self._after_ns = int(max_gap * 1e9)
        self._before_ns = int(jump_threshold * 1e9)
        self._silence = max_gap

    def publishers(self) -> int:
        """Publishers on the topic (from the graph, cached for COUNT_TTL_S)."""
        now = time.monotonic()
        if now - self._count_at > COUNT_TTL_S:
            self._count = self._count_publishers()
            self._count_at = now
        return self._count

    def check(self, info, t_ns: int) -> str | None:
        """None: the message is the owner's, take it; SECOND_SOURCE: reject it;
        SOURCE_CHANGE: a new owner, restart the observer and take it."""
        seq = info.get("publication_sequence_number", 0) if info else 0
        if not 0 < seq < _SEQ_MAX:
            return None                       # no sequence numbers: one source assumed
        last = self._seq
        if last and seq > last and self._t - self._before_ns <= t_ns <= self._t + self._after_ns:
            self.lost += seq - last - 1
            self._take(seq, t_ns)
            return None
        if not last or self.publishers() <= 1:
            if last and seq > last:
                self.lost += seq - last - 1    # (a lower one: a restarted writer)
            self._take(seq, t_ns)
            return None
        if time.monotonic() - self._steady > self._silence:
            self._take(seq, t_ns)
            return SOURCE_CHANGE
        return SECOND_SOURCE

    def _take(self, seq: int, t_ns: int) -> None:
        self._seq, self._t, self._steady = seq, t_ns, time.monotonic()
