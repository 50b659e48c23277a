"""single_delay (Mazenc & Malisoff 2022): the paper's DC-motor example and Theorem 1/2 claims.

Theorem 1 says xi1(t) = xi_e(t) exactly for every t >= tau, whatever the initial
conditions and for any tau > 0.  Sampled at h, the only approximation left is the
first-order hold of Y between samples, so the tests check: the error after tau
is at discretisation level (and O(h^2): halving h divides it by ~4), it is large
before tau (the check can fail), the same holds for other tau, for random initial
conditions and for irregular sampling.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate
from fto_ros.core.params import resolve
from fto_ros.observers.base import SampleRejected
from fto_ros.observers.single_delay import SingleDelayObserver, design
from fto_ros.runner import Runner, load_params_file

CONFIG = "test/data/dc_motor_explicit/dc_motor_single_delay.yaml"


def dc_cfg(**over):
    flat = load_params_file(CONFIG)
    vals = {k[len("single_delay."):]: v for k, v in flat.items() if k.startswith("single_delay.")}
    vals.update(over)
    return resolve(SingleDelayObserver.PARAMS, vals, prefix="single_delay.")


def run_dc(obs, h=1e-3, T=0.6, x0=dc_motor.DEFAULT_X0, jitter=0.0, seed=0, x0_hat=None,
           noise=0.0, uncertainty=False):
    """Simulate the motor (ZOH voltage at the sample instants) and run the observer.

    Returns (t, estimates, truth)."""
    rng = np.random.default_rng(seed)
    n = int(round(T / h))
    t = np.arange(n + 1) * h
    if jitter:
        t[1:-1] += rng.uniform(-jitter, jitter, n - 1) * h
    sim = simulate(dc_motor.make_rhs(), x0, t, dc_motor.default_voltage,
                   delta1=dc_motor.uncertainty if uncertainty else None)
    q = sim.x[:, 0] + (rng.normal(0, noise, len(t)) if noise else 0.0)
    obs.reset(t[0], x0_hat)
    est = []
    for k in range(len(t)):
        obs.update(t[k], np.array([q[k]]), sim.u[k])
        est.append(obs.estimate.copy())
    return t, np.array(est), sim.x


def max_err_after(t, est, truth, t_from, cols=(1, 2)):
    m = t >= t_from - 1e-12
    return np.abs(est[m][:, cols] - truth[m][:, cols]).max(axis=0)


# -- the paper's example ---------------------------------------------------------------
def test_paper_dc_motor_exact_after_tau():
    """Section V: b0=40, b1=15, a1=35, a2=1, a3=36.4, a4=200, k=100, tau=0.1, 1 kHz."""
    obs = SingleDelayObserver(dc_cfg())
    t, est, x = run_dc(obs)
    before = max_err_after(t, est, x, 0.0)
    after = max_err_after(t, est, x, 0.1 + 0.01)
    # the bar is 1e-3 after tau + 10 ms; the hold of Y leaves ~1e-4
    assert np.all(after < 2e-4), after
    # not trivially small: before tau the open-loop copy is far off
    assert before[0] > 0.5
    # q itself is measured: exact
    assert np.abs(est[:, 0] - x[:, 0]).max() < 1e-12


def test_error_is_second_order_in_the_sampling_step():
    errs = []
    for h in (2e-3, 1e-3, 5e-4):
        obs = SingleDelayObserver(dc_cfg())
        t, est, x = run_dc(obs, h=h, T=0.4)
        errs.append(max_err_after(t, est, x, 0.11).max())
    r1, r2 = errs[0] / errs[1], errs[1] / errs[2]
    assert 3.0 < r1 < 5.0 and 3.0 < r2 < 5.0, (errs, r1, r2)


@pytest.mark.parametrize("tau, k", [(0.02, 100.0), (0.05, 100.0), (0.2, 200.0), (1.0, 200.0)])
def test_any_tau_gives_exact_estimates_after_tau(tau, k):
    """Any tau > 0 (Remark 1).  For long tau, k = 100 leaves A1 + kI an eigenvalue of
    -97: lambda(r) then grows like e^{97 |r|} and S is ill-conditioned (1.5e13 at
    tau = 0.2, refused); k = 200 > 197.2 makes every mode of lambda decay."""
    obs = SingleDelayObserver(dc_cfg(tau=tau, k=k))
    t, est, x = run_dc(obs, T=tau + 0.3)
    assert np.all(max_err_after(t, est, x, tau + 1e-3) < 5e-4)
    assert obs.guaranteed_time == tau


@pytest.mark.parametrize("seed", range(4))
def test_exact_for_random_initial_conditions(seed):
    """Fixed time: tau does not depend on the initial error."""
    rng = np.random.default_rng(100 + seed)
    x0 = rng.uniform(-5, 5, 3) * np.array([1, 10, 5])
    x0_hat = rng.uniform(-50, 50, 3)
    obs = SingleDelayObserver(dc_cfg())
    t, est, x = run_dc(obs, x0=x0, x0_hat=x0_hat, T=0.3)
    init = np.abs(x0_hat[1:] - x0[1:])
    assert np.all(max_err_after(t, est, x, 0.101) < 1e-3 + 1e-5 * init)


def test_irregular_sampling():
    obs = SingleDelayObserver(dc_cfg())
    t, est, x = run_dc(obs, jitter=0.4, seed=3)
    assert np.all(np.diff(t) > 0)
    assert np.all(max_err_after(t, est, x, 0.11) < 3e-4)


def test_noise_bound_and_reported_gain():
    """With measurement noise the error stays bounded; the reported linear noise gain
    bounds what the measurement noise does (model terms add the K1 part)."""
    obs = SingleDelayObserver(dc_cfg())
    sigma = 1e-4
    t, est, x = run_dc(obs, noise=sigma, seed=5, T=1.0)
    err = max_err_after(t, est, x, 0.11)
    gain = obs.design["noise_gain"]
    assert 10 < gain < 1e4
    # noise samples are bounded by ~4.5 sigma here; allow the F1 term (K1 = 35) on top
    assert err.max() < 5 * gain * sigma
    assert err.max() > 1e-4  # the noise does show (the test is not vacuous)


def test_sampled_form_converges_on_sparse_irregular_samples():
    """Theorem 2 (eq. 39): q only every 1-2 ms; predictor omega in between."""
    obs = SingleDelayObserver(dc_cfg(measurement="sampled", substep=5e-4, max_sample_interval=2e-3))
    h = 1e-3
    T = 1.0
    tu = np.arange(int(T / h) + 1) * h
    rng = np.random.default_rng(7)
    ty = [0.0]
    while ty[-1] < T - 2e-3:
        ty.append(ty[-1] + rng.uniform(1e-3, 2e-3))
    ty = np.array(ty)
    grid = np.union1d(tu, ty)
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, grid, dc_motor.default_voltage, t_input=tu)
    obs.reset(0.0)
    errs = []
    iy = set(np.searchsorted(grid, ty).tolist())
    for k, tk in enumerate(grid):
        if k in iy:
            obs.update(tk, sim.x[k, :1], dc_motor.default_voltage(tk))
            errs.append((tk, *np.abs(obs.estimate - sim.x[k])))
        else:
            obs.advance(tk, dc_motor.default_voltage(tk))
    errs = np.array(errs)
    late = errs[errs[:, 0] > 0.3]
    assert late[:, 2].max() < 0.02 and late[:, 3].max() < 0.02, late[:, 2:].max(axis=0)
    diag = obs.diagnostics()
    assert "Theorem 2 mu" in diag and "NOT met" in diag["Theorem 2 condition T_bar mu < 1"]


# -- design quantities ------------------------------------------------------------------
def test_gramian_matches_closed_form():
    """S = int_{-tau}^0 lambda^T lambda: compare the quadrature with a fine trapezoid rule
    and check symmetry, positive definiteness and lambda's closed form derivative."""
    A1, A2 = dc_motor.single_delay_split()
    k, tau = 100.0, 0.1
    d = design(A1, A2, k, tau)
    from scipy.linalg import expm
    Ak = A1 + k * np.eye(2)
    G = A2 @ np.linalg.inv(Ak)
    m = np.linspace(-tau, 0, 20001)
    lam = np.array([G @ (np.eye(2) - expm(Ak * s)) for s in m])
    trapezoid = getattr(np, "trapezoid", None) or np.trapz   # numpy 1.x (ROS Jazzy on Ubuntu 24.04)
    S_ref = trapezoid(np.einsum("kqi,kqj->kij", lam, lam), m, axis=0)
    assert np.allclose(d["S"], S_ref, rtol=1e-6, atol=0)
    assert np.allclose(d["S"], d["S"].T)
    assert np.all(np.linalg.eigvalsh(d["S"]) > 0)
    assert d["cond_S"] == pytest.approx(np.linalg.cond(S_ref), rel=1e-4)
    assert np.allclose(d["H"], np.linalg.inv(Ak).T @ A2.T)


