"""A history of a vector signal, read back at ``t - tau``, for irregular sampling.

Each entry stores the time, the value and its time derivative, so a read between two
entries is a cubic Hermite interpolation: O(h^4) accurate for a smooth signal, whatever the
spacing of the samples.  Reads come at non-decreasing times (``t - tau`` as t advances), so
a cursor makes them O(1); a trim drops what lies before the cursor.

**The ring** (compiled, core/jit.py) lives in a float64 work array at ``base``:

    times[cap] | rows[cap, 2 dim] = [value, derivative] | scratch[4 + 4 dim]

and its indices in a float array ``idx = [start, cursor, end]`` (absolute: entry i is in
slot i % cap) that its owner keeps in its state.  A kernel pushes and reads on its
candidate state's indices, so a rejected sample, whose candidate is discarded, takes its
pushes and reads back with it; ``keep`` (the committed start) guards the committed entries
from being overwritten by the candidate's pushes.

The capacity is fixed.  Once the ring holds ``dense`` entries, a push closer than
``min_gap`` after the newest entry is skipped: a stream too fast for the ring is thinned to
that spacing (a read then interpolates between entries that far apart: still O(min_gap^4)),
a slower one is kept whole.  An owner that trims after each read, with min_gap = window / E,
holds at most dense + E + 2 entries of one window: the entries pushed while the ring held
fewer than ``dense`` are at most ``dense`` (they were all there at the last one's push), the
later ones are min_gap apart (see observers/single_delay/kernel.py).
Reads clamp to the stored span: below the cursor's entry (the oldest a read may still
need) and above the newest.

``DelayBuffer`` is a Python view of one ring of its own that grows when full (doubling,
entries keep their absolute indices), with ``mark``/``rewind`` to undo pushes and reads,
and that refuses reads outside its span: for tools and the ring's tests.
"""
from __future__ import annotations

import numpy as np

from .errors import BadArgument
from .jit import jit

START, CURSOR, END = 0, 1, 2


def ring_floats(cap: int, dim: int) -> int:
    """Floats a ring of ``cap`` entries of ``dim`` values takes in a work array."""
    return cap * (1 + 2 * dim) + 4 + 4 * dim


@jit
def ring_push(wk, base, cap, dim, idx, keep, t, value, deriv, min_gap, dense):
    """Append the entry (t, value, deriv) after the newest (t later than it).  Skipped
    (False) when the ring holds ``dense`` entries or more and t is less than min_gap after
    the newest one (thinning), or when it holds ``cap`` entries from index ``keep`` on
    (nothing from there is overwritten)."""
    start = int(idx[START])
    end = int(idx[END])
    if end - start >= dense and t - wk[base + (end - 1) % cap] < min_gap:
        return False
    if end - keep >= cap:
        return False
    i = end % cap
    wk[base + i] = t
    row = base + cap + i * 2 * dim
    for j in range(dim):
        wk[row + j] = value[j]
        wk[row + dim + j] = deriv[j]
    idx[END] = end + 1
    return True


