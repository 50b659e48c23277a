"""joint_kalman, the model-free joint velocity baseline (docs/joint_kalman.md): the closed-form
exact step against a matrix exponential, the running filter against the steady state of the
Riccati equation, the bandwidth relation (the running filter's response to a sine is
-3 dB at the stated bandwidth), variable steps against a naive filter written from the
equations (expm and Van Loan per step, Joseph form), the NIS, refusals, a rejected sample
leaving no trace, and the numpy path against the compiled kernel."""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import expm

from fto_ros.core.errors import ConfigError
from fto_ros.observers import REGISTRY
from fto_ros.observers.base import SampleRejected
from fto_ros.observers.joint_kalman import JointKalmanFilter
from fto_ros.observers.joint_kalman import design as D
from fto_ros.observers.joint_kalman.adapter import DEFAULT_P0

ROOT = Path(__file__).resolve().parents[3]
R_ENC = 1e-10 + 2.0 ** -36 / 12


def cfg(**kw):
    base = dict(n_outputs=1, order=3, bandwidth=[40.0], encoder_noise=[1e-5],
                resolution=[2.0 ** -18], sample_period=1e-3, initial_covariance=[],
                initial_state="measurement", state_names=[])
    base.update(kw)
    return base


def run(obs, t, y):
    obs.reset()
    x = np.zeros((t.size, obs.n_states))
    for k in range(t.size):
        obs.update_checked(float(t[k]), np.atleast_1d(y[k]).astype(float), np.zeros(0))
        x[k] = obs.estimate
    return x


def naive_step(r, h, qc):
    """F = expm(A h) and Q by Van Loan (1978): expm([[-A, G qc G'], [0, A']] h)."""
    A = np.diag(np.ones(r - 1), 1)
    G = np.zeros((r, 1))
    G[-1, 0] = 1.0
    M = np.block([[-A, qc * G @ G.T], [np.zeros((r, r)), A.T]]) * h
    E = expm(M)
    F = E[r:, r:].T
    return expm(A * h), F @ E[:r, r:]


def naive_filter(t, y, r, qc, R, P0):
    """The filter from the equations: a new expm per step, the Joseph form."""
    x = np.zeros(r)
    x[0] = y[0]
    P = P0.copy()
    P[0, :] = P[:, 0] = 0.0
    P[0, 0] = R
    X, Ps = [x.copy()], [P.copy()]
    H = np.eye(r)[:1]
    for k in range(1, t.size):
        F, Q = naive_step(r, t[k] - t[k - 1], qc)
        x, P = F @ x, F @ P @ F.T + Q
        S = (H @ P @ H.T)[0, 0] + R
        K = (P @ H.T)[:, 0] / S
        x = x + K * (y[k] - x[0])
        L = np.eye(r) - np.outer(K, H[0])
        P = L @ P @ L.T + R * np.outer(K, K)
        X.append(x.copy())
        Ps.append(P.copy())
    return np.array(X), np.array(Ps)


def jittered(n, h=1e-3, jitter=50e-6, seed=0):
    rng = np.random.default_rng(seed)
    return np.round((1.0 + np.arange(n) * h + rng.uniform(-jitter, jitter, n)) * 1e6) / 1e6


def test_registered_and_described():
    assert REGISTRY["joint_kalman"] is JointKalmanFilter
    obs = JointKalmanFilter(cfg())
    assert obs.state_names == ["q", "q_dot", "q_ddot"] and obs.n_inputs == 0
    assert math.isinf(obs.guaranteed_time) and "NIS" in obs.HEALTH_NAME
    d = obs.diagnostics()
    assert d["bandwidth (Hz)"] == "40" and "NIS mean since reset" in d


def exact_step(r, h, qc):
    """F and Q by Van Loan's exponential in 60 digits (mpmath): the reference for entries
    down to h^(2r-1) qc, where a float exponential of the block matrix loses them."""
    import mpmath
    with mpmath.workdps(60):
        n = 2 * r
        M = mpmath.zeros(n, n)
        for i in range(r - 1):
            M[i, i + 1] = -h                  # -A h
            M[r + i + 1, r + i] = h           # A' h
        M[r - 1, n - 1] = qc * h              # G qc G' h
        E = mpmath.expm(M)
        F = np.array([[float(E[r + j, r + i]) for j in range(r)] for i in range(r)])
        Q = np.array([[float(sum(E[r + k, r + i] * E[k, r + j] for k in range(r)))
                       for j in range(r)] for i in range(r)])
    return F, Q