def test_theorem2_condition_is_reported_with_mu():
    obs = SingleDelayObserver(dc_cfg(measurement="sampled", max_sample_interval=1e-3))
    assert obs.mu > obs.k + obs.K2  # (41): mu = |A2| q1 + k + K2 with q1 > 0
    assert math.isfinite(obs.mu)


# -- configuration errors name the parameter --------------------------------------------
@pytest.mark.parametrize("over, param, words", [
    (dict(A2=[0.0, 0.0]), "single_delay.A2", "not observable"),
    (dict(tau=0.0), "single_delay.tau", "> 0"),
    (dict(tau=0.5), "single_delay.tau", "numerically singular"),
    (dict(k=75.0), "single_delay.k", "unstable"),
    (dict(A1=[-1.0, 15.0, -36.4]), "single_delay.A1", "2x2"),
    (dict(F1=["-35*sin(y0)"]), "single_delay.F1", "expected 2"),
    (dict(F1=["-35*sin(q)", "40*u0"]), "single_delay.F1[0]", "unknown name"),
    (dict(state_map=[0.0] * 9), "single_delay.state_map", "invertible"),
])
def test_bad_configuration_is_refused_with_a_clear_message(over, param, words):
    with pytest.raises(ConfigError) as exc:
        SingleDelayObserver(dc_cfg(**over))
    assert exc.value.parameter == param
    assert words in str(exc.value)


