"""newton_inversion (Possieri, Vidano & Novara 2020): the paper's example (22) and its claims.

Theorem 2 / Corollary 1: without noise x_hat = x after a finite time; sampled at h the
floor is the differentiator's discretisation error (eta_1 ~ L h^2: halving h divides the
error by ~4).  Remark 5: the input's derivatives can be estimated.  Remark 2: delayed
start.  Remark 6 / Fig. 1(d), 2: with a sinusoidal output disturbance the filtered
observer (11) beats the n-dimensional one (21).  Bounds are measured values with margin.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.models import possieri_example as pe
from fto_ros.observers import REGISTRY
from fto_ros.core.params import resolve
from fto_ros.observers.base import SampleRejected
from fto_ros.observers.newton_inversion import NewtonInversionObserver as NI
from fto_ros.observers.newton_inversion import implicit_flow
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files

NOTCH = dict(filter_numerator=[1.0, 0.0, 2500.0], filter_denominator=[1.0, 5.0, 2500.0])
PAPER_LL = dict(scheme="livne_levant", lambdas=[1.1, 1.5, 3.0])
_SIMS: dict = {}


def cfg(**over):
    c = dict(states=["x1", "x2"], inputs=["u"], f=list(pe.F_TEXT), h=[pe.H_TEXT], L=100.0,
             Z=1000.0, mu=10.0, alpha=0.1)
    c.update(over)
    return resolve(NI.PARAMS, c, prefix="newton_inversion.")


def sim(h=1e-3, T=6.0, disturbance="none"):
    key = (h, T, disturbance)
    if key not in _SIMS:
        t = np.round(np.arange(0.0, T + h / 2, h) * 1e9) / 1e9
        _SIMS[key] = pe.simulate_example(t, disturbance)
    return _SIMS[key]


def run(obs, s, u=None):
    obs.reset(0.0, np.zeros(2))
    X = np.empty_like(s["x"])
    u = s["u"] if u is None else u
    for i, t in enumerate(s["t"]):
        obs.update(t, s["y"][i], u[i])
        X[i] = obs.estimate
    return np.abs(X - s["x"])


def test_registered():
    assert REGISTRY["newton_inversion"] is NI


def test_noiseless_example_converges_to_the_discretisation_level():
    s = sim()
    err = run(NI(cfg()), s)
    t = s["t"]
    big = np.flatnonzero(err.max(axis=1) > 1e-3)
    t_conv = t[big[-1] + 1]
    assert 0.02 < t_conv < 0.5                 # measured 0.13 s (x_hat(0) = 0, x(0) = (1, 2))
    assert err[0].max() > 0.9                  # the check can fail: it starts 2 away
    after = err[t >= 2.0].max(axis=0)
    # measured (1.2e-5, 4.0e-5) at 1 kHz, L = 100: the "about 1e-4"
    assert np.all(after < 1e-4), after


def test_error_shrinks_as_h_squared():
    e1 = run(NI(cfg()), sim(1e-3))[2000:].max(axis=0)
    e2 = run(NI(cfg()), sim(5e-4))[4000:].max(axis=0)
    ratio = e1 / e2
    assert np.all(ratio > 3.0) and np.all(ratio < 5.5), ratio     # measured ~4.0


def test_sinusoidal_disturbance_filtered_beats_n_dimensional():
    """Fig. 1(d) vs Fig. 2: the notch on eta (Remark 6) vs the observer (21), t >= 2 s."""
    s = sim(T=6.0, disturbance="sinusoid")
    steady = s["t"] >= 2.0
    e11 = run(NI(cfg(**NOTCH, **PAPER_LL)), s)[steady]
    e21 = run(NI(cfg(variant="n_dimensional", **PAPER_LL)), s)[steady]
    rms11, rms21 = np.sqrt((e11 ** 2).mean(0)), np.sqrt((e21 ** 2).mean(0))
    # measured rms (0.061, 0.117) vs (0.167, 0.351); max (0.13, 0.29) vs (0.39, 0.65)
    assert np.all(rms11 < 0.5 * rms21), (rms11, rms21)
    assert np.all(e11.max(0) < 0.6 * e21.max(0))
    # with the default eigenvalue-matched differentiator the filtered one still wins
    e11m = run(NI(cfg(**NOTCH)), s)[steady]
    e21m = run(NI(cfg(variant="n_dimensional")), s)[steady]
    assert np.all(np.sqrt((e11m ** 2).mean(0)) < 0.9 * np.sqrt((e21m ** 2).mean(0)))


def test_input_differentiator_matches_known_derivatives():
    s = sim(T=4.0)
    obs = NI(cfg())
    err_est = run(obs, s)
    # the input differentiator (Remark 5) has converged to u' and u'' (measured errors
    # 1.9e-8, 3.5e-5, 0.038 with Z = 1000)
    du = pe.input_derivatives(s["t"][-1], 2)
    assert np.all(np.abs(obs.Du.estimates[0] - du) < [1e-7, 1e-4, 0.1]), (obs.Du.estimates[0], du)
    # known derivatives as extra input channels [u, u', u'']
    ue = np.array([pe.input_derivatives(t, 2) for t in s["t"]])
    obs_k = NI(cfg(input_derivatives="known"))
    assert obs_k.n_inputs == 3
    err_known = run(obs_k, s, u=ue)
    assert err_known[2000:].max() < 1e-4
    assert err_est[2000:].max() < 1e-4
    # (ignoring u' altogether costs nothing in steady state: with alpha = 0.1 the sliding
    # term absorbs G, |eta~| ~ (|G| / mu)^(1/alpha); see docs/newton_inversion.md)


def test_delayed_start_holds_the_estimate_then_converges():
    s = sim(T=3.0)
    obs = NI(cfg(delay=0.3))
    obs.reset(0.0, np.array([0.5, 1.5]))
    X = []
    for i, t in enumerate(s["t"]):
        obs.update(t, s["y"][i], s["u"][i])
        X.append(obs.estimate.copy())
        if t < 0.3 - 1e-9:
            assert not obs.inversion_active
    X = np.array(X)
    before = s["t"] < 0.3 - 1e-9
    assert np.all(X[before] == [0.5, 1.5])
    assert obs.inversion_active
    assert np.abs(X[-1] - s["x"][-1]).max() < 1e-4
    assert "yes" in obs.diagnostics()["inversion active"]


def test_bad_samples_are_rejected_with_state_untouched():
    s = sim(T=1.0)
    obs = NI(cfg())
    obs.reset(0.0)
    for i in range(200):
        obs.update(s["t"][i], s["y"][i], s["u"][i])
    before = (obs.estimate.copy(), obs.Dy.get_state(), obs.Du.get_state(), obs.eta.copy())
    t = s["t"][200]
    for y, u, tt in (([np.nan], s["u"][200], t), (s["y"][200], [np.inf], t),
                     (s["y"][200], s["u"][200], s["t"][199]), (s["y"][200], [0.1, 0.2], t)):
        with pytest.raises(SampleRejected):
            obs.update(tt, y, u)
        np.testing.assert_array_equal(obs.estimate, before[0])
        np.testing.assert_array_equal(obs.Dy.get_state()[0], before[1][0])
        np.testing.assert_array_equal(obs.Du.get_state()[0], before[2][0])
        np.testing.assert_array_equal(obs.eta, before[3])
    obs.update(t, s["y"][200], s["u"][200])        # and it carries on
    assert np.all(np.isfinite(obs.estimate))


def test_implicit_flow_is_the_backward_euler_step():
    rng = np.random.default_rng(0)
    for _ in range(200):
        e = rng.normal(size=3) * 10.0 ** rng.uniform(-8, 1)
        c, a = 10.0 ** rng.uniform(-4, -1), rng.uniform(0.05, 0.9)
        ep = np.array(implicit_flow(list(e), c, a))
        # e+ + c |e+|^a sign(e+) = e on the entries still moving; the others are 0
        moving = ep != 0
        r = np.linalg.norm(ep)
        # (when e+ is at the rounding level of e, r^a amplifies that rounding: looser)
        tol = (1e-12 if r > 1e-6 * np.abs(e).max() else 1e-6) * np.abs(e).max()
        np.testing.assert_allclose(ep[moving] + c * r ** a * np.sign(ep[moving]), e[moving],
                                   rtol=1e-9, atol=tol)
        assert np.all(np.abs(ep) <= np.abs(e)) and np.all(ep * e >= 0)
    assert implicit_flow([0.0, 0.0], 0.1, 0.5) == [0.0, 0.0]


@pytest.mark.parametrize("over,param", [
    (dict(alpha=1.0), "alpha"), (dict(mu=0.0), "mu"),
    (dict(lambdas=[1.1, 1.5, 3.0]), "lambdas"),                  # not for eigenvalue_matched
    (dict(scheme="livne_levant", lambdas=[1.1]), "lambdas"),
    (dict(variant="n_dimensional", **NOTCH), "filter_numerator"),
    (dict(variant="n_dimensional", delay=0.1), "delay"),
    (dict(filter_numerator=[1.0]), "filter_denominator"),
    (dict(filter_numerator=[1, 0, 0, 1], filter_denominator=[1, 5, 2500]), "filter_numerator"),
    (dict(filter_numerator=[1], filter_denominator=[1, -5, 2500]), "filter_denominator"),
    (dict(initial_estimate=[0.0]), "initial_estimate"),
    (dict(check_box=[-1, 1]), "check_box"),
    (dict(f=["x2", "-x1"], h=["x1**3"]), "h"),                    # singular at x_hat(0) = 0
    (dict(f=["x2", "-x1"], h=["x1**3"], initial_estimate=[1.0, 0.0],
          check_box=[-1, 1, -1, 1]), "check_box"),
    (dict(f=["x2 +", "x1"]), "f[0]"),
])
def test_bad_configuration_is_refused_naming_the_parameter(over, param):
    with pytest.raises(ConfigError) as e:
        NI(cfg(**over))
    assert e.value.parameter == "newton_inversion." + param, str(e.value)


def test_params_files_load_and_dc_motor_model():
    for name in ("possieri_example_newton", "possieri_example_newton_notch",
                 "possieri_example_newton_ndim", "dc_motor_newton"):
        r = Runner(load_params_files(params_files(Path(f"config/{name}.yaml"))))
        assert r.observer_type == "newton_inversion"
    obs = Runner(load_params_files(params_files(Path("config/dc_motor_newton.yaml")))).observer
    assert obs.n_states == 3 and obs.Du is None            # O_2 does not depend on V
    assert obs.startup["rank_at_x0"] == 3


def test_runner_replay_of_the_committed_noiseless_bag(tmp_path):
    from fto_ros.replay.replay import replay
    m = replay("bags/possieri_example", "config/possieri_example_newton.yaml", tmp_path / "o",
               progress=False, after=2.0)
    assert m["samples_rejected"] == 0 and m["samples_accepted"] == m["sample_count"] > 9000
    worst = max(e["max_abs_after_settle"] for e in m["errors"]["per_state"].values())
    assert worst < 1e-4                                   # measured 4.0e-5

