"""The continuous-discrete EKF (fto_ros/observers/ekf.py): on a linear plant it is the discrete
Kalman filter, on the DC motor and a pendulum it converges from a nearby start, its NIS has
mean p when the noise settings are the simulation's, and bad samples or parameters are
refused without touching the state."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from fto_ros.core.errors import ConfigError
from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate
from fto_ros.observers.base import SampleRejected, resolve
from fto_ros.observers.ekf import ExtendedKalmanFilter as EKF
from fto_ros.plant import resolve_plant
from fto_ros.plant.block import compiled
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files

# a linear 3-state plant (the DC motor without gravity) with one input and one output
A = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 15.0], [0.0, -36.4, -200.0]])
B = np.array([[0.0], [0.0], [40.0]])
C = np.array([[1.0, 0.0, 0.0]])
LINEAR = dict(states=["q", "w", "i"], inputs=["V"],
              f=["w", "-w + 15*i", "40*V - 36.4*w - 200*i"], h=["q"])
Q = np.array([1e-4, 0.25, 0.04])
R = 1e-6


def ekf(**cfg) -> EKF:
    return EKF(resolve(EKF.PARAMS, cfg, prefix="ekf."))


def discrete_model(h: float):
    """Phi, Gamma (held input) and Qd by independent means: augmented expm and quadrature."""
    n = 3
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A * h, B * h
    E = expm(M)
    s, w = np.polynomial.legendre.leggauss(20)
    s = 0.5 * h * (s + 1.0)
    Qd = sum(wi * 0.5 * h * expm(A * si) @ np.diag(Q) @ expm(A * si).T for si, wi in zip(s, w))
    return E[:n, :n], E[:n, n:], Qd


def kalman(steps, ys, us, x0, P0):
    """The textbook discrete Kalman filter (input held over each step)."""
    x, P, out = x0.copy(), P0.copy(), []
    for k, (h, y) in enumerate(zip(steps, ys)):
        if h > 0:
            Phi, G, Qd = discrete_model(h)
            x = Phi @ x + G @ us[k - 1]
            P = Phi @ P @ Phi.T + Qd
        S = C @ P @ C.T + R
        K = P @ C.T / S
        x = x + (K * (y - C @ x)).ravel()
        P = (np.eye(3) - K @ C) @ P
        out.append((x.copy(), P.copy()))
    return out


def test_on_a_linear_plant_the_ekf_is_the_discrete_kalman_filter():
    rng = np.random.default_rng(3)
    # irregular sampling, on the 1 us grid the observers round their steps to
    steps = np.concatenate(([0.0], rng.integers(500, 2000, 299) * 1e-6))
    t = np.cumsum(steps)
    us = rng.normal(size=(300, 1))
    ys = rng.normal(scale=0.1, size=300)
    f = ekf(**LINEAR, process_noise=Q.tolist(), measurement_noise=[R],
            initial_covariance=[1.0, 2.0, 3.0], max_step=1.0)
    f.reset(0.0, [0.1, 0.0, 0.0])
    ref = kalman(steps, ys, us, np.array([0.1, 0.0, 0.0]), np.diag([1.0, 2.0, 3.0]))
    for k in range(300):
        f.update(t[k], np.array([ys[k]]), us[k])
        x, P = ref[k]
        assert np.allclose(f.estimate, x, rtol=1e-9, atol=1e-12), (k, f.estimate, x)
        assert np.allclose(f.covariance, P, rtol=1e-7, atol=1e-15), k


def run_filter(filt: EKF, t, y, u, x0_hat):
    filt.reset(t[0], x0_hat)
    est = []
    for k in range(len(t)):
        filt.update(t[k], y[k], u[k])
        est.append(filt.estimate.copy())
    return np.array(est)


def test_converges_on_the_dc_motor_from_a_nearby_start():
    t = np.arange(3001) * 1e-3
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage)
    plant = resolve_plant(load_params_files(["config/dc_motor_plant.yaml"]))
    f = ekf(states=plant.states, inputs=plant.inputs, constants=plant.constant_texts,
            f=[str(e) for e in plant.nominal(plant.f_raw)], h=plant.h_texts,
            process_noise=[1e-6, 0.25, 0.04], measurement_noise=[1e-8])
    est = run_filter(f, t, sim.x[:, :1], sim.u, [0.6, 0.0, 0.0])
    err = np.abs(est - sim.x)
    assert np.max(err[0]) > 0.9                    # it starts 1 rad/s off
    assert np.max(err[1000:], axis=0).tolist() < [1e-6, 1e-4, 1e-4], np.max(err[1000:], axis=0)


PENDULUM = {"plant.states": ["theta", "omega"], "plant.inputs": ["tau"],
            "plant.constants": ["g=9.81", "l=0.5", "c=0.4", "J=0.2"],
            "plant.f": ["omega", "-g/l*sin(theta) - c*omega + tau/J"], "plant.h": ["theta"]}


def test_converges_on_a_pendulum_from_a_nearby_start():
    fn, hn = compiled(resolve_plant(PENDULUM))
    t = np.arange(4001) * 1e-3
    sim = simulate(lambda t_, x, u: np.array(fn(x, u, [])), [2.0, 0.0], t,
                   lambda s: [0.3 * math.sin(2.0 * s)])
    flat = dict(PENDULUM, **{"observer.type": "ekf", "ekf.process_noise": [1e-6, 1e-2],
                              "ekf.measurement_noise": [1e-8]})
    f = Runner(flat).observer                     # derived from the plant block
    est = run_filter(f, t, sim.x[:, :1], sim.u, [1.7, 1.0])
    err = np.abs(est - sim.x)
    assert np.max(err[0]) > 0.9
    assert np.max(err[2000:], axis=0).tolist() < [1e-6, 1e-4], np.max(err[2000:], axis=0)


def nis_mean(r_filter: float, seed: int = 5, n: int = 4000) -> float:
    """Mean NIS of the EKF on the linear plant simulated with process noise of intensity Q
    (exact discrete covariance) and measurement variance R."""
    rng = np.random.default_rng(seed)
    h = 1e-3
    Phi, G, Qd = discrete_model(h)
    Lq = np.linalg.cholesky(Qd)
    x = np.array([0.2, 0.0, 0.0])
    f = ekf(**LINEAR, process_noise=Q.tolist(), measurement_noise=[r_filter],
            initial_covariance=[1e-2, 1.0, 1.0])
    f.reset(0.0, [0.0, 0.0, 0.0])
    u = np.zeros(1)
    total = 0.0
    for k in range(n):
        if k:
            x = Phi @ x + G @ u + Lq @ rng.standard_normal(3)
        u = np.array([math.sin(3e-3 * k)])
        f.update(k * h, C @ x + math.sqrt(R) * rng.standard_normal(1), u)
        if k >= 200:
            total += f.nis
    return total / (n - 200)


def test_nis_is_consistent_with_the_right_noise_settings():
    # chi-square with p = 1: mean 1, standard error of the mean sqrt(2 / 3800) = 0.023
    assert abs(nis_mean(R) - 1.0) < 0.1
    # measurement noise set 100 times too small: the filter is overconfident
    assert nis_mean(R / 100) > 5.0


def test_a_sample_that_would_not_be_finite_is_rejected_and_the_state_kept():
    f = ekf(states=["x"], f=["-x"], h=["log(x)"], process_noise=[0.1], measurement_noise=[0.01])
    f.reset(0.0, [1.0])
    f.update(0.0, np.array([0.0]), np.zeros(0))
    x, P = f.estimate.copy(), f.covariance.copy()
    with pytest.raises(SampleRejected):
        f.update(1e-3, np.array([1e308]), np.zeros(0))     # NIS overflows
    assert f.estimate.tolist() == x.tolist() and np.array_equal(f.covariance, P)
    with pytest.raises(SampleRejected):
        f.update(0.0, np.array([0.0]), np.zeros(0))        # not after the previous sample
    f.reset(0.0, [-1.0])                                   # h = log(x) is not defined there
    with pytest.raises(SampleRejected):
        f.update(0.0, np.array([0.0]), np.zeros(0))
    assert f.estimate.tolist() == [-1.0]


@pytest.mark.parametrize("change, name", [
    (dict(process_noise=[1.0]), "ekf.process_noise"),
    (dict(measurement_noise=[0.0]), "ekf.measurement_noise"),
    (dict(initial_covariance=[1.0, -1.0, 1.0]), "ekf.initial_covariance"),
    (dict(f=["w", "-w + 15*i", "40*V - 36.4*w - 200*k"]), "ekf.f[2]"),
])
def test_bad_parameters_are_refused_naming_them(change, name):
    cfg = dict(LINEAR, process_noise=Q.tolist(), measurement_noise=[R])
    cfg.update(change)
    with pytest.raises(ConfigError) as e:
        ekf(**cfg)
    assert e.value.parameter == name and "\n" not in str(e.value)


def test_innovation_and_its_covariance_are_exposed():
    f = ekf(**LINEAR, process_noise=Q.tolist(), measurement_noise=[R])
    f.reset(0.0)
    assert f.innovation is None and math.isnan(f.nis)
    f.update(0.0, np.array([0.5]), np.array([1.0]))
    nu, S = f.innovation, f.innovation_covariance
    assert nu.shape == (1,) and S.shape == (1, 1)
    assert f.nis == pytest.approx(float(nu @ np.linalg.solve(S, nu)))
    assert f.health == f.nis and f.output_residual == pytest.approx(abs(nu[0]))
    assert "NIS mean since reset" in f.diagnostics()
