"""Hermite delay buffer (fto_ros/core/delay_buffer.py): accuracy, irregular spacing, growth, rewind."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.core.delay_buffer import DelayBuffer


def sin_buffer(times, capacity=256) -> DelayBuffer:
    """(t, [sin t, cos 2t], [cos t, -2 sin 2t]) at the given times."""
    b = DelayBuffer(2, capacity)
    for t in times:
        b.push(t, [math.sin(t), math.cos(2 * t)], [math.cos(t), -2 * math.sin(2 * t)])
    return b


def truth(t):
    return np.array([math.sin(t), math.cos(2 * t)])


def max_read_error(h: float, t_end: float = 3.0) -> float:
    times = np.arange(0.0, t_end + h / 2, h)
    b = sin_buffer(times)
    err = 0.0
    # read inside every interval at non-decreasing times
    for ta in times[:-1]:
        for s in (0.1, 0.25, 0.5, 0.7, 0.9):
            t = ta + s * h
            err = max(err, float(np.max(np.abs(b.at(t) - truth(t)))))
    return err


# -- accuracy --------------------------------------------------------------------------------
def test_hermite_error_is_fourth_order():
    e1 = max_read_error(0.1)
    e2 = max_read_error(0.05)
    # cubic Hermite: |f''''|/384 h^4 (|f''''| <= 16 for cos 2t)
    assert e1 < 16 / 384 * 0.1 ** 4 * 1.01
    assert e1 > 1e-8                 # well above round-off: the ratio means something
    ratio = e1 / e2
    assert 10.0 <= ratio <= 22.0, ratio


def test_the_derivatives_matter():
    # the same read with the derivatives set to zero (flat tangents) is far less accurate
    b = DelayBuffer(1)
    for t in np.arange(0.0, 1.01, 0.1):
        b.push(t, [math.sin(t)], [0.0])
    assert abs(b.at(0.55)[0] - math.sin(0.55)) > 1e-4      # Hermite with derivatives: 3e-7


def test_cubic_polynomial_is_reproduced_exactly():
    p = lambda t: 2.0 - t + 0.5 * t ** 2 - 0.3 * t ** 3  # noqa: E731
    dp = lambda t: -1.0 + t - 0.9 * t ** 2  # noqa: E731
    b = DelayBuffer(1)
    for t in (0.0, 0.13, 0.5, 0.52, 1.4, 2.0):
        b.push(t, [p(t)], [dp(t)])
    for t in np.linspace(0.0, 2.0, 57):
        assert b.at(t)[0] == pytest.approx(p(t), abs=1e-13)


def test_irregular_spacing_stays_accurate():
    rng = np.random.default_rng(7)
    gaps = rng.uniform(0.001, 0.05, size=400)      # 50:1 spacing ratio
    times = np.concatenate(([0.0], np.cumsum(gaps)))
    b = sin_buffer(times)
    reads = np.sort(rng.uniform(times[0], times[-1], size=2000))
    err = max(float(np.max(np.abs(b.at(t) - truth(t)))) for t in reads)
    assert err < 16 / 384 * gaps.max() ** 4 * 1.01
    assert err < 3e-7


def test_reads_at_stored_times_return_stored_values_exactly():
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.01, 0.2, size=50))
    values = rng.standard_normal((50, 3))
    derivs = rng.standard_normal((50, 3)) * 100     # derivatives must not leak into the value
    b = DelayBuffer(3, capacity=8)
    for t, v, d in zip(times, values, derivs):
        b.push(t, v, d)
    for t, v in zip(times, values):
        out = b.at(t)
        np.testing.assert_array_equal(out, v)
    # the same time read twice is allowed (non-decreasing) and gives the same value
    np.testing.assert_array_equal(b.at(times[-1]), values[-1])


def test_read_returns_a_copy():
    b = DelayBuffer(1)
    b.push(0.0, [1.0], [0.0])
    b.push(1.0, [2.0], [0.0])
    v = b.at(0.0)
    v[0] = 99.0
    assert b.at(0.0)[0] == 1.0
    v = b.at(1.0)
    v[0] = 99.0
    assert b.at(1.0)[0] == 2.0


# -- errors ----------------------------------------------------------------------------------
def test_read_outside_the_range_raises():
    b = DelayBuffer(1)
    with pytest.raises(ValueError):
        b.at(0.0)                              # empty
    assert math.isnan(b.first_time)
    b.push(1.0, [1.0], [0.0])
    b.push(2.0, [2.0], [0.0])
    with pytest.raises(ValueError):
        b.at(0.999)
    with pytest.raises(ValueError):
        b.at(2.0 + 1e-9)
    with pytest.raises(ValueError):
        b.at(float("nan"))
    # the failed reads changed nothing
    assert b.at(1.5)[0] == pytest.approx(1.5)


def test_read_earlier_than_the_previous_read_raises():
    b = sin_buffer(np.arange(0.0, 1.01, 0.1))
    b.at(0.55)
    with pytest.raises(ValueError, match="before the previous read"):
        b.at(0.35)
    with pytest.raises(ValueError):
        b.at(0.0)
    # later reads still work
    assert b.at(0.75)[0] == pytest.approx(math.sin(0.75), abs=1e-6)


def test_after_clear_the_buffer_is_empty():
    b = sin_buffer(np.arange(0.0, 1.0, 0.1))
    b.at(0.5)
    b.clear()
    assert len(b) == 0
    with pytest.raises(ValueError):
        b.at(0.5)
    b.push(5.0, [1.0, 2.0], [0.0, 0.0])
    np.testing.assert_array_equal(b.at(5.0), [1.0, 2.0])
    assert b.first_time == 5.0


# -- growth ----------------------------------------------------------------------------------
def cubic(t):
    return np.array([0.1 * t ** 3 - t, 3.0 - 0.5 * t ** 2]), np.array([0.3 * t ** 2 - 1.0, -t])


def test_growth_keeps_every_value():
    b = DelayBuffer(2, capacity=4)
    times = np.arange(10_000) * 1e-3
    for t in times:
        v, d = cubic(t)
        b.push(t, v, d)
    assert len(b) == 10_000
    assert b.first_time == 0.0
    for t in times[::7]:
        np.testing.assert_array_equal(b.at(t), cubic(t)[0])


def test_growth_while_reading_with_a_lag():
    b = DelayBuffer(2, capacity=4)
    lag = 0.0237                                     # not a multiple of the step
    dt = 1e-3
    worst = 0.0
    for i in range(10_000):
        t = i * dt
        v, d = cubic(t)
        b.push(t, v, d)
        if t - lag >= 0.0:
            r = t - lag
            worst = max(worst, float(np.max(np.abs(b.at(r) - cubic(r)[0]))))
    assert worst < 1e-9                              # Hermite is exact for a cubic
    assert len(b) == 10_000                          # nothing trimmed: everything kept
    # all entries still there, readable in order from the oldest after a fresh cursor
    c = DelayBuffer(2, capacity=4)
    for i in range(10_000):
        v, d = cubic(i * dt)
        c.push(i * dt, v, d)
    np.testing.assert_array_equal(c.at(0.0), cubic(0.0)[0])
    np.testing.assert_array_equal(c.at(9.999), cubic(9.999)[0])


def test_trim_bounds_len_and_memory():
    b = DelayBuffer(2, capacity=4)
    dt, tau = 1e-3, 0.1
    longest = 0
    for i in range(20_000):
        t = i * dt
        v, d = cubic(t)
        b.push(t, v, d)
        if t >= tau:
            r = t - tau
            np.testing.assert_allclose(b.at(r), cubic(r)[0], rtol=0, atol=1e-9)
            b.trim()
            longest = max(longest, len(b))
    # one delay window of entries (tau/dt + 1), plus the one at or before the cursor
    assert longest <= round(tau / dt) + 2
    assert b._cap <= 256                             # memory ~ one window, not the whole run
    assert b.first_time <= 20_000 * dt - tau


def test_trim_drops_only_entries_before_the_cursor():
    b = sin_buffer(np.arange(0.0, 1.001, 0.1))
    b.at(0.55)
    b.trim()
    assert b.first_time == pytest.approx(0.5)
    assert len(b) == 6
    with pytest.raises(ValueError):
        b.at(0.45)
    assert b.at(0.6)[0] == pytest.approx(math.sin(0.6), abs=1e-12)


# -- mark / rewind -----------------------------------------------------------------------------
def test_rewind_restores_pushes_and_reads_exactly():
    ref = DelayBuffer(2, capacity=64)
    b = DelayBuffer(2, capacity=64)
    for t in np.arange(0.0, 0.5, 0.01):
        v, d = cubic(t)
        ref.push(t, v, d)
        b.push(t, v, d)
    ref.at(0.2)
    b.at(0.2)
    m = b.mark()
    # an abandoned sample: pushes garbage, reads further on
    for t in (0.5, 0.51, 0.52):
        b.push(t, [1e9, -1e9], [1e9, 1e9])
    b.at(0.45)
    b.at(0.515)
    b.rewind(m)
    assert len(b) == len(ref)
    # reading back earlier than the abandoned read is allowed again
    np.testing.assert_array_equal(b.at(0.21), ref.at(0.21))
    # new pushes at the abandoned times replace the garbage
    for t in (0.5, 0.505, 0.51):
        v, d = cubic(t)
        ref.push(t, v, d)
        b.push(t, v, d)
    for t in (0.3, 0.499, 0.5, 0.503, 0.51):
        np.testing.assert_array_equal(b.at(t), ref.at(t))


def test_rewind_across_growth():
    b = DelayBuffer(1, capacity=4)
    ref = DelayBuffer(1, capacity=4)
    for t in (0.0, 0.1, 0.2):
        b.push(t, [t], [1.0])
        ref.push(t, [t], [1.0])
    b.at(0.05)
    ref.at(0.05)
    m = b.mark()
    cap_before = b._cap
    for i in range(3, 40):                            # grows 4 -> 8 -> 16 -> 32 -> 64
        b.push(i * 0.1, [-5.0], [0.0])
    assert b._cap > cap_before
    b.at(2.0)
    b.rewind(m)
    assert len(b) == 3
    for i in range(3, 12):
        t = i * 0.1
        b.push(t, [t], [1.0])
        ref.push(t, [t], [1.0])
    for t in np.linspace(0.05, 1.1, 31):
        np.testing.assert_array_equal(b.at(t), ref.at(t))
        assert b.at(t)[0] == pytest.approx(t, abs=1e-12)


def test_mark_after_trim_and_repeated_rewinds():
    b = DelayBuffer(1, capacity=4)
    for i in range(10):
        b.push(i * 1.0, [float(i)], [1.0])
    b.at(4.5)
    b.trim()
    m = b.mark()
    for _ in range(3):
        for i in range(10, 30):
            b.push(i * 1.0, [0.0], [0.0])
        b.at(25.0)
        b.rewind(m)
        assert len(b) == 6
        assert b.first_time == 4.0
        assert b.at(4.5)[0] == pytest.approx(4.5)
        assert b.at(9.0)[0] == 9.0
        b.rewind(m)


# -- the compiled ring: fixed capacity, thinning -------------------------------------------------
def test_a_ring_thins_a_stream_faster_than_its_capacity_to_fourth_order():
    """A ring of fixed capacity that trims after each read at t - lag holds at most
    dense + lag / min_gap + 2 entries however fast the stream; the thinned entries are
    min_gap apart, so reads stay within the Hermite bound of that spacing."""
    from fto_ros.core.delay_buffer import CURSOR, START, ring_floats, ring_push, ring_read
    dim, dense, gap, lag, dt = 2, 100, 0.01, 1.0, 1e-4
    cap = 2 * dense + int(lag / gap) + 8
    wk, idx, out = np.zeros(ring_floats(cap, dim)), np.zeros(3), np.empty(dim)
    kept = longest = 0
    worst = 0.0
    for i in range(40_000):                      # 4 s at 10 kHz: 10000 samples per lag
        t = i * dt
        kept += ring_push(wk, 0, cap, dim, idx, int(idx[START]), t,
                          np.array([math.sin(t), math.cos(2 * t)]),
                          np.array([math.cos(t), -2 * math.sin(2 * t)]), gap, dense)
        if t >= lag:
            ring_read(wk, 0, cap, dim, idx, t - lag, out)
            worst = max(worst, float(np.max(np.abs(out - truth(t - lag)))))
            idx[START] = idx[CURSOR]
            longest = max(longest, int(idx[2] - idx[0]))
    assert kept < 40_000 / 50                    # thinned: about one entry per min_gap
    assert longest <= dense + lag / gap + 3
    # spacing at most gap + dt: cubic Hermite |f''''| / 384 h^4 (|f''''| <= 16)
    bound = 16 / 384 * (gap + dt) ** 4
    assert 1e-3 * bound < worst < bound, (worst, bound)


def test_a_ring_keeps_a_slow_stream_whole():
    from fto_ros.core.delay_buffer import ring_floats, ring_push
    wk, idx = np.zeros(ring_floats(64, 1)), np.zeros(3)
    for i in range(40):                          # fewer than `dense` entries: none skipped
        assert ring_push(wk, 0, 64, 1, idx, 0, i * 1e-6, np.ones(1), np.zeros(1), 0.5, 50)
    assert idx[2] == 40


def test_a_full_ring_never_overwrites_the_committed_entries():
    from fto_ros.core.delay_buffer import ring_floats, ring_push
    wk, idx = np.zeros(ring_floats(8, 1)), np.zeros(3)
    for i in range(8):
        assert ring_push(wk, 0, 8, 1, idx, 0, float(i), np.full(1, i), np.zeros(1), 0.0, 100)
    before = wk.copy()
    assert not ring_push(wk, 0, 8, 1, idx, 0, 8.0, np.full(1, 8.0), np.zeros(1), 0.0, 100)
    np.testing.assert_array_equal(wk, before)
    assert idx[2] == 8