@pytest.mark.parametrize("r", D.ORDERS)
@pytest.mark.parametrize("h", [1e-6, 1e-3, 0.0137, 0.5])
def test_closed_form_step_is_the_matrix_exponential(r, h):
    F, Q = D.chain_step(r, h, 2.7)
    Fn, Qn = exact_step(r, h, 2.7)
    assert np.allclose(F, Fn, rtol=1e-14, atol=0)
    assert np.allclose(Q, Qn, rtol=1e-13, atol=0)


@pytest.mark.parametrize("r", D.ORDERS)
def test_running_filter_reaches_the_riccati_steady_state(r):
    """A fixed rate: the kernel's covariance after 4000 steps is the DARE's posterior."""
    obs = JointKalmanFilter(cfg(order=r, bandwidth=[25.0]))
    t = 1.0 + np.arange(4000) * 1e-3
    run(obs, t, np.zeros(t.size))
    Pp, K = D.steady_state(r, 1e-3, obs.intensity[0], obs.variance[0])
    L = np.eye(r) - np.outer(K, np.eye(r)[0])
    post = L @ Pp @ L.T + obs.variance[0] * np.outer(K, K)
    assert np.allclose(obs.covariance, post, rtol=1e-8, atol=0), (obs.covariance, post)
    assert np.allclose(obs.steady_state_std()[0], np.sqrt(np.diag(post)), rtol=1e-8)


@pytest.mark.parametrize("r,f", [(2, 10.0), (3, 40.0), (3, 150.0), (4, 80.0)])
def test_bandwidth_is_the_minus_3db_of_the_running_filter(r, f):
    """y = sin(2 pi f t) at the nominal rate, no noise: the position estimate's amplitude
    after the transient is 1/sqrt(2) (the bandwidth's definition), through the kernel."""
    obs = JointKalmanFilter(cfg(order=r, bandwidth=[f]))
    t = 1.0 + np.arange(3000) * 1e-3
    x = run(obs, t, np.sin(2 * math.pi * f * (t - 1.0)))
    tail = slice(1000, None)
    w = 2 * math.pi * f * (t[tail] - 1.0)
    basis = np.column_stack([np.sin(w), np.cos(w)])
    amp = np.hypot(*np.linalg.lstsq(basis, x[tail, 0], rcond=None)[0])
    assert abs(amp - 2 ** -0.5) < 1e-4, amp


@pytest.mark.parametrize("r", D.ORDERS)
def test_closed_form_relation_in_the_continuous_limit(r):
    """qc = R h0 (2 pi f / c_r)^(2r) within 1 % at f h0 = 1e-3 (mu - 1 < 0.01), and the
    solved intensity gives exactly the bandwidth."""
    R, h0, f = R_ENC, 1e-3, 1.0
    qc = D.process_intensity(r, f, R, h0)
    assert abs(qc / D.closed_form_intensity(r, f, R, h0) - 1) < 0.01
    assert abs(D.minus3db(r, h0, qc, R) / f - 1) < 1e-8
    assert D.C_R[r] == pytest.approx({2: 2.0581710, 3: 2.8311772, 4: 3.6548357}[r], rel=1e-7)


@pytest.mark.parametrize("r", D.ORDERS)
def test_variable_steps_match_the_naive_filter(r):
    """Jittered instants (+-50 us) and a lost message: every estimate and covariance as the
    naive filter's (expm per step), to 1e-9 of its scale."""
    t = jittered(1500, seed=r)
    t = np.delete(t, [300, 301, 700])
    rng = np.random.default_rng(r)
    y = 0.3 * np.sin(3 * (t - 1)) + 1e-5 * rng.standard_normal(t.size)
    obs = JointKalmanFilter(cfg(order=r))
    x = run(obs, t, y)
    P0 = np.diag(DEFAULT_P0[:r])
    X, Ps = naive_filter(t, y, r, obs.intensity[0], obs.variance[0], P0)
    scale = np.max(np.abs(X), axis=0)
    assert np.all(np.abs(x - X) <= 1e-9 * scale), np.max(np.abs(x - X) / scale, axis=0)
    assert np.allclose(obs.covariance, Ps[-1], rtol=1e-7, atol=0)