@jit
def ring_read(wk, base, cap, dim, idx, t, out):
    """out = the signal at t (clamped to [the cursor's entry, the newest]), Hermite-
    interpolated; moves the cursor to the last entry at or before t.  The ring must not be
    empty."""
    a = int(idx[CURSOR])
    end = int(idx[END])
    ta = wk[base + a % cap]
    if t < ta:
        t = ta
    t_new = wk[base + (end - 1) % cap]
    if t > t_new:
        t = t_new
    while a + 1 < end and wk[base + (a + 1) % cap] <= t:
        a += 1
    idx[CURSOR] = a
    ia = a % cap
    ta = wk[base + ia]
    rows = base + cap
    if a + 1 == end or t == ta:
        r = rows + ia * 2 * dim
        for j in range(dim):
            out[j] = wk[r + j]
        return
    ib = (a + 1) % cap
    h = wk[base + ib] - ta
    s = (t - ta) / h
    s2 = s * s
    s3 = s2 * s
    scratch = base + cap * (1 + 2 * dim)
    coef = wk[scratch:scratch + 4]
    coef[0] = 2 * s3 - 3 * s2 + 1
    coef[1] = (s3 - 2 * s2 + s) * h
    coef[2] = -2 * s3 + 3 * s2
    coef[3] = (s3 - s2) * h
    # rows [v_a, d_a, v_b, d_b] as one (4, dim) matrix: in place unless the pair wraps
    if ib == ia + 1:
        r = rows + ia * 2 * dim
        M = wk[r:r + 4 * dim]
    else:
        M = wk[scratch + 4:scratch + 4 + 4 * dim]
        M[:2 * dim] = wk[rows + ia * 2 * dim:rows + (ia + 1) * 2 * dim]
        M[2 * dim:] = wk[rows:rows + 2 * dim]
    # one small product, as numpy's coef @ M: BLAS gemv, a dot product for one column
    if dim == 1:
        out[0] = np.dot(coef, M)
    else:
        np.dot(coef, M.reshape(4, dim), out)


class DelayBuffer:
    """A ring of (t, value, derivative) with Hermite reads at non-decreasing times, that
    grows when full and refuses reads outside its span (ValueError)."""

    def __init__(self, dim: int, capacity: int = 256):
        self.dim = dim
        self._cap = max(4, capacity)
        self._wk = np.zeros(ring_floats(self._cap, dim))
        self._idx = np.zeros(3)

    def clear(self) -> None:
        self._idx[:] = 0.0

    def __len__(self) -> int:
        return int(self._idx[END] - self._idx[START])

    def _time(self, i: float) -> float:
        return float(self._wk[int(i) % self._cap])

    @property
    def first_time(self) -> float:
        return self._time(self._idx[START]) if len(self) else float("nan")

    def push(self, t: float, value, derivative) -> None:
        """Append the entry at time t (after the newest one)."""
        if len(self) == self._cap:
            self._grow()
        ring_push(self._wk, 0, self._cap, self.dim, self._idx, int(self._idx[START]), float(t),
                  np.ascontiguousarray(value, dtype=float),
                  np.ascontiguousarray(derivative, dtype=float), 0.0, 0)

    def at(self, t: float) -> np.ndarray:
        """The signal at time t (first entry <= t <= newest entry), Hermite-interpolated.
        The next read must not be earlier than this one."""
        if not len(self) or not self.first_time <= t <= self._time(self._idx[END] - 1):
            raise BadArgument(f"time {t} outside the buffer [{self.first_time}, newest]")
        if t < self._time(self._idx[CURSOR]):
            raise BadArgument(f"time {t} is before the previous read")
        out = np.empty(self.dim)
        ring_read(self._wk, 0, self._cap, self.dim, self._idx, float(t), out)
        return out

    def trim(self) -> None:
        """Drop the entries before the last read."""
        self._idx[START] = self._idx[CURSOR]

    def mark(self) -> tuple[float, float]:
        """A point to ``rewind`` to (valid until the next ``trim``)."""
        return (float(self._idx[CURSOR]), float(self._idx[END]))

    def rewind(self, mark: tuple[float, float]) -> None:
        """Forget the pushes and reads made since ``mark``."""
        self._idx[CURSOR], self._idx[END] = mark

    def _grow(self) -> None:
        # keep absolute indices valid (marks survive growth): entry i goes to slot i % cap
        old, cap, d = self._cap, 2 * self._cap, 2 * self.dim
        wk = np.zeros(ring_floats(cap, self.dim))
        i = np.arange(int(self._idx[START]), int(self._idx[END]))
        wk[i % cap] = self._wk[i % old]
        rows_new = (cap + (i % cap)[:, None] * d + np.arange(d)).ravel()
        rows_old = (old + (i % old)[:, None] * d + np.arange(d)).ravel()
        wk[rows_new] = self._wk[rows_old]
        self._wk, self._cap = wk, cap
