"""The window form of the momentum identity on actual stamps (fto_ros/arm/identify_windows.py,
identify_regressor.py) and the identified corrections applied to a model (arm/tree.py's
correct_inertia, shift_params)."""
from __future__ import annotations

import numpy as np
import pytest

from arm_urdfs import chain, gripper_arm
from fto_ros.arm.identify_windows import WindowError, Windows, centred_velocity, kernel
from fto_ros.arm.model import load_model
from fto_ros.arm.tree import inertia_params, shift_params
from fto_ros.core.errors import ConfigError


def _stamps(N=400, h=1e-3, jitter=0.3e-3, seed=0, lost=()):
    rng = np.random.default_rng(seed)
    t = np.arange(N) * h + rng.uniform(-jitter, jitter, N) * (np.arange(N) > 0)
    return np.delete(t, list(lost))


def _integral(f, te, T, order, points=20001):
    u = np.linspace(0.0, T, points)
    return np.trapezoid(kernel(u, T, order) * f(te - u), u)


def test_weights_integrate_the_kernel_exactly_on_jittered_stamps_with_lost_samples():
    t = _stamps(lost=(100, 101, 250))
    T = 0.06
    w = Windows(t, T, stride=7, max_gap=0.01)
    te = t[w.ends]
    one = np.ones(t.size)
    # integral k = 1, integral k' = integral k'' = 0 (boundary terms vanish)
    for A, want in ((w.A0, 1.0), (w.A1, 0.0), (w.A2, 0.0), (w.Z, 1.0)):
        np.testing.assert_allclose(A @ one, want, atol=1e-9)    # rounding of weights ~1e4
    # data linear in time is interpolated exactly: integral k'(u) (t_e - u) du = 1
    np.testing.assert_allclose(w.A1 @ t - te * (w.A1 @ one), 1.0, atol=1e-10)
    np.testing.assert_allclose(w.A2 @ t - te * (w.A2 @ one), 0.0, atol=1e-8)
    # smooth data: the kernel is integrated exactly, what is left is the linear
    # interpolation's error between samples, at most h^2 / 8 max|f''| times integral |k^(o)|
    f = lambda s: np.sin(7.0 * s) + 0.3 * s ** 2   # noqa: E731
    h = np.diff(t).max()
    u = np.linspace(0, T, 100001)
    for A, order in ((w.A0, 0), (w.A1, 1), (w.A2, 2)):
        bound = h ** 2 / 8 * 49.6 * np.trapezoid(np.abs(kernel(u, T, order)), u)
        err = np.abs(A @ f(t) - [_integral(f, x, T, order) for x in te])
        assert err.max() < bound and err.max() > 1e-3 * bound
    # the held value over [t_j, t_j+1) weighs with the kernel over that interval
    step = (t >= t[200]).astype(float)
    k = np.flatnonzero(w.ends > 200)[0]
    u_step = te[k] - t[200]
    assert (w.Z @ step)[k] == pytest.approx(_integral(lambda s: (s >= t[200]) * 1.0, te[k], T, 0,
                                                      400001), abs=2e-5)
    assert 0 < u_step < T


def test_no_window_over_a_gap_or_an_excluded_sample():
    t = _stamps(N=300, jitter=0.0)
    t[150:] += 0.05                                  # a 50 ms gap
    w = Windows(t, 0.03, stride=1, max_gap=0.01)
    assert not np.any((t[w.first] < t[150]) & (t[w.ends] >= t[150]))
    mask = np.ones(t.size, bool)
    mask[60] = False
    w2 = Windows(t, 0.03, stride=1, max_gap=0.1, mask=mask)
    assert not np.any((w2.first <= 60) & (w2.ends >= 60))
    with pytest.raises(WindowError, match="no window"):
        Windows(t[:20], 0.03)