def test_nis_is_consistent_with_the_right_noise():
    """A white-jerk chain simulated exactly at jittered instants, the filter with its true
    intensity and variance: mean NIS 1 +- 0.05; with R 100 times too small, > 5."""
    r, qc, sigma = 3, 50.0, 1e-5
    t = jittered(20000, seed=7)
    rng = np.random.default_rng(7)
    x = np.array([0.0, 1.0, 0.0])
    ys = []
    for k in range(t.size):
        if k:
            F, Q = D.chain_step(r, t[k] - t[k - 1], qc)
            x = F @ x + np.linalg.cholesky(Q) @ rng.standard_normal(r)
        ys.append(x[0] + sigma * rng.standard_normal())
    y = np.array(ys)
    for R, lo, hi in ((sigma ** 2, 0.95, 1.05), (sigma ** 2 / 100, 5.0, np.inf)):
        f = D.minus3db(r, 1e-3, qc, R)               # the bandwidth of the process's qc
        obs = JointKalmanFilter(cfg(bandwidth=[f], encoder_noise=[math.sqrt(R)],
                                    resolution=[0.0]))
        assert obs.intensity[0] == pytest.approx(qc, rel=1e-8)
        run(obs, t, y)
        assert lo < obs.nis_mean < hi, (R, obs.nis_mean)


def test_rejected_sample_leaves_no_trace():
    obs = JointKalmanFilter(cfg())
    t = jittered(50)
    run(obs, t, np.zeros(t.size))
    before = obs._st.copy()
    with pytest.raises(SampleRejected, match="non_finite_estimate"):
        obs.update_checked(t[-1] + 1e-3, np.array([1e300]), np.zeros(0))
    assert np.array_equal(obs._st, before)
    obs.update_checked(t[-1] + 1e-3, np.array([0.0]), np.zeros(0))
    assert np.all(np.isfinite(obs.estimate))


@pytest.mark.parametrize("change, parameter", [
    (dict(bandwidth=[400.0]), "joint_kalman.bandwidth"),     # beyond 0.3 of the rate
    (dict(bandwidth=[1.0, 2.0]), "joint_kalman.bandwidth"),  # 2 values for 1 output
    (dict(encoder_noise=[0.0], resolution=[0.0]), "joint_kalman.encoder_noise"),
    (dict(initial_covariance=[1.0, -1.0, 1.0]), "joint_kalman.initial_covariance"),
    (dict(initial_covariance=[1.0, 1.0]), "joint_kalman.initial_covariance"),
    (dict(state_names=["a"]), "joint_kalman.state_names"),
])
def test_refusals_name_the_parameter(change, parameter):
    with pytest.raises(ConfigError) as err:
        JointKalmanFilter(cfg(**change))
    assert err.value.parameter == parameter


def test_outputs_are_independent_chains():
    """Two outputs: each chain is the one-output filter of its own values."""
    t = jittered(400)
    y = np.column_stack([np.sin(t), 0.1 * np.cos(2 * t)])
    two = JointKalmanFilter(cfg(n_outputs=2, bandwidth=[20.0, 60.0], encoder_noise=[1e-5]))
    assert two.state_names[:4] == ["q0", "q0_dot", "q0_ddot", "q1"]
    x2 = run(two, t, y)
    for c, f in enumerate((20.0, 60.0)):
        x1 = run(JointKalmanFilter(cfg(bandwidth=[f])), t, y[:, c])
        assert np.array_equal(x2[:, 3 * c:3 * c + 3], x1)


_NUMPY_PATH = """
import sys, numpy as np
sys.path.insert(0, {test!r})
from test_joint_kalman import cfg, run, jittered
from fto_ros.observers.joint_kalman import JointKalmanFilter
t = jittered(800)
y = np.sin(2 * (t - 1)) + 1e-5 * np.random.default_rng(3).standard_normal(t.size)
np.save({out!r}, run(JointKalmanFilter(cfg()), t, y))
"""


def test_numpy_path_equals_the_compiled_kernel(tmp_path):
    from fto_ros.core import jit
    if not jit.ENABLED:
        pytest.skip("numba is off in this run: the compiled side cannot be compared")
    out = tmp_path / "numpy.npy"
    env = dict(os.environ, FTO_ROS_NUMBA="0")
    code = _NUMPY_PATH.format(test=str(Path(__file__).parent), out=str(out))
    subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=ROOT, timeout=600)
    t = jittered(800)
    y = np.sin(2 * (t - 1)) + 1e-5 * np.random.default_rng(3).standard_normal(t.size)
    compiled = run(JointKalmanFilter(cfg()), t, y)
    assert np.allclose(np.load(out), compiled, rtol=1e-13, atol=0)
