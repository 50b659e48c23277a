"""DC-motor plant (Mazenc & Malisoff 2022, eq. 65-67) and the ZOH simulator. No ROS needed."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from fto_ros.models import MODELS, get_model
from fto_ros.models import dc_motor
from fto_ros.models.dc_motor import DCMotorParams
from fto_ros.models.simulate import (quantize_ns, simulate, sparse_instants, to_ns,
                                     uniform_grid)

POINTS = [
    (0.0, (0.0, 0.0, 0.0), 0.0),
    (0.3, (0.5, -1.0, 0.2), 3.5),
    (1.7, (-2.0, 3.0, -0.7), -1.25),
    (4.0, (math.pi / 2, 0.25, 1.1), 6.0),
]


def eq65(x, u, p=DCMotorParams(), d=(0.0, 0.0, 0.0)):
    """Eq. (65) written out by hand."""
    q, qd, cur = x
    return np.array([
        qd + d[0],
        p.b1 * cur - p.a1 * math.sin(q) - p.a2 * qd + d[1],
        p.b0 * u - p.a3 * qd - p.a4 * cur + d[2],
    ])


def test_default_parameters_are_the_papers():
    p = DCMotorParams()
    assert (p.b0, p.b1, p.a1, p.a2, p.a3, p.a4) == (40.0, 15.0, 35.0, 1.0, 36.4, 200.0)
    with pytest.raises(Exception):
        p.a1 = 3.0  # frozen


@pytest.mark.parametrize("t,x,u", POINTS)
def test_rhs_matches_eq65(t, x, u):
    np.testing.assert_allclose(dc_motor.rhs(t, x, u), eq65(x, u), rtol=0, atol=1e-12)
    f = dc_motor.make_rhs()
    np.testing.assert_allclose(f(t, np.array(x), np.array([u])), eq65(x, u), rtol=0, atol=1e-12)


def test_rhs_with_uncertainty_and_other_parameters():
    p = DCMotorParams(b0=10.0, b1=2.0, a1=3.0, a2=0.5, a3=7.0, a4=50.0)
    x, u, d = (0.4, -0.3, 0.9), 1.5, (0.01, -0.2, 0.3)
    np.testing.assert_allclose(dc_motor.rhs(0.0, x, u, d, p), eq65(x, u, p, d), atol=1e-12)
    f = dc_motor.make_rhs({"b0": 10.0, "b1": 2.0, "a1": 3.0, "a2": 0.5, "a3": 7.0, "a4": 50.0})
    np.testing.assert_allclose(f(0.0, np.array(x), np.array([u])), eq65(x, u, p), atol=1e-12)
    with pytest.raises(ValueError, match="unknown dc_motor parameter"):
        dc_motor.make_rhs({"L": 1.0})


def test_uncertainty_is_the_documented_one():
    for t in (0.0, 0.4, 2.5):
        np.testing.assert_allclose(dc_motor.uncertainty(t),
                                   [0.0, 0.5 * math.sin(3 * t), 0.2 * math.cos(5 * t)])


def test_single_delay_split_eq67():
    a1, a2 = dc_motor.single_delay_split()
    np.testing.assert_array_equal(a1, [[-1.0, 15.0], [-36.4, -200.0]])
    np.testing.assert_array_equal(a2, [[1.0, 0.0]])
    # (A1, A2) observable, as the paper's appendix needs
    assert np.linalg.matrix_rank(np.vstack([a2, a2 @ a1])) == 2
    # det(A1 + k I) = k^2 - 201 k + 746 (Section V)
    for k in (0.5, 75.0, 100.0, 150.0):
        assert np.linalg.det(a1 + k * np.eye(2)) == pytest.approx(k * k - 201 * k + 746)


@pytest.mark.parametrize("t,x,u", POINTS)
def test_split_reproduces_the_plant(t, x, u):
    """xi1' = A1 xi1 + F1(q, u) and q' = A2 xi1 (eq. 66 without the observer's k terms)."""
    a1, a2 = dc_motor.single_delay_split()
    xi1 = np.array(x[1:])
    full = eq65(x, u)
    np.testing.assert_allclose(a1 @ xi1 + dc_motor.single_delay_f1(x[0], u), full[1:],
                               atol=1e-12)
    np.testing.assert_allclose(a2 @ xi1, full[:1], atol=1e-12)


def test_default_voltage_profile():
    v = lambda t: float(dc_motor.default_voltage(t)[0])  # noqa: E731
    assert v(0.0) == pytest.approx(3.5)
    assert v(0.5) == pytest.approx(2.0 + 3.0 + 1.5)
    assert v(0.7) == pytest.approx(2.0 + 3.0 * math.sin(0.7 * math.pi) - 1.5)
    assert v(1.4) == pytest.approx(2.0 + 3.0 * math.sin(1.4 * math.pi) + 1.5)
    # it has steps: a jump of 3 V at 0.7 s
    assert v(0.7 - 1e-6) - v(0.7) == pytest.approx(3.0, abs=1e-4)


def test_registry_spec_is_consistent():
    spec = get_model("dc_motor")
    assert MODELS["dc_motor"] is spec
    assert spec.n == 3 and spec.m == 1 and spec.p == 1
    assert spec.joint_names == ("joint1",)
    assert len(spec.default_x0) == spec.n and any(spec.default_x0)
    f = spec.make_rhs(dict(spec.default_params))
    x0 = np.array(spec.default_x0)
    u0 = np.atleast_1d(spec.default_input(0.0))
    assert u0.shape == (spec.m,)
    np.testing.assert_allclose(f(0.0, x0, u0), eq65(x0, u0[0]))
    np.testing.assert_array_equal(spec.output(x0), [x0[0]])
    assert spec.uncertainty(0.0).shape == (spec.n,)
    with pytest.raises(KeyError, match="unknown model .* known models: .*dc_motor"):
        get_model("no_such_plant")


# --------------------------------------------------------------------- simulator
def zoh_exact(a, b, x0, t_samples, t_input, u_profile, d=None):
    """Exact solution of x' = A x + B u_k + d (u held from the input instants), via expm."""
    n, m = b.shape
    t_break = np.union1d(t_samples, t_input[t_input <= t_samples[-1]])
    u_idx = np.searchsorted(t_input, t_break, side="right") - 1
    x = np.array(x0, dtype=float)
    out = {t_break[0]: x.copy()}
    for i in range(t_break.size - 1):
        h = t_break[i + 1] - t_break[i]
        u = np.atleast_1d(u_profile(t_input[u_idx[i]]))
        # augmented [[A, B, d], [0, 0, 0]] gives the ZOH step exactly
        aug = np.zeros((n + m + 1, n + m + 1))
        aug[:n, :n], aug[:n, n:n + m] = a, b
        if d is not None:
            aug[:n, -1] = d
        phi = expm(aug * h)
        x = phi[:n, :n] @ x + phi[:n, n:n + m] @ u + phi[:n, -1]
        out[t_break[i + 1]] = x.copy()
    return np.array([out[t] for t in t_samples])


A_LIN = np.array([[0.0, 1.0, 0.0], [-4.0, -0.4, 1.0], [0.0, -2.0, 0.3]])  # oscillatory, unstable
B_LIN = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 2.0]])


