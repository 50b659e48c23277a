"""Health that describes the present: the /diagnostics level from a recent window.

Counters in the runner are cumulative (they stay as key-values); the level comes from
what happened in the last ``diagnostics.window`` seconds of the caller's clock (the
node's ROS clock, the replay's bag time): the clock of ``status(now)`` calls, never a
sample's stamp, so junk stamps cannot age events.  Events between two status calls
land in one bucket stamped with the later call's time; buckets older than the window
are dropped.  ``clear()`` (``~/reset``) forgets them all.

Level rules (the message says which applied):

- ERROR: the observer failed (an internal error, a non-finite or implausible estimate:
  it was restarted) within the window;
- WARN: samples rejected within the window, waiting for a first sample, restarted and
  waiting, converged but diverging, the measurement rate below ``diagnostics.expected_rate``,
  no sample accepted for ``diagnostics.stale_after`` seconds, the outlier gate re-based;
- OK otherwise.
"""
from __future__ import annotations

from collections import Counter, deque

#: restart reasons that mean the observer failed (ERROR while in the window)
FAILURES = ("observer_error", "non_finite_state", "estimate_implausible")


class HealthWindow:
    """Events bucketed between status calls, kept for ``window`` seconds."""

    def __init__(self, window: float):
        self.window = window
        self.clear()

    def clear(self) -> None:
        self._current: Counter[str] = Counter()
        self._buckets: deque[tuple[float, Counter[str]]] = deque()
        self._last_active: float | None = None

    def count(self, event: str, n: int = 1) -> None:
        self._current[event] += n

    def close(self, now: float | None) -> Counter[str]:
        """Close the current bucket at ``now``; the events of the window (this bucket
        included).  Without a clock (now None) only the current bucket counts."""
        bucket, self._current = self._current, Counter()
        if now is None:
            return bucket
        if bucket.get("accepted"):
            self._last_active = now
        elif self._last_active is None:
            self._last_active = now          # the clock of the first call starts the count
        self._buckets.append((now, bucket))
        while self._buckets and self._buckets[0][0] <= now - self.window:
            self._buckets.popleft()
        # a clock that jumped back (sim time reset): forget the future
        while self._buckets and self._buckets[0][0] > now:
            self._buckets.popleft()
        total: Counter[str] = Counter()
        for _, b in self._buckets:
            total.update(b)
        return total

    def idle_for(self, now: float | None) -> float:
        """Seconds of the caller's clock since a status call that saw an accepted sample."""
        if now is None or self._last_active is None:
            return 0.0
        return max(0.0, now - self._last_active)