def test_centred_velocity_on_jittered_stamps():
    t = _stamps(N=200, seed=3)
    q = np.stack([0.3 + 2.0 * t - 1.5 * t ** 2 + 4.0 * t ** 3, np.sin(3 * t)], axis=1)
    v = centred_velocity(t, q)
    want = np.stack([2.0 - 3.0 * t + 12.0 * t ** 2, 3 * np.cos(3 * t)], axis=1)
    np.testing.assert_allclose(v[:, 0], want[:, 0], atol=1e-9)     # a cubic: exact
    np.testing.assert_allclose(v[:, 1], want[:, 1], atol=2e-6)      # the end: one-sided


def test_shift_params_agrees_with_placing_a_body():
    rng = np.random.default_rng(1)
    for _ in range(20):
        m, c = rng.uniform(0.1, 3), rng.uniform(-0.2, 0.2, 3)
        a = rng.uniform(0.01, 0.1, 3)
        Rb = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        I = Rb @ np.diag(a) @ Rb.T
        R = np.linalg.qr(rng.standard_normal((3, 3)))[0]
        p = rng.uniform(-0.3, 0.3, 3)
        np.testing.assert_allclose(shift_params(inertia_params(m, c, I), R, p),
                                   inertia_params(m, c, I, R, p), atol=1e-12)


def test_inertia_corrections_change_the_model_as_the_urdf_would():
    """A link scaled by f, or corrected by a delta, gives the terms of a URDF written with
    those inertias (here: the same URDF with the link's mass, com and inertia changed)."""
    base = load_model(None, robot_description=chain(3))
    scaled = load_model(None, robot_description=chain(3), inertia_scale={"l2": 1.3})
    b, params = base.tree.link_params("l2")
    rows = base.tree.rows.copy()
    rng = np.random.default_rng(2)
    q, v = rng.standard_normal(3), rng.standard_normal(3)
    M0 = base.mass_matrix(q)
    base.tree.rows[b, 17:27] += 0.3 * params                        # INERTIA columns
    np.testing.assert_allclose(scaled.mass_matrix(q), base.mass_matrix(q), atol=1e-14)
    np.testing.assert_allclose(scaled.gravity(q), base.gravity(q), atol=1e-13)
    base.tree.rows[:] = rows
    np.testing.assert_allclose(base.mass_matrix(q), M0)
    d = [0.2, 0.01, -0.02, 0.03, 0.004, 0.0, 0.001, 0.0, 0.0, 0.0]
    corrected = load_model(None, robot_description=chain(3), inertia_delta={"l3": d})
    b3, _ = corrected.tree.link_params("l3")
    np.testing.assert_allclose(corrected.tree.rows[b3, 17:27] - base.tree.rows[b3, 17:27], d)
    np.testing.assert_allclose(corrected.coriolis(q, v) - base.coriolis(q, v),
                               _only(base, b3, d).coriolis(q, v), atol=1e-13)
    # a payload added after the corrections keeps them; correcting again replaces them
    corrected.set_payload("l3", 0.5)
    corrected.correct_inertia(delta={"l3": d})
    assert corrected.tree.inertia_delta["l3"].tolist() == d


def _only(model, body, d):
    m = load_model(None, robot_description=chain(3))
    m.tree.rows[:, 17:27] = 0.0
    m.tree.rows[body, 17:27] = d
    return m


def test_corrections_refused_in_one_line():
    with pytest.raises(ConfigError, match="plant.inertia_scale.links.*nope"):
        load_model(None, robot_description=chain(3), inertia_scale={"nope": 1.1})
    with pytest.raises(ConfigError, match="plant.inertia_scale.factors.*l1"):
        load_model(None, robot_description=chain(3), inertia_scale={"l1": -1.0})
    with pytest.raises(ConfigError, match="plant.inertia_delta.values.*10 finite"):
        load_model(None, robot_description=chain(3), inertia_delta={"l1": [1.0, 2.0]})
    with pytest.raises(ConfigError, match="mass negative"):
        load_model(None, robot_description=chain(3), inertia_delta={"l1": [-5] + [0] * 9})
    # the fingers' links are no body a listed joint moves, yet they move: a scale is accepted
    m = load_model([], robot_description=gripper_arm(0, camera=False),
                   inertia_scale={"hand": 1.1})
    assert m.tree.inertia_scale == {"hand": 1.1}
