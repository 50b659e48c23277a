"""hosm observer (Fridman, Levant & Davila 2007) in operation: a bad sample is rejected and
leaves the state untouched (rolled back after the differentiator stepped), the initial
estimate and diagnostics, the committed configs and the load-torque bag, a 14-state design
that warns nothing, poles that were not placed, and M from a recording (fto-design
--suggest-from)."""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.linear import place_observer_poles
from fto_ros.core.params import resolve
from fto_ros.observers.base import ConfigError, SampleRejected
from fto_ros.observers.hosm import HosmObserver
from hosm_cases import ex1, fld_traj

T1 = np.arange(8001) * 1e-3


@pytest.fixture(scope="module")
def example1():
    return fld_traj(1, T1)


# -- transactional updates -----------------------------------------------------------------------
def test_bad_samples_rejected_state_untouched(example1):
    x, _ = example1
    a, b = ex1(), ex1()
    a.reset(0.0)
    b.reset(0.0)
    for k in range(300):
        a.update(T1[k], x[k, :1], np.zeros(0))
        b.update(T1[k], x[k, :1], np.zeros(0))
    snap = (a.estimate.copy(), a.unknown_input.copy(), a.diffs[0].get_state()[0].copy())
    bad = [(T1[300], np.array([np.nan]), "measurement_non_finite"),
           (T1[300], np.array([1.0, 2.0]), "measurement_wrong_length"),
           (T1[299], x[300, :1], "stamp_too_close"), (T1[299] + 1e-7, x[300, :1], "stamp_too_close"),
           (T1[300], x[300, :1], "non_finite_estimate")]
    good_Tinv1 = a.Tinv1
    for t, y, reason in bad:
        if reason == "non_finite_estimate":
            # a failure AFTER the differentiator has stepped: it must be rolled back
            a.Tinv1 = good_Tinv1 * np.nan
        with pytest.raises(SampleRejected) as exc:
            a.update(t, y, np.zeros(0))
        a.Tinv1 = good_Tinv1
        assert exc.value.reason == reason
        np.testing.assert_array_equal(a.estimate, snap[0])
        np.testing.assert_array_equal(a.unknown_input, snap[1])
        np.testing.assert_array_equal(a.diffs[0].get_state()[0], snap[2])
    with pytest.raises(SampleRejected):
        a.update(T1[300], x[300, :1], np.zeros(1))          # wrong input length
    for k in range(300, 400):
        a.update(T1[k], x[k, :1], np.zeros(0))
        b.update(T1[k], x[k, :1], np.zeros(0))
    np.testing.assert_array_equal(a.estimate, b.estimate)   # as if the bad samples never came


def test_initial_estimate_and_diagnostics():
    obs = ex1()
    obs.reset(0.0, np.array([1.0, 0.0, 1.0, 1.0]))
    obs.update(0.0, np.array([1.0]), np.zeros(0))
    np.testing.assert_allclose(obs.estimate, [1.0, 0.0, 1.0, 1.0])
    d = obs.diagnostics()
    assert d["relative degree"] == "4" and d["invariant zeros"] == "none"
    assert "strongly observable" in d["structure"] and d["M"] == "1"
    assert "differentiator residual" in d and math.isfinite(obs.health)
    assert obs.guaranteed_time == math.inf


# -- configs and bags -------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["fld_example1_hosm", "fld_example2_hosm", "dc_motor_hosm"])
def test_configs_load(name):
    from pathlib import Path

    from fto_ros.runner.runner import Runner
    from fto_ros.runner.plant_files import params_files
    from fto_ros.runner.settings import load_params_files
    root = Path(__file__).resolve().parents[3]
    r = Runner(load_params_files(params_files(root / "config" / f"{name}.yaml")))
    assert r.observer.TYPE == "hosm"
    assert r.observer.n_inputs == (1 if name.startswith("dc") else 0)


def test_replay_dc_motor_load_reports_unknown_input_errors(tmp_path):
    from pathlib import Path

    from fto_ros.replay.replay import replay
    from fto_ros.runner.plant_files import params_files
    root = Path(__file__).resolve().parents[3]
    m = replay(root / "bags" / "dc_motor_load", params_files(root / "config" / "dc_motor_hosm.yaml"),
               tmp_path / "out", progress=False, plot=False, after=0.3)
    assert m["samples_rejected"] == 0
    ui = m["unknown_input_errors"]["per_state"]["tau_L"]
    assert ui["max_abs_after_settle"] < 1e-2 and ui["max_abs"] > 0.1
    assert m["errors"]["per_state"]["q_dot"]["max_abs_after_settle"] < 1e-4
    assert m["unknown_input_topic"] == "/dc_motor/true_unknown_input"


