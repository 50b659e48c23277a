"""The sampled single_delay's advance path in the runner: inputs advance the predictor, the
advance matches the prediction, a measurement older than an applied input is refused, and a
run-time change of k stays exact.

On test_runner.py's simulated DC motor (test/support/runner_streams.py).
"""
from __future__ import annotations

import copy

import numpy as np
import pytest

from fto_ros.runner import Output, Runner
from runner_streams import drive, flat, make
from runner_streams import uniform, sparse  # noqa: F401 (fixtures)


# -- the sampled form's advance path ----------------------------------------------------------------------
def test_sampled_input_advances_the_predictor(sparse):
    s = sparse
    r = make("single_delay_sampled")
    drive(r, s, 0, 100)
    obs = r.observer
    t_meas = s.t[99]
    x_meas = np.array(obs.estimate, copy=True)
    assert obs._s == pytest.approx(t_meas - s.t[0], abs=1e-9)
    nxt = s.after[99]
    t_in, kind, j = s.events[nxt]
    assert kind == 0 and t_in > t_meas
    # the runner applies the input when a measurement reaches its stamp (an input stamped
    # ahead cannot move the prediction past measurements still to come): the same as
    # advancing the observer at once, then giving it the measurement with that input
    twin = copy.deepcopy(obs)
    assert r.set_input(t_in, s.u[j]) is None
    assert obs._s == pytest.approx(t_meas - s.t[0], abs=1e-9)   # not moved yet
    twin.advance(t_in, s.u[j])
    assert twin._s == pytest.approx(t_in - s.t[0], abs=1e-9)    # integrated to the input
    assert not np.array_equal(twin.estimate, x_meas)
    # the measured component is the predictor omega between samples
    assert twin.estimate[0] != s.y[99][0]
    k = next(i for i in range(100, len(s.t)) if s.t[i] > t_in)
    a = r.process(s.t[k], s.y[k])
    twin.update_checked(s.t[k], s.y[k], s.u[j])
    np.testing.assert_array_equal(a.estimate, twin.estimate)
    # an input stamped before the last measurement does not move the observer
    twin = copy.deepcopy(obs)
    assert r.set_input(s.t[k] - 1e-4, s.u[j]) is None
    a = r.process(s.t[k] + 1e-4, s.y[k])
    twin.update_checked(s.t[k] + 1e-4, s.y[k], s.u[j])
    np.testing.assert_array_equal(a.estimate, twin.estimate)


def test_sampled_advance_matches_prediction_without_inputs(sparse):
    """Advancing at input instants with the same held value is the same as one prediction."""
    s = sparse
    a = make("single_delay_sampled")
    b = make("single_delay_sampled")
    for r in (a, b):
        drive(r, s, 0, 100)
    u = next(s.u[j] for _, kind, j in reversed(s.events[:s.after[99]]) if kind == 0).copy()
    t0, t1 = s.t[99], s.t[100]
    for f in (0.2, 0.5, 0.9):
        a.set_input(t0 + f * (t1 - t0), u)
    b.set_input(t0 + 0.9 * (t1 - t0), u)
    oa = a.process(t1, s.y[100])
    ob = b.process(t1, s.y[100])
    # sub-steps split at other instants: the same up to the Heun step of F and the
    # interpolation of the delayed term (2e-5 here), well inside the estimate's accuracy
    np.testing.assert_allclose(oa.estimate, ob.estimate, rtol=0, atol=1e-4)
    assert np.max(np.abs(oa.estimate - s.x[100])) < 3e-3
    assert np.max(np.abs(ob.estimate - s.x[100])) < 3e-3


def test_sampled_measurement_older_than_an_applied_input_is_rejected(sparse):
    s = sparse
    r = make("single_delay_sampled")
    drive(r, s, 0, 150)
    t = s.t[149]
    assert r.set_input(t + 1e-3, s.u[0]) is None
    got = r.process(t + 5e-4, s.y[149])
    assert isinstance(got, (str, Output))


def test_single_delay_k_changed_at_run_time_stays_exact(uniform):
    """k and the k y part of F2 cannot drift apart: F2 is the plant's own term, the observer
    adds k y from k, so k := 150 alone still gives the exact estimate tau after the restart."""
    r = make("single_delay")
    drive(r, uniform, 0, 200)
    r.reconfigure(flat("single_delay", single_delay__k=150.0))
    after = drive(r, uniform, 200, 400)
    err = max(np.max(np.abs(after[i].estimate - uniform.x[i])) for i in range(310, 400))
    assert err < 3e-4, err
    # the old form (F2 = k y written out) is flagged: it would count k y twice
    with pytest.warns(UserWarning, match="adds itself"):
        old = Runner(flat("single_delay", single_delay__F2=["100*y0"]))
    assert "F2 note" in old.observer.diagnostics()
