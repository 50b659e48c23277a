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
from fto_ros.core.params import resolve
from fto_ros.observers.base import SampleRejected
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


def kalman(steps, ys, us, x0, P0, started=False):
    """The textbook discrete Kalman filter (input held over each step); ``started``: (x0, P0)
    is already the first sample's (no correction with it)."""
    x, P, out = x0.copy(), P0.copy(), []
    for k, (h, y) in enumerate(zip(steps, ys)):
        if h > 0:
            Phi, G, Qd = discrete_model(h)
            x = Phi @ x + G @ us[k - 1]
            P = Phi @ P @ Phi.T + Qd
        elif started:
            out.append((x.copy(), P.copy()))
            continue
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


def _irregular(seed):
    rng = np.random.default_rng(seed)
    steps = np.concatenate(([0.0], rng.integers(500, 2000, 99) * 1e-6))
    return steps, np.cumsum(steps), rng.normal(size=(100, 1)), rng.normal(scale=0.1, size=100)


def test_by_default_the_ekf_starts_from_the_first_measurement():
    """Issue 19 item 18: no explicit initial estimate, the first sample gives the state
    consistent with it (h = q: q = y, the unmeasured states 0) and a covariance saying so
    (R in q, P0 in the others); from there on the textbook Kalman filter from that start."""
    steps, t, us, ys = _irregular(5)
    f = ekf(**LINEAR, process_noise=Q.tolist(), measurement_noise=[R],
            initial_covariance=[1.0, 2.0, 3.0], max_step=1.0)
    f.reset(0.0)
    f.update(t[0], np.array([ys[0]]), us[0])
    x0, P0 = np.array([ys[0], 0.0, 0.0]), np.diag([R, 2.0, 3.0])
    assert np.array_equal(f.estimate, x0)
    assert np.allclose(f.covariance, P0, rtol=1e-12, atol=1e-18), f.covariance
    assert f.output_residual == 0.0
    ref = kalman(steps, ys, us, x0, P0, started=True)
    for k in range(1, 100):
        f.update(t[k], np.array([ys[k]]), us[k])
        x, P = ref[k]
        assert np.allclose(f.estimate, x, rtol=1e-9, atol=1e-12), (k, f.estimate, x)
        assert np.allclose(f.covariance, P, rtol=1e-7, atol=1e-15), k


def test_the_zero_start_and_an_explicit_estimate_are_kept():
    """``initial_state: zero`` is the old start (a correction from 0 with P0); an explicit
    initial estimate wins over the default."""
    steps, t, us, ys = _irregular(6)
    P0 = np.diag([1e-8, 2.0, 3.0])          # P0 << R: a correction stays off y
    for mode, x0 in (("zero", None), ("measurement", [0.3, -1.0, 0.5])):
        f = ekf(**LINEAR, process_noise=Q.tolist(), measurement_noise=[R],
                initial_covariance=np.diag(P0).tolist(), max_step=1.0, initial_state=mode)
        f.reset(0.0, x0)
        ref = kalman(steps, ys, us, np.zeros(3) if x0 is None else np.array(x0), P0)
        for k in range(100):
            f.update(t[k], np.array([ys[k]]), us[k])
            assert np.allclose(f.estimate, ref[k][0], rtol=1e-9, atol=1e-12), (mode, k)
        assert not np.isclose(ref[0][0][0], ys[0], rtol=0.1)    # the start differs from y


def test_a_nonlinear_output_is_solved_for_the_start():
    """h = q + 0.1 q^3: Gauss-Newton from 0 gives q with h(q) = y, P = R / h'(q)^2 in q."""
    f = ekf(states=["q", "w"], f=["w", "-q"], h=["q + 0.1*q**3"], process_noise=[0.0, 1.0],
            measurement_noise=[1e-4], initial_covariance=[1.0, 5.0])
    f.reset(0.0)
    f.update(0.0, np.array([2.0]), np.zeros(0))
    q, w = f.estimate
    assert q + 0.1 * q ** 3 == pytest.approx(2.0, abs=1e-12) and w == 0.0
    assert np.allclose(f.covariance, np.diag([1e-4 / (1 + 0.3 * q * q) ** 2, 5.0]), rtol=1e-10)


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
    f.update(0.0, np.array([0.5]), np.array([1.0]))      # the start, from this measurement
    assert f.innovation is None and math.isnan(f.nis)
    f.update(0.01, np.array([0.6]), np.array([1.0]))     # the first correction
    nu, S = f.innovation, f.innovation_covariance
    assert nu.shape == (1,) and S.shape == (1, 1)
    assert f.nis == pytest.approx(float(nu @ np.linalg.solve(S, nu)))
    assert f.health == f.nis and f.output_residual == pytest.approx(abs(nu[0]))
    assert "NIS mean since reset" in f.diagnostics()


# -- the compiled kernel against the numpy path and scipy ------------------------------------
from fto_ros.core import jit as J  # noqa: E402

COMPILED = pytest.mark.skipif(not J.ENABLED, reason="compares the compiled kernels with the "
                              "numpy path, and numba is off (FTO_ROS_NUMBA=0)")


def _family_pairs():
    """Every committed config of the ekf (and of track, whose tracker is one) with the first
    bag the reference runs it on."""
    import reference_runs as RR
    pairs, seen = [], set()
    for p in RR.load_reference()[1]["pairs"]:
        name = p["params"][-1]
        if name.endswith("_ekf.yaml") or name.endswith("acquire_track.yaml"):
            if name not in seen:
                seen.add(name)
                pairs.append([p["bag"], p["params"]])
    return pairs