# -- a large design: no warning when it succeeded (the 7-joint arm, 14 states) --------------------
def _arm(joints: int = 7):
    n = 2 * joints
    A, C, D = np.zeros((n, n)), np.zeros((joints, n)), np.zeros((n, joints))
    for j in range(joints):
        A[2 * j, 2 * j + 1], A[2 * j + 1, 2 * j + 1] = 1.0, -0.5 * (j + 1)
        C[j, 2 * j], D[2 * j + 1, j] = 1.0, 1.0
    return A, C, D


def test_a_14_state_start_warns_nothing_and_places_the_poles():
    """Was: scipy's 'Convergence was not reached' at every 14-state start (its robustness
    iteration, not the placement): the placed poles are checked instead."""
    A, C, D = _arm()
    poles = [-100.0 - 5.0 * i for i in range(14)]
    cfg = resolve(HosmObserver.PARAMS, {
        "n_states": 14, "n_outputs": 7, "A": A.ravel().tolist(), "C": C.ravel().tolist(),
        "D": D.ravel().tolist(), "poles": poles, "M": [100.0], "identify_unknown_input": False})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        obs = HosmObserver(cfg)
    got = np.sort(np.linalg.eigvals(A - obs.L @ C).real)
    np.testing.assert_allclose(got, np.sort(poles), rtol=1e-6)


def test_poles_that_were_not_placed_are_refused(monkeypatch):
    import scipy.signal

    class Bad:
        gain_matrix = np.zeros((7, 14))
    monkeypatch.setattr(scipy.signal, "place_poles", lambda *a, **k: Bad())
    A, C, _ = _arm()
    with pytest.raises(ConfigError, match="not placed"):
        place_observer_poles(A, C, [-100.0 - 5.0 * i for i in range(14)], "hosm.poles")


# -- M from a recording (fto-design --suggest-from) ------------------------------------------------
@pytest.mark.parametrize("noise", [0.0, 1e-6, 1e-4, 1e-2])
def test_the_derivative_bound_estimator_recovers_a_known_derivative(noise):
    from fto_ros.core.derivative_bound import derivative_bound
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, 5000))           # irregular sampling
    x = np.sin(2 * np.pi * 2.0 * t) + noise * rng.standard_normal(t.size)
    b = derivative_bound(t, x, 3)
    true = (2 * np.pi * 2.0) ** 3
    assert not b.noise_limited
    assert abs(b.bound - true) <= (0.01 if noise == 0 else 0.06) * true, (b, true)


def test_below_the_noise_is_said():
    from fto_ros.core.derivative_bound import derivative_bound
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 2.0, 1e-3)
    b = derivative_bound(t, 1e-3 * rng.standard_normal(t.size), 3)
    assert b.noise_limited and math.isfinite(b.bound) and b.bound > 0


def test_fto_design_suggests_m_from_a_recording(capsys):
    from fto_ros.cli import design
    root = Path(__file__).resolve().parents[3]
    rc = design.main([str(root / "config" / "dc_motor_plant.yaml"),
                      str(root / "config" / "dc_motor_hosm.yaml"),
                      str(root / "config" / "dc_motor_luenberger.yaml"),
                      "--suggest-from", str(root / "bags" / "dc_motor_load")])
    out = capsys.readouterr().out
    assert rc == 0, out
    line = next(x for x in out.splitlines() if "max |d^3/dt^3 (y0 - c0 z)|" in x)
    assert "rad/s^3" in line, line                                   # the plant's units
    measured = float(line.split("= ")[1].split()[0])
    suggested = float(next(x for x in out.splitlines() if "hosm.M: [" in x).split("[")[1][:-1])
    assert 1.0 < measured < 25.5 and suggested == pytest.approx(3 * measured, rel=0.05)
    assert "luenberger has no M to suggest" in out
    rc = design.main([str(root / "config" / "dc_motor_plant.yaml"),
                      str(root / "config" / "dc_motor_hosm.yaml"), "--suggest-from", "/nonexistent"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1 and "unexpected" not in err[0], err