def test_singular_A1_plus_kI_is_refused():
    # A1 = diag(-3, -5) with A2 = [1, 1] is observable; k = 3 makes A1 + kI singular
    cfg = dc_cfg(A1=[-3.0, 0.0, 0.0, -5.0], A2=[1.0, 1.0], k=3.0, allow_unstable_internal=True)
    with pytest.raises(ConfigError, match="A1 \\+ k I is singular"):
        SingleDelayObserver(cfg)


def test_unstable_internal_mode_allowed_on_request():
    obs = SingleDelayObserver(dc_cfg(k=75.0, allow_unstable_internal=True))
    assert obs.max_internal_rate > 0
    t, est, x = run_dc(obs, T=0.3)
    assert np.all(max_err_after(t, est, x, 0.11) < 5e-4)   # still exact on a short run


# -- bad samples never corrupt the state --------------------------------------------------
def test_non_finite_model_term_rejected_and_state_kept():
    cfg = dc_cfg(F1=["-35*sin(y0) + 1e-12*log(y0 + 10)", "40*u0"])
    obs = SingleDelayObserver(cfg)
    ref = SingleDelayObserver(dc_cfg())
    t, _, x = run_dc(ref, T=0.2)
    obs.reset(0.0)
    for k in range(len(t)):
        obs.update(t[k], x[k, :1], dc_motor.default_voltage(t[k]))
        if k == 150:
            before = obs.estimate.copy()
            with pytest.raises(SampleRejected) as exc:
                obs.update(t[k] + 0.5e-3, np.array([-20.0]), dc_motor.default_voltage(t[k]))
            assert exc.value.reason == "non_finite_model_term"
            assert np.array_equal(obs.estimate, before)
    assert np.allclose(obs.estimate, ref.estimate, atol=1e-12)