def u_lin(t):
    return np.array([math.sin(3.0 * t) + (1.0 if t > 0.5 else -1.0), math.cos(1.3 * t)])


def f_lin(t, x, u):
    return A_LIN @ x + B_LIN @ u


def test_zoh_linear_system_matches_exact_discretisation():
    t = uniform_grid(2.0, 100.0)
    res = simulate(f_lin, [1.0, -0.5, 0.25], t, u_lin)
    ref = zoh_exact(A_LIN, B_LIN, [1.0, -0.5, 0.25], t, t, u_lin)
    scale = np.abs(ref).max()
    assert np.abs(res.x - ref).max() <= 1e-9 * max(1.0, scale)
    # u_k is u_profile sampled at the input instants, and u is the held value at t
    np.testing.assert_array_equal(res.t_u, t)
    np.testing.assert_array_equal(res.u_k, np.array([u_lin(tk) for tk in t]))
    np.testing.assert_array_equal(res.u, res.u_k)


def test_zoh_with_irregular_samples_between_input_instants():
    rng = np.random.default_rng(7)
    t_input = uniform_grid(1.5, 50.0)
    t_samples = np.sort(np.concatenate([[0.0], rng.uniform(0, 1.5, 37)]))
    res = simulate(f_lin, [0.0, 1.0, -1.0], t_samples, u_lin, t_input=t_input)
    ref = zoh_exact(A_LIN, B_LIN, [0.0, 1.0, -1.0], t_samples, t_input, u_lin)
    assert np.abs(res.x - ref).max() <= 1e-9 * max(1.0, np.abs(ref).max())
    # the input acting at t is the one of the latest input instant <= t
    k = np.searchsorted(t_input, t_samples, side="right") - 1
    np.testing.assert_array_equal(res.u, np.array([u_lin(t_input[i]) for i in k]))