@COMPILED
@pytest.mark.slow
def test_compiled_and_numpy_paths_agree_on_the_committed_configs(tmp_path):
    """The first 3000 messages of each pair, compiled here and on the numpy path in a
    subprocess: the same statuses; estimates within 1e-12 of each state's scale; the output
    residual y - h(x) within 1e-12 of the measurement's scale (it is a difference of numbers
    of that size); the NIS nu' S^-1 nu within 1e-12 relative, widened by the residual's
    conditioning (NIS ~ nu^2: a relative error of 2 * 1e-12 max|y| / |nu| where nu is near
    the rounding of y).  Measured: estimates <= 1.1e-13, residuals <= 1.0e-13 of scale, NIS
    <= 1.4e-12 relative (possieri_example, fld_example2); the compiled expm, core.linalg's
    products and solve order the sums differently from scipy's and BLAS."""
    import path_runs as PR
    pairs = _family_pairs()
    assert len(pairs) >= 11
    compiled = PR.run_pairs(pairs, 3000)
    numpy_path = PR.numpy_path(pairs, 3000, tmp_path)
    for i, (bag, params) in enumerate(pairs):
        what = f"{params[-1]} on {bag}"
        status = compiled[f"{i}_status"]
        np.testing.assert_array_equal(status, numpy_path[f"{i}_status"], err_msg=what)
        out = status == 0
        assert out.sum() > 500, what
        est, ref = compiled[f"{i}_est"][out], numpy_path[f"{i}_est"][out]
        scale = np.maximum(1.0, np.abs(ref).max(axis=0))
        assert np.max(np.abs(est - ref) / scale) <= 1e-12, what
        conv, cref = compiled[f"{i}_conv"][out], numpy_path[f"{i}_conv"][out]
        res, nis = 1, 4                             # runner.CONVERGENCE_FIELDS
        np.testing.assert_array_equal(np.delete(conv, [res, nis], axis=1),
                                      np.delete(cref, [res, nis], axis=1), err_msg=what)
        ymax = max(1.0, _measurement_scale(bag, params))
        assert np.max(np.abs(conv[:, res] - cref[:, res])) <= 1e-12 * ymax, what
        widen = 1.0 + 2.0 * ymax / np.maximum(np.abs(cref[:, res]), 1e-300)
        tol = 1e-12 * np.maximum(1.0, np.abs(cref[:, nis])) * widen
        assert np.all(np.abs(conv[:, nis] - cref[:, nis]) <= tol), what


def _measurement_scale(bag, params) -> float:
    import path_runs as PR
    from fto_ros.runner import Runner, loop as L
    from fto_ros.runner.params_file import load_params_files
    r = Runner(load_params_files([str(PR.ROOT / p) for p in params]))
    kind, _, values = PR._events(PR.ROOT / "bags" / bag, r, 3000)
    return float(np.abs(values[kind == L.MEASUREMENT]).max())


def _van_loan(rng, n, scale, dt):
    A = rng.normal(size=(n, n)) * scale
    M = np.zeros((2 * n + 1, 2 * n + 1))
    M[0, n + 1:] = rng.normal(size=n)
    M[1:n + 1, 1:n + 1] = -A
    M[1:n + 1, n + 1:] = np.diag(rng.uniform(0.0, 1.0, n))
    M[n + 1:, n + 1:] = A.T
    return M * dt


@COMPILED
@pytest.mark.parametrize("kind", ["van_loan", "general", "large_norm", "upper", "lower",
                                  "diagonal", "blas_sized"])
def test_compiled_expm_is_accurate(kind):
    """core.linalg.expm (compiled, scipy's algorithm) against e^M to 50 digits (mpmath): the
    EKF's Van Loan matrices, general ones, norms that need scaling and squaring (Pade 13),
    the triangular cases (exact diagonal and superdiagonal), a diagonal one and one large
    enough for BLAS.  Measured: <= 5.2e-14 of the largest entry (large norms; scipy's own
    expm: 9.7e-12 there, 2.7e-13 on the triangular ones), 2.1e-16 on the Van Loan ones."""
    import mpmath
    from fto_ros.core.linalg import expm as compiled_expm
    rng = np.random.default_rng(7)
    bar = {"van_loan": 1e-15, "general": 1e-14}.get(kind, 1e-13)
    for _ in range(12):
        n = int(rng.integers(2, 8))
        if kind == "van_loan":
            M = _van_loan(rng, n, 100.0, 1e-3)
        elif kind == "general":
            M = rng.normal(size=(n, n))
        elif kind == "large_norm":
            M = rng.normal(size=(n, n)) * 30.0
        elif kind == "upper":
            M = np.triu(rng.normal(size=(n, n)) * 8.0)
        elif kind == "lower":
            M = np.tril(rng.normal(size=(n, n)) * 8.0)
        elif kind == "diagonal":
            M = np.diag(rng.normal(size=n))
        else:
            M = rng.normal(size=(20, 20)) * 0.5
        with mpmath.workdps(50):
            exact = np.array(mpmath.expm(mpmath.matrix(M.tolist())).tolist(), dtype=float)
        err = np.max(np.abs(compiled_expm(M) - exact)) / np.max(np.abs(exact))
        assert err <= bar, (kind, n, err)
    assert np.all(np.isnan(compiled_expm(np.array([[np.inf, 0.0], [0.0, 1.0]]))))