def test_runner_with_paper_config_reports_design_figures():
    r = Runner(load_params_file(CONFIG))
    diag = r.observer.diagnostics()
    assert float(diag["cond(S)"]) == pytest.approx(1.408e5, rel=1e-2)
    assert float(diag["tau (guaranteed convergence time, s)"]) == 0.1
    assert "noise gain |R| + int|S^-1 (e^-kr - e^-(A1'+2k)r) H| dr" in diag


# -- the delay ring's fixed capacity ------------------------------------------------------------
def _windowed(entries: int):
    """The continuous form with a delay ring that keeps ``entries`` per window whole."""
    return type(f"Window{entries}", (SingleDelayObserver,), {"WINDOW_ENTRIES": entries})


def _run_checked(obs, t, y, u):
    obs.reset(t[0])
    est, entries = [], 0
    for k in range(len(t)):
        obs.update_checked(t[k], y[k], u[k])
        est.append(obs.estimate.copy())
        entries = max(entries, obs.delay_entries)
    return np.array(est), entries


def test_a_stream_faster_than_the_ring_stays_exact_to_the_interpolation_order():
    """10 kHz, tau = 0.1 s: 1000 entries per window.  Rings that keep 64 and 128 entries
    whole thin the stream to tau / 64 and tau / 128 apart: the estimate then differs from
    the unthinned one (the default ring keeps 4096) by the Hermite error of the delayed
    term, fourth order in the spacing (halving it: / 16), far below the observer's own
    error (the hold of y: 6e-7 here), with the memory fixed."""
    h = 1e-4
    t = np.arange(3001) * h
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage)
    y, u = sim.x[:, :1].copy(), sim.u.copy()
    late = t >= 0.101
    ref, n_ref = _run_checked(SingleDelayObserver(dc_cfg()), t, y, u)
    assert n_ref > 1000                                      # the whole window is kept
    own = np.abs(ref[late] - sim.x[late]).max()
    diffs = []
    for entries in (64, 128):
        est, n = _run_checked(_windowed(entries)(dc_cfg()), t, y, u)
        assert n <= 2 * entries + 3                          # thinned: fixed memory
        diffs.append(np.abs(est[late] - ref[late]).max())
    assert 1e-14 < diffs[1] < diffs[0] < 1e-4 * own, (diffs, own)
    assert 10.0 <= diffs[0] / diffs[1] <= 22.0, diffs


def test_the_default_ring_thins_a_very_fast_stream_without_changing_the_estimate():
    """A 10 us stream gives 10000 entries per tau = 0.1 s window: the default ring (4096
    whole) thins it to 24 us apart; a ring that keeps everything gives the same estimate to
    round-off."""
    t = np.arange(15001) * 1e-5
    y = (0.5 + 0.3 * np.sin(7 * t))[:, None]
    u = (2.0 + np.sin(3 * t))[:, None]
    thinned, n = _run_checked(SingleDelayObserver(dc_cfg()), t, y, u)
    whole, n_whole = _run_checked(_windowed(16384)(dc_cfg()), t, y, u)
    assert n <= 2 * 4096 + 3 < n_whole
    late = t >= 0.101
    scale = np.abs(whole[late]).max(axis=0)
    err = (np.abs(thinned[late] - whole[late]).max(axis=0) / scale).max()
    assert err < 1e-12, err
