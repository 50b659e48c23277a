"""A history of a vector signal, read back at ``t - tau``, for irregular sampling.

Each entry stores the time, the value and its time derivative, so a read
between two entries is a cubic Hermite interpolation: O(h^4) accurate for a
smooth signal, whatever the spacing of the samples.  Reads are expected at
non-decreasing times (``t - tau`` as t advances), so a cursor makes them O(1);
``trim()`` drops what lies before the cursor, and ``mark()``/``rewind()`` undo
the pushes and reads since the mark (so an observer can abandon a sample
without corrupting its history).  The storage is a ring that doubles when full,
so memory stays proportional to the samples inside one delay window.
"""
from __future__ import annotations

import numpy as np


class DelayBuffer:
    """Ring buffer of (t, value, derivative) with Hermite reads at non-decreasing times."""

    def __init__(self, dim: int, capacity: int = 256):
        self.dim = dim
        self._cap = max(4, capacity)
        self._t = np.empty(self._cap)
        self._vd = np.empty((self._cap, 2 * dim))   # row = [value, derivative]
        self.clear()

    def clear(self) -> None:
        self._start = 0      # absolute index of the oldest kept entry
        self._cursor = 0     # absolute index of the entry at or before the last read
        self._end = 0        # absolute index one past the newest

    def __len__(self) -> int:
        return self._end - self._start

    @property
    def first_time(self) -> float:
        return float(self._t[self._start % self._cap]) if len(self) else float("nan")

    def push(self, t: float, value, derivative) -> None:
        """Append the entry at time t (strictly after the newest one)."""
        if len(self) == self._cap:
            self._grow()
        i = self._end % self._cap
        self._t[i] = t
        self._vd[i, :self.dim] = value
        self._vd[i, self.dim:] = derivative
        self._end += 1

    def at(self, t: float) -> np.ndarray:
        """The signal at time t (first entry <= t <= newest entry), Hermite-interpolated.

        The next read must not be earlier than this one.
        """
        cap = self._cap
        if not len(self) or not self._t[self._start % cap] <= t <= self._t[(self._end - 1) % cap]:
            raise ValueError(f"time {t} outside the buffer [{self.first_time}, newest]")
        a = self._cursor
        if t < self._t[a % cap]:
            raise ValueError(f"time {t} is before the previous read")
        while a + 1 < self._end and self._t[(a + 1) % cap] <= t:
            a += 1
        self._cursor = a
        ia = a % cap
        ta = float(self._t[ia])
        if a + 1 == self._end or t == ta:
            return self._vd[ia, :self.dim].copy()
        ib = (a + 1) % cap
        h = float(self._t[ib]) - ta
        s = (t - ta) / h
        s2 = s * s
        s3 = s2 * s
        # Hermite basis on rows [v_a, d_a, v_b, d_b]: one small product
        coef = np.array((2 * s3 - 3 * s2 + 1, (s3 - 2 * s2 + s) * h, -2 * s3 + 3 * s2, (s3 - s2) * h))
        return coef @ self._vd[[ia, ib]].reshape(4, self.dim)

    def trim(self) -> None:
        """Drop the entries before the last read."""
        self._start = self._cursor

    def mark(self) -> tuple[int, int]:
        """A point to ``rewind`` to (valid until the next ``trim``)."""
        return (self._cursor, self._end)

    def rewind(self, mark: tuple[int, int]) -> None:
        """Forget the pushes and reads made since ``mark``."""
        self._cursor, self._end = mark

    def _grow(self) -> None:
        # keep absolute indices valid (marks survive growth): entry i goes to i % cap
        cap = 2 * self._cap
        old = np.arange(self._start, self._end)
        t, vd = np.empty(cap), np.empty((cap, 2 * self.dim))
        t[old % cap], vd[old % cap] = self._t[old % self._cap], self._vd[old % self._cap]
        self._t, self._vd, self._cap = t, vd, cap
