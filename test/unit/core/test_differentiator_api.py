"""core/differentiator.py's robustness and API: bad arguments refused, bad samples leave the
state untouched, channels equal independent runs (filtered too), the state's round trip, a
copy steps on its own, read-only estimates, a constant signal and zero innovation, huge steps
stay finite, max_step splits with the sample held, scalar sample forms, user gains."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.core.differentiator import SCHEMES, Differentiator, levant_gains


# -- robustness and API --------------------------------------------------------------------
@pytest.mark.parametrize("kwargs,word", [
    (dict(order=0, L=1), "order"), (dict(order=8, L=1), "order"), (dict(order=2.0, L=1), "order"),
    (dict(order=True, L=1), "order"),
    (dict(order=2, L=0), "L"), (dict(order=2, L=float("nan")), "L"), (dict(order=2, L="x"), "L"),
    (dict(order=2, L=1, channels=0), "channels"), (dict(order=2, L=1, scheme="rk4"), "scheme"),
    (dict(order=2, L=1, rho=-1), "rho"), (dict(order=2, L=1, filter_order=-1), "filter_order"),
    (dict(order=7, L=1, filter_order=3), "filter_order"),
    (dict(order=2, L=1, scheme="euler", filter_order=1), "filter_order"),
    (dict(order=2, L=1, gains=(1, 2, 3)), "gains"),
    (dict(order=2, L=1, scheme="livne_levant", gains=(1, 2)), "gains"),
    (dict(order=2, L=1, scheme="livne_levant", gains=(1, 2, -3)), "gains"),
    (dict(order=2, L=1, max_step=0), "max_step"),
])
def test_bad_arguments(kwargs, word):
    with pytest.raises(ValueError, match=word):
        Differentiator(**kwargs)


@pytest.mark.parametrize("channels", [1, 3])
def test_bad_samples_leave_the_state_untouched(channels):
    d = Differentiator(2, 1.0, channels=channels)
    with pytest.raises(RuntimeError, match="reset"):
        d.update(1e-3, np.zeros(channels))
    d.reset(np.ones(channels), np.ones((channels, 2)))
    d.update(1e-3, np.full(channels, 1.001))
    before = d.get_state()
    est = d.estimates.copy()
    for h, f in [(0.0, np.ones(channels)), (-1e-3, np.ones(channels)),
                 (float("nan"), np.ones(channels)), (float("inf"), np.ones(channels)),
                 (1e-3, np.full(channels, np.nan)), (1e-3, np.ones(channels + 1))]:
        with pytest.raises(ValueError):
            d.update(h, f)
    with pytest.raises(ValueError, match="non-finite"):
        d.update(1e200, np.ones(channels))              # h^2 overflows
    assert np.array_equal(d.estimates, est)
    assert np.array_equal(d.get_state()[0], before[0])
    with pytest.raises(ValueError):
        d.reset(np.ones(channels), np.ones((channels, 3)))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_channels_equal_independent_runs(scheme):
    """3 channels through the numpy path = 3 single-channel runs through the unrolled path."""
    t = np.cumsum(np.random.default_rng(0).uniform(5e-4, 2e-3, 3000))
    sig = np.array([np.sin(t), np.cos(2 * t) + 1, 0.3 * t ** 2]).T
    multi = Differentiator(3, 4.0, channels=3, scheme=scheme, max_step=1.5e-3)
    singles = [Differentiator(3, 4.0, scheme=scheme, max_step=1.5e-3) for _ in range(3)]
    multi.reset(sig[0])
    for c, d in enumerate(singles):
        d.reset(sig[0, c:c + 1])
    for k in range(1, len(t)):
        zm = multi.update(t[k] - t[k - 1], sig[k])
        for c, d in enumerate(singles):
            zs = d.update(t[k] - t[k - 1], sig[k, c:c + 1])
            assert np.allclose(zm[c], zs[0], rtol=1e-9, atol=1e-9), (k, c)
    assert np.allclose(multi.residual, [d.residual[0] for d in singles], atol=1e-9)


def test_filtered_channels_equal_independent_runs():
    t = np.arange(2000) * 1e-3
    sig = np.array([np.sin(t), np.cos(t)]).T
    multi = Differentiator(2, 1.0, channels=2, filter_order=2)
    single = Differentiator(2, 1.0, filter_order=2)
    multi.reset(sig[0])
    single.reset(sig[0, :1])
    for k in range(1, len(t)):
        zm = multi.update(1e-3, sig[k])
        zs = single.update(1e-3, sig[k, :1])
    assert np.allclose(zm[0], zs[0], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("channels", [1, 2])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_state_round_trip(channels, scheme):
    d = Differentiator(3, 1.0, channels=channels, scheme=scheme)
    d.reset(np.zeros(channels))
    for k in range(1, 50):
        d.update(1e-2, np.full(channels, math.sin(k * 1e-2)))
    snap = d.get_state()
    first = [d.update(1e-2, np.full(channels, math.sin(k * 1e-2))).copy() for k in range(50, 60)]
    res_first = d.residual.copy()
    d.set_state(snap)
    second = [d.update(1e-2, np.full(channels, math.sin(k * 1e-2))).copy() for k in range(50, 60)]
    assert np.array_equal(np.array(first), np.array(second))
    assert np.array_equal(res_first, d.residual)


@pytest.mark.parametrize("channels", [1, 2])
def test_a_copy_steps_on_its_own(channels):
    """A deep copy (the fault suites copy runners) and a pickled copy publish their own
    estimates, the original's are untouched (numpy copies a view as an independent array:
    the estimates of a copy once stayed frozen at the time of the copy)."""
    import copy
    import pickle
    d = Differentiator(2, 1.0, channels=channels)
    d.reset(np.zeros(channels))
    for k in range(1, 20):
        d.update(1e-2, np.full(channels, math.sin(k * 1e-2)))
    copies = [copy.deepcopy(d), pickle.loads(pickle.dumps(d))]
    before = d.estimates.copy()
    ref = Differentiator(2, 1.0, channels=channels)
    ref.set_state(d.get_state())
    for k in range(20, 40):
        f = np.full(channels, math.sin(k * 1e-2))
        for c in copies:
            c.update(1e-2, f)
        ref.update(1e-2, f)
    for c in copies:
        np.testing.assert_array_equal(c.estimates, ref.estimates)
        np.testing.assert_array_equal(c.predicted, ref.predicted)
    assert not np.array_equal(ref.estimates, before)
    np.testing.assert_array_equal(d.estimates, before)


def test_estimates_are_a_read_only_view():
    d = Differentiator(2, 1.0)
    d.reset([1.0], [[2.0, 3.0]])
    z = d.update(1e-3, np.array([1.002]))
    assert z.shape == (1, 3) and z is d.estimates or np.array_equal(z, d.estimates)
    with pytest.raises(ValueError):
        z[0, 0] = 5.0
    assert d.residual.shape == (1,)
    assert d.residual[0] == pytest.approx(abs(1.002 - d.predicted[0, 0]))
    with pytest.raises(ValueError):
        d.predicted[0, 0] = 5.0


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("n", [1, 4, 7])
def test_constant_signal_and_zero_innovation(scheme, n):
    """e = 0 exactly (w = 1 deadbeat for the default scheme): finite, and f constant is
    reproduced exactly by the default and Livne-Levant schemes."""
    for channels in (1, 2):
        d = Differentiator(n, 1.0, scheme=scheme, channels=channels)
        d.reset(np.full(channels, 3.0))
        for _ in range(100):
            z = d.update(1e-3, np.full(channels, 3.0))
        assert np.all(np.isfinite(z))
        assert np.array_equal(z[:, 0], np.full(channels, 3.0))
        assert np.all(z[:, 1:] == 0.0)


def test_huge_steps_stay_finite():
    """A long gap (the stream paused) is a Taylor extrapolation over h: h = 1e3 s gives
    huge but finite estimates (w = 1); h = 2 s after convergence recovers within 15 s.
    (An observer should reset() after a gap much longer than its convergence time.)"""
    d = Differentiator(3, 1.0)
    d.reset([0.0])
    for k in range(1, 100):
        d.update(1e-2, [math.sin(k * 1e-2)])
    snap = d.get_state()
    z = d.update(1e3, [math.sin(1e3)])
    assert np.all(np.isfinite(z))
    d.set_state(snap)
    for k in range(1, 1000):
        d.update(1e-2, [math.sin(0.99 + k * 1e-2)])
    t0 = 0.99 + 999e-2 + 2.0
    z = d.update(2.0, [math.sin(t0)])
    assert np.abs(z[0, 1:] - [math.cos(t0), -math.sin(t0), -math.cos(t0)]).max() > 0.1
    for k in range(1, 1501):
        z = d.update(1e-2, [math.sin(t0 + k * 1e-2)])
    t = t0 + 1500 * 1e-2
    ref = [math.sin(t + i * math.pi / 2) for i in range(4)]
    assert np.allclose(z[0], ref, atol=0.05), (z, ref)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_max_step_splits_with_the_sample_held(scheme):
    """update(10 h, f1) with max_step = h equals ten h-steps on the held previous sample."""
    a = Differentiator(2, 1.0, scheme=scheme, max_step=1e-3)
    b = Differentiator(2, 1.0, scheme=scheme)
    for d in (a, b):
        d.reset([0.5], [[1.0, -0.5]])
    za = a.update(1e-2, [0.7])
    for _ in range(9):
        b.update(1e-3, [0.5])
    zb = b.update(1e-3, [0.7])
    assert np.allclose(za, zb, rtol=1e-12, atol=1e-15)
    assert np.allclose(a.residual, b.residual)


def test_scalar_sample_forms():
    """Channel-1 samples as float, (1,) array, list, 0-d array: same result."""
    outs = []
    for form in (lambda v: v, lambda v: np.array([v]), lambda v: [v], lambda v: np.float64(v),
                 lambda v: np.array(v)):
        d = Differentiator(2, 1.0)
        d.reset(form(0.0))
        for k in range(1, 20):
            d.update(1e-2, form(math.sin(k * 1e-2)))
        outs.append(d.estimates.copy())
    assert all(np.array_equal(o, outs[0]) for o in outs)


def test_user_gains_are_used():
    a = Differentiator(2, 1.0, scheme="livne_levant")
    b = Differentiator(2, 1.0, scheme="livne_levant", gains=levant_gains(2))
    c = Differentiator(2, 1.0, scheme="livne_levant", gains=(2.0, 4.0, 4.0))
    for d in (a, b, c):
        d.reset([0.0])
        for k in range(1, 20):
            d.update(1e-2, [math.sin(k * 1e-2)])
    assert np.array_equal(a.estimates, b.estimates)
    assert not np.array_equal(a.estimates, c.estimates)
