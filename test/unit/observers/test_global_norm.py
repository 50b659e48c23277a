"""global_norm (Astolfi & Praly 2005, eq. 79-85) and the high_gain comparison."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from fto_ros.core.errors import ConfigError
from fto_ros.observers import REGISTRY
from fto_ros.core.params import resolve
from fto_ros.observers.base import SampleRejected
from fto_ros.observers.global_norm import (GlobalNormObserver, companion_expm, companion_step,
                                           gains_numeric)
from fto_ros.observers.high_gain import HighGainObserver
from fto_ros.runner.settings import load_params_file

ROOT = Path(__file__).resolve().parents[3]
CUBIC = dict(f="-x1 + y**3", gamma_1="5*y**2 + y**6",
             gamma_hat="1 + (1 + 2*sqrt(2))*sqrt(4*w + 2) + (4*w + 2)**1.5")
VDP = dict(f="(1 - y**2)*x1 - y", gamma_1="y**2", gamma_hat="4 + 4*w")


def make(cls, **vals):
    return cls(resolve(cls.PARAMS, vals, cls.TYPE + "."))


def cubic(t, x):
    return [x[1], -x[1] + x[0] ** 3]


def vdp(t, x):
    return [x[1], (1 - x[0] ** 2) * x[1] - x[0]]


def simulate(rhs, x0, T, rate=1000.0):
    t = np.arange(int(round(T * rate)) + 1) / rate
    s = solve_ivp(rhs, (0, t[-1]), x0, t_eval=t, method="DOP853", rtol=1e-11, atol=1e-12)
    assert s.success
    return t, s.y.T


def drive(ob, t, X, x0_hat):
    ob.reset(0.0, x0_hat)
    est = np.empty_like(X)
    for i, (ti, xi) in enumerate(zip(t, X)):
        ob.update(float(ti), np.array([xi[0]]), np.zeros(0))
        est[i] = ob.estimate
    return est, np.linalg.norm(X - est, axis=1) / (1 + np.linalg.norm(X, axis=1))


def from_config(name, **override):
    flat = load_params_file(ROOT / "config" / f"{name}.yaml")
    typ = flat["observer.type"]
    vals = {k[len(typ) + 1:]: v for k, v in flat.items() if k.startswith(typ + ".")}
    vals.update(override)
    return make(REGISTRY[typ], **vals), flat["observer.initial_estimate"]


def test_registered():
    assert REGISTRY["global_norm"] is GlobalNormObserver
    assert REGISTRY["high_gain"] is HighGainObserver


# -- numerics ------------------------------------------------------------------------------
@pytest.mark.parametrize("c", [[-3.0], [-80.0, -1500.0], [-2.0, -5.0], [-1.0, -1.0 / 4],
                               [-6.0, -11.0, -6.0], [-3.0, -12.0, -10.0], [-10.0, -35.0, -50.0, -24.0]])
@pytest.mark.parametrize("h", [1e-3, 0.3])
def test_companion_expm_matches_scipy(c, h):
    m = len(c)
    A = np.diag(np.ones(m - 1), 1) if m > 1 else np.zeros((1, 1))
    A[:, 0] += c
    ref = expm(A * h)
    got = np.array(companion_expm(c, h))
    # entrywise in the balanced scale D = diag(s^i) (high-gain states differ in size by s^i)
    s = max(abs(np.linalg.eigvals(A)).max(), 1e-300)
    D = np.diag(s ** np.arange(m))
    bal = lambda E: np.linalg.inv(D) @ E @ D  # noqa: E731
    assert np.allclose(bal(got), bal(ref), rtol=1e-9, atol=1e-11)


def test_companion_step_exact_for_quadratic_forcing():
    c = [-7.0, -12.0]
    A = np.array([[c[0], 1.0], [c[1], 0.0]])
    r0, r1, r2 = [0.3, -1.0], [2.0, 0.5], [-1.0, 4.0]
    x0, h = [1.0, -2.0], 0.4
    s = solve_ivp(lambda t, x: A @ x + np.array(r0) + np.array(r1) * t + np.array(r2) * t * t,
                  (0, h), x0, rtol=1e-12, atol=1e-14, method="DOP853")
    got = companion_step(c, companion_expm(c, h), x0, h, r0, r1, r2)
    assert np.allclose(got, s.y[:, -1], rtol=1e-10, atol=1e-12)


def test_gains_eq79_give_eigenvalues_a1_and_a0_minus_a1():
    # n_states = 2: (I + L) k = (-a0, a1^2) -> error matrix [[k0, 1], [k1, 0]] with
    # characteristic polynomial (s + a1)(s + a0 - a1)
    k, _ = gains_numeric([80.0, 6.0])
    eig = np.sort(np.linalg.eigvals(np.array([[k[0], 1.0], [k[1], 0.0]])).real)
    assert np.allclose(eig, [-74.0, -6.0])


def test_scheme_error_vs_tight_reference():
    """The sampled exact-linear-part scheme vs the continuous observer ODE (Radau, rtol 1e-11).

    Van der Pol, x_hat(0) = (10, -10), 2 s; the continuous observer is driven by the exact
    y(t) of the plant.  Measured: max relative difference ~1e-6 (foh), ~1e-8 (quadratic),
    after the first 0.2 s transient.
    """
    ob = make(GlobalNormObserver, **VDP)
    t, X = simulate(vdp, [2.0, 0.0], 2.0)
    plant = solve_ivp(vdp, (0, 2.0), [2.0, 0.0], dense_output=True, method="DOP853",
                      rtol=1e-12, atol=1e-12).sol
    gains = ob._gains

    def rhs(tt, z):
        x0h, x1h, w = z
        y = plant(tt)[0]
        vals = gains(w)
        gh, k0, k1 = vals[0], vals[3], vals[4]
        f = (1 - y * y) * x1h - y
        v = max(-gh, min(gh, f))
        return [x1h - k0 * (y - x0h), -k1 * (y - x0h) + v, -w + y * y]

    ref = solve_ivp(rhs, (0, 2.0), [10.0, -10.0, 1.0], t_eval=t, method="Radau",
                    rtol=1e-11, atol=1e-11)
    assert ref.success
    R = ref.y[:2].T
    after = t >= 0.2
    errs = {}
    for hold in ("foh", "quadratic"):
        est, _ = drive(make(GlobalNormObserver, **VDP, output_hold=hold), t, X, [10.0, -10.0])
        errs[hold] = np.max(np.linalg.norm(est - R, axis=1)[after] / (1 + np.linalg.norm(R[after], axis=1)))
    assert errs["foh"] < 1e-4
    assert errs["quadratic"] < 1e-6


# -- the examples ----------------------------------------------------------------------------
def test_cubic_escape_relative_error_vanishes_before_escape_high_gain_does_not():
    t, X = simulate(cubic, [0.6, 0.0], 3.8)          # t_e = 3.8541 s
    gn, x0h = from_config("cubic_escape_global_norm")
    _, rel = drive(gn, t, X, x0h)
    hg, x0h = from_config("cubic_escape_high_gain")
    _, rel_hg = drive(hg, t, X, x0h)
    late = t >= 3.5                                   # |x| grows from 12 to 464
    assert rel[0] > 0.3                               # starts far off
    assert np.max(rel[(t >= 0.5) & (t <= 3.0)]) < 1e-6
    assert np.max(rel[late]) < 1e-3                   # measured 6.4e-4 at 3.8 s (sampling floor)
    assert np.max(rel_hg[late]) > 2e-2                # saturated high-gain: ~3e-2, not -> 0
    assert rel_hg[-1] > 10 * rel[-1]
    assert "saturation active" in gn.diagnostics()


def test_cubic_escape_gains_grow_with_the_state():
    t, X = simulate(cubic, [0.6, 0.0], 3.8)
    gn, x0h = from_config("cubic_escape_global_norm")
    drive(gn, t, X, x0h)
    assert gn.gamma_hat > 1e9 and gn.w > 1e5
    assert gn.injection_gains[0] == pytest.approx(80 * gn.gamma_hat, rel=1e-9)


@pytest.mark.parametrize("form", ["full", "reduced"])
def test_van_der_pol_from_far_off(form):
    t, X = simulate(vdp, [2.0, 0.0], 3.0)
    gn, x0h = from_config("van_der_pol_global_norm", form=form)
    assert x0h == [10.0, -10.0]
    _, rel = drive(gn, t, X, x0h)
    assert np.max(rel[t >= 1.0]) < 1e-7


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(x=st.tuples(st.floats(-3, 3), st.floats(-3, 3)),
       xh=st.tuples(st.floats(-20, 20), st.floats(-20, 20)))
def test_property_van_der_pol_converges(x, xh):
    t, X = simulate(vdp, list(x), 2.0)
    _, rel = drive(make(GlobalNormObserver, **VDP), t, X, list(xh))
    assert rel[-1] < 1e-6


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(x=st.tuples(st.floats(-1.2, 1.2), st.floats(-1.0, 1.0)),
       xh=st.tuples(st.floats(-10, 10), st.floats(-10, 10)))
def test_property_cubic_converges_until_escape(x, xh):
    """Horizon: 2 s, or until |x| reaches 100 (before the escape) if that comes first."""
    ev = lambda t, z: abs(z[0]) + abs(z[1]) - 100.0  # noqa: E731
    ev.terminal = True
    s = solve_ivp(cubic, (0, 2.0), list(x), events=ev, rtol=1e-10, atol=1e-12)
    T = math.floor(s.t[-1] * 1000) / 1000
    if T < 0.5:
        return
    t, X = simulate(cubic, list(x), T)
    _, rel = drive(make(GlobalNormObserver, **CUBIC), t, X, list(xh))
    assert rel[-1] < 1e-3
    assert np.max(rel[t >= 0.3]) < 1e-3


def test_third_order_chain_converges():
    # synthetic n_states = 3: x0' = x1, x1' = x2, x2' = -x2 - 2 x1 - x0 + 0.5 sin(x0)
    rhs = lambda t, x: [x[1], x[2], -x[2] - 2 * x[1] - x[0] + 0.5 * math.sin(x[0])]  # noqa: E731
    t, X = simulate(rhs, [1.0, 0.0, -1.0], 3.0)
    with pytest.warns(UserWarning, match="footnote 6"):
        ob = make(GlobalNormObserver, n_states=3, f="-x2 - 2*x1 - y + 0.5*sin(y)",
                  gamma_1="y**2", gamma_hat="3 + w", conditions="warn")
    _, rel = drive(ob, t, X, [0.0, 0.0, 0.0])
    assert np.max(rel[t >= 1.0]) < 1e-6


# -- parameters and samples ----------------------------------------------------------------------
@pytest.mark.parametrize("vals,param,text", [
    (dict(gamma_hat="0.5"), "global_norm.gamma_hat", ">= 1"),
    (dict(gamma_hat="10 - w"), "global_norm.gamma_hat", "nondecreasing"),
    (dict(gamma_1="y"), "global_norm.gamma_1", ">= 0"),
    (dict(c=[5.0, 6.0]), "global_norm.c", "Hurwitz"),
    (dict(c=[20.0, 6.0]), "global_norm.c", "footnote 6"),
    (dict(c=[80.0, 5.0]), "global_norm.c", "11/2"),
    (dict(a=["80*(1+w)"]), "global_norm.a", "expected 2"),
    (dict(f="z + y"), "global_norm.f", "unknown name"),
])
def test_bad_parameters_refused(vals, param, text):
    with pytest.raises(ConfigError) as err:
        make(GlobalNormObserver, **{**VDP, **vals})
    assert err.value.args and param in str(err.value) and text in str(err.value)


def test_footnote6_violation_only_warns_when_asked():
    with pytest.warns(UserWarning, match="global_norm.c"):
        ob = make(GlobalNormObserver, **VDP, c=[20.0, 6.0], conditions="warn")
    assert ob.diagnostics()["conditions"].startswith("WARN")


def test_bad_sample_leaves_state():
    ob = make(GlobalNormObserver, **VDP)
    ob.reset(0.0, [1.0, 2.0])
    ob.update(0.0, np.array([1.0]), np.zeros(0))
    ob.update(0.001, np.array([1.001]), np.zeros(0))
    before = ob.estimate.copy(), ob.w
    for bad in (float("nan"), float("inf")):
        with pytest.raises(SampleRejected):
            ob.update(0.002, np.array([bad]), np.zeros(0))
    with pytest.raises(SampleRejected):
        ob.update(0.001, np.array([1.0]), np.zeros(0))
    assert np.array_equal(ob.estimate, before[0]) and ob.w == before[1]
    d = ob.diagnostics()
    for key in ("w (norm estimator)", "gamma_hat(w)", "gains", "saturation active"):
        assert key in d


def test_high_gain_refuses_non_hurwitz_alpha():
    with pytest.raises(ConfigError, match="high_gain.alpha"):
        make(HighGainObserver, f="-x1", alpha=[-1.0, 1.0])


def test_high_gain_model_input_estimate_evaluates_f_at_the_estimate():
    """model_input: estimate puts xh_0 where y stands in f (the textbook form): from
    xh = (1, 0) with y = 0, f = y**3 adds 1 to xh_1' that the measured form does not."""
    h = 1e-3
    out = {}
    for mode in ("measured", "estimate"):
        ob = make(HighGainObserver, f="y**3", L=1.0, model_input=mode, output_hold="foh")
        ob.reset(0.0, [1.0, 0.0])
        ob.update(0.0, np.array([0.0]), np.zeros(0))
        ob.update(h, np.array([0.0]), np.zeros(0))
        out[mode] = ob.estimate
    assert out["estimate"][1] - out["measured"][1] == pytest.approx(h, rel=0.05)
    assert out["estimate"][0] - out["measured"][0] == pytest.approx(h * h / 2, rel=0.1)
