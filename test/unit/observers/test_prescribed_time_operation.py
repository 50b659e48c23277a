"""prescribed_time (Holloway & Krstic 2019) in continuous operation: window after window in
the restart mode (also at window ends between samples), the stop and constant modes after
the window, the sampling limit for high orders, resets, a rejected sample leaving the state
untouched, the runner's health and guaranteed time; the models and example configs."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.models import MODELS
from fto_ros.models.canonical_form import (DOUBLE_INTEGRATOR, THIRD_ORDER, CanonicalPlant,
                                           example1_input)
from fto_ros.models.simulate import simulate, uniform_grid
from fto_ros.observers.base import SampleRejected
from fto_ros.runner import Runner, load_params_file
from prescribed_time_cases import DI_CONFIG, TO_CONFIG, grid, make, simulate_zoh


# ---------------------------------------------------------------- continuous operation
def _di_stream(T_end, h=1e-3):
    t = grid(T_end, h)
    u = np.sin(10 * t) + np.cos(t)
    return t, u, simulate_zoh(DOUBLE_INTEGRATOR, (20.0, 1.0), t, u)


def test_restart_mode_runs_window_after_window_without_error_growth():
    """mode restart (default): a new window every T, from the (exact) estimate; the error
    after the first T stays at rounding level for the next windows."""
    t, u, X = _di_stream(21.0)
    obs = make()
    obs.reset(0.0)
    errs = []
    for k in range(len(t)):
        obs.update(t[k], X[k, :1], np.array([u[k]]))
        errs.append(np.abs(X[k] - obs.estimate).max())
    errs = np.array(errs)
    assert obs.restarts == 4 and obs.restarts_total == 4
    assert obs.window_start == pytest.approx(20.0)
    for w in range(1, 4):                       # windows 2, 3, 4: no growth
        sel = (t >= 5.0 * w) & (t < 5.0 * (w + 1))
        assert errs[sel].max() < 1e-9, (w, errs[sel].max())
    d = obs.diagnostics()
    for key in ("mode", "time to T (s)", "largest gain now", "gamma_i = g_i (y - x_hat_1)",
                "restarts (since reset)", "restarts (total)", "largest |gamma_i| (health)"):
        assert key in d, key
    assert d["mode"] == "restart" and d["restarts (total)"] == "4"
    assert float(d["time to T (s)"]) == pytest.approx(4.0, abs=1e-9)
    assert obs.guaranteed_time == 5.0
    assert obs.health == pytest.approx(np.abs(obs.injections).max())


def test_restart_at_window_ends_between_samples():
    """T = 0.4567 s: the window ends fall between samples; the step splits there exactly."""
    t, u, X = _di_stream(3.0)
    obs = make(T=0.4567)
    obs.reset(0.0)
    errs = []
    for k in range(len(t)):
        obs.update(t[k], X[k, :1], np.array([u[k]]))
        errs.append(np.abs(X[k] - obs.estimate).max())
    assert obs.restarts == int(3.0 // 0.4567)
    assert max(errs[int(0.4567 / 1e-3) + 1:]) < 1e-9


def test_stop_mode_turns_the_injections_off():
    """mode stop with g_max (the paper's Section II-A): after t_stop the observer is the
    open-loop model; the error grows only as e^(A (t - t_stop)) x~(t_stop) (nilpotent A)."""
    t, u, X = _di_stream(8.0)
    obs = make(mode="stop", g_max=1e4)
    s_end = obs.s_end
    assert obs.end_reason == "g_max" and s_end < 5.0
    assert np.abs(obs.gains_at(5.0 / (5.0 - s_end))).max() == pytest.approx(1e4, rel=1e-9)
    obs.reset(0.0)
    err_end = None
    for k in range(len(t)):
        obs.update(t[k], X[k, :1], np.array([u[k]]))
        if err_end is None and obs.after_window:
            err_end = (t[k], X[k] - obs.estimate)
    assert np.all(obs.gains == 0.0) and obs.health == 0.0
    assert obs.diagnostics()["time to T (s)"] == "passed"
    tk, e = err_end
    predicted = np.array([e[0] + e[1] * (t[-1] - tk), e[1]])     # e^(A s) e
    assert np.allclose(X[-1] - obs.estimate, predicted, rtol=1e-6, atol=1e-12)


def test_constant_mode_freezes_the_gains():
    t, u, X = _di_stream(10.0)
    obs = make(mode="constant", t_stop=4.5)
    g_end = obs.gains_at(5.0 / 0.5).copy()
    obs.reset(0.0)
    errs = []
    for k in range(len(t)):
        obs.update(t[k], X[k, :1], np.array([u[k]]))
        errs.append(np.abs(X[k] - obs.estimate).max())
    assert obs.after_window and np.allclose(obs.gains, g_end)
    # from 4.5 s on a constant high-gain observer: the error keeps decaying
    errs = np.array(errs)
    assert errs[-1] < errs[4500] < 1e-3 * errs[0]


def test_sampling_limit_for_high_orders():
    """n >= 5: the window ends where the bandwidth (rho_nm / (T - s)) times h reaches 0.1."""
    plant = CanonicalPlant((0.0,) * 6, (1.0,))
    obs = make(plant, T=2.0, m=1, mode="restart")
    assert obs.sampling_limit == 0.1
    t = grid(2.0, 1e-3)
    X = simulate_zoh(plant, np.ones(6), t, np.zeros(len(t)))
    obs.reset(0.0)
    for k in range(len(t)):
        obs.update(t[k], X[k, :1], np.zeros(1))
        if obs.restarts:
            break
    left = 2.0 - t[k]
    assert obs.rho_nm * 1e-3 / left >= 0.1 > obs.rho_nm * 1e-3 / (left + 1e-3)
    assert obs.last_end[1] == "sampling limit"
    assert make(plant, sampling_limit=0.0).sampling_limit == 0.0
    assert make(sampling_limit=-1).sampling_limit == 0.0          # n = 2: exact, no limit


def test_reset_restarts_the_window_and_keeps_the_estimate():
    """~/reset (Runner.reset): the next sample starts a new window; without an initial
    estimate the current one is kept (moved on by a normal step), so nothing jumps."""
    t, u, X = _di_stream(7.0)
    flat = load_params_file(DI_CONFIG)
    r = Runner(flat)
    errs = []
    for k in range(len(t)):
        r.set_input(t[k], [u[k]])
        if abs(t[k] - 6.0) < 1e-9:
            r.reset("service")
        out = r.process(t[k], [X[k, 0]])
        errs.append(np.abs(X[k] - out.estimate).max())
        if abs(t[k] - 6.0) < 1e-9:
            assert out.convergence[0] == 0.0             # time since (re)start
            assert r.observer.window_start == pytest.approx(6.0, abs=1e-9)
    assert max(errs[5001:]) < 1e-9
    assert r.resets["service"] == 1
    # reset_keeps_estimate: false starts the new window from zero instead
    flat["prescribed_time.reset_keeps_estimate"] = False
    r = Runner(flat)
    for k in range(6001):
        r.set_input(t[k], [u[k]])
        out = r.process(t[k], [X[k, 0]])
    r.reset("service")
    r.set_input(t[6001], [u[6001]])
    out = r.process(t[6001], [X[6001, 0]])
    assert np.all(out.estimate == 0.0)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_rejected_sample_leaves_the_state_untouched():
    obs = make()
    t, u, X = _di_stream(0.1)
    obs.reset(0.0)
    for k in range(50):
        obs.update(t[k], X[k, :1], np.array([u[k]]))
    # the whole committed state (estimate, last sample, window) and the clock
    before = (obs.estimate.copy(), obs._st.copy(), obs._clk.copy(), obs.window_start)
    with pytest.raises(SampleRejected) as exc:
        obs.update(t[50], np.array([1e308]), np.array([1e308]))
    assert exc.value.reason == "non_finite_estimate"
    assert np.array_equal(obs.estimate, before[0])
    assert np.array_equal(obs._st, before[1], equal_nan=True)
    assert np.array_equal(obs._clk, before[2]) and obs.window_start == before[3]
    for k in range(50, len(t)):
        obs.update(t[k], X[k, :1], np.array([u[k]]))
    assert np.all(np.isfinite(obs.estimate))


def test_runner_reports_health_and_guaranteed_time():
    t, u, X = _di_stream(6.0)
    r = Runner(load_params_file(DI_CONFIG))
    for k in range(len(t)):
        r.set_input(t[k], [u[k]])
        out = r.process(t[k], [X[k, 0]])
    since, res, conv, gt, health = out.convergence
    assert gt == 5.0 and conv == 1.0 and since == pytest.approx(6.0)
    assert health == pytest.approx(np.abs(r.observer.injections).max())
    values = dict(r.status(now=6.0).values)
    assert values["mode"] == "restart" and values["restarts (total)"] == "1"
    assert r.status(now=6.0).level == 0


# --------------------------------------------------------------- models and configs
def test_models_are_registered_and_match_the_exact_zoh_samples():
    for name, plant in (("double_integrator", DOUBLE_INTEGRATOR), ("third_order", THIRD_ORDER)):
        spec = MODELS[name]
        assert spec.n == plant.n and spec.m == 1 and spec.p == 1
        t = uniform_grid(1.0, 1000.0)
        sim = simulate(spec.make_rhs(dict(spec.default_params)), spec.default_x0, t, spec.default_input)
        X = simulate_zoh(plant, spec.default_x0, t, sim.u[:, 0])
        assert np.abs(sim.x - X).max() < 1e-9 * max(1.0, np.abs(X).max())
    assert MODELS["double_integrator"].default_x0 == (20.0, 1.0)
    assert example1_input(0.3)[0] == pytest.approx(math.sin(3.0) + math.cos(0.3))
    assert THIRD_ORDER.r == 2


def test_example_configs_build_the_papers_observers():
    obs = Runner(load_params_file(DI_CONFIG)).observer
    assert (obs.T, obs.m, obs.l.tolist(), obs.mode) == (5.0, 1, [1.0, 1.0], "restart")
    obs = Runner(load_params_file(TO_CONFIG)).observer
    assert (obs.n, obs.r, obs.T, obs.m) == (3, 2, 2.0, 2)