def test_additive_disturbance_is_integrated_exactly():
    d = np.array([0.3, -0.1, 0.2])
    t = uniform_grid(1.0, 40.0)
    res = simulate(f_lin, [1.0, 0.0, 0.0], t, u_lin, delta1=lambda _t: d)
    ref = zoh_exact(A_LIN, B_LIN, [1.0, 0.0, 0.0], t, t, u_lin, d=d)
    assert np.abs(res.x - ref).max() <= 1e-9 * max(1.0, np.abs(ref).max())


def test_dc_motor_simulation_converged_in_tolerance():
    """Default tolerances vs. a 100x tighter reference: the bag's truth is exact to ~1e-9."""
    spec = get_model("dc_motor")
    f = spec.make_rhs(dict(spec.default_params))
    t = uniform_grid(1.5, 1000.0)  # includes the 0.7 s and 1.4 s voltage steps
    res = simulate(f, spec.default_x0, t, spec.default_input, delta1=spec.uncertainty)
    ref = simulate(f, spec.default_x0, t, spec.default_input, delta1=spec.uncertainty,
                   rtol=1e-13, atol=1e-14)
    assert np.abs(res.x - ref.x).max() < 1e-9
    # and the disturbance really acts
    nominal = simulate(f, spec.default_x0, t, spec.default_input)
    assert np.abs(nominal.x - res.x).max() > 1e-3


def test_measurement_noise_is_seeded():
    spec = get_model("dc_motor")
    f = spec.make_rhs(dict(spec.default_params))
    t = uniform_grid(0.5, 1000.0)
    kw = dict(output=spec.output, noise_sigma=1e-3)
    a = simulate(f, spec.default_x0, t, spec.default_input, rng=np.random.default_rng(1), **kw)
    b = simulate(f, spec.default_x0, t, spec.default_input, rng=np.random.default_rng(1), **kw)
    np.testing.assert_array_equal(a.y, b.y)
    np.testing.assert_array_equal(a.y_true[:, 0], a.x[:, 0])
    err = a.y - a.y_true
    assert 0.8e-3 < err.std() < 1.2e-3
    with pytest.raises(ValueError, match="seeded numpy Generator"):
        simulate(f, spec.default_x0, t, spec.default_input, **kw)


def test_simulator_rejects_bad_times():
    with pytest.raises(ValueError, match="strictly increasing"):
        simulate(f_lin, [0, 0, 0], [0.0, 0.2, 0.1], u_lin)
    with pytest.raises(ValueError, match="first input instant"):
        simulate(f_lin, [0, 0, 0], [0.0, 0.1], u_lin, t_input=[0.05, 0.1])


def test_sparse_instants_respect_bounds():
    rng = np.random.default_rng(0)
    t = sparse_instants(10.0, 0.05, 0.12, rng)
    gaps = np.diff([to_ns(v) for v in t])
    assert t[0] == 0.0 and t[-1] <= 10.0
    assert gaps.min() >= 50_000_000 and gaps.max() <= 120_000_000
    # T_min = T_max (the paper's choice 0.1): exactly periodic at ns resolution
    t = sparse_instants(1.0, 0.1, 0.1, rng)
    assert [to_ns(v) for v in t] == [k * 100_000_000 for k in range(11)]
    with pytest.raises(ValueError):
        sparse_instants(1.0, 0.2, 0.1, rng)


def test_uniform_grid_is_whole_nanoseconds():
    t = uniform_grid(10.0, 1000.0)
    assert t.size == 10001 and t[-1] == 10.0
    ns = np.array([to_ns(v) for v in t])
    np.testing.assert_array_equal(ns, np.arange(10001) * 1_000_000)
    np.testing.assert_array_equal(quantize_ns(t), t)


def test_models_layer_imports_no_ros():
    code = ("import sys, fto_ros.models, fto_ros.models.simulate, fto_ros.models.dc_motor; "
            "bad = [m for m in ('rclpy', 'rosbags') if m in sys.modules]; "
            "sys.exit(1 if bad else 0)")
    root = Path(__file__).resolve().parents[3]
    assert subprocess.run([sys.executable, "-c", code], cwd=root).returncode == 0
