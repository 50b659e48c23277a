"""The runner shared by the node and the replay (fto_ros/runner/runner.py), on a simulated DC
motor: clean runs (finite, convergent, deterministic across processes) and rejections.

Every rejection is checked for its exact reason and count, and for leaving the observer as
if the bad sample had never come: the following outputs are compared bit for bit with a
clean run.  (Restarts and reconfiguration: test_runner_restarts.py; status and the
estimated joint state: test_runner_status.py; non-finite values: test_runner_non_finite.py;
the sampled form's advance path: test_runner_sampled.py.)

The stream is the paper's DC-motor manipulator (Mazenc & Malisoff 2022, eq. 65) simulated
with the ZOH simulator: q measured at 1 kHz, V at every sample (continuous configs), or q at
irregular 1-2 ms instants with V at 1 kHz (sampled single_delay); test/support/runner_streams.py.
"""
from __future__ import annotations

import numpy as np
import pytest

from fto_ros.runner import CONVERGENCE_FIELDS, Output
from runner_streams import (CONTINUOUS, INF, NAN, check_finite, clean, drive, make, same_output,
                            stream_for)
from runner_streams import uniform, sparse  # noqa: F401 (fixtures)
from two_processes import assert_bitwise_equal, run_twice


# -- clean runs: finite, convergent -----------------------------------------------------------------
def test_convergence_fields():
    assert CONVERGENCE_FIELDS == ("time_since_start", "output_residual", "converged",
                                  "guaranteed_time", "health")


def test_luenberger_clean_run_converges(uniform):
    outs = clean("luenberger", uniform)
    r = make("luenberger")
    assert len(outs) == len(uniform.t) == 1001
    for i, out in outs.items():
        check_finite(out)
        assert out.t == uniform.t[i]
        assert out.convergence[0] == pytest.approx(uniform.t[i] - uniform.t[0], abs=1e-12)
        assert out.convergence[3] == INF                  # asymptotic: no guarantee
        assert out.unknown_input is None
        assert out.convergence[4] == pytest.approx(-50.0)  # slowest pole
    # starts from the first measurement (C^+ y: q = y, the rest 0), converges (poles -50..-70)
    np.testing.assert_array_equal(outs[0].estimate, [uniform.y[0][0], 0.0, 0.0])
    err = [np.max(np.abs(outs[i].estimate - uniform.x[i])) for i in range(1001)]
    assert err[0] > 0.5
    assert max(err[600:]) < 1e-3                # (the voltage step at 0.7 s costs 4e-4 on I)
    assert err[1000] < 1e-5
    assert outs[1000].convergence[2] == 1.0
    # without a guarantee the flag follows the residual threshold (0.1)
    for out in outs.values():
        assert out.convergence[2] == float(out.convergence[1] <= 0.1)
    assert r.accepted == 0


def test_single_delay_exact_after_tau(uniform):
    outs = clean("single_delay", uniform)
    for i, out in outs.items():
        check_finite(out)
        since = out.convergence[0]
        assert out.convergence[3] == pytest.approx(0.1)
        assert out.convergence[2] == float(since >= 0.1 - 1e-9)
    err = np.array([np.max(np.abs(outs[i].estimate - uniform.x[i])) for i in range(1001)])
    assert err[50] > 0.1                                      # open loop before tau
    assert np.max(err[100:]) < 3e-4                           # exact (up to the hold of y) after
    # the measured state is passed straight through
    for i in (0, 10, 500):
        assert outs[i].estimate[0] == uniform.y[i][0]


def test_single_delay_sampled_clean_run(sparse):
    outs = clean("single_delay_sampled", sparse)
    assert len(outs) == len(sparse.t)
    for i, out in outs.items():
        check_finite(out)
    late = [i for i in outs if sparse.t[i] > 0.2]
    err = max(np.max(np.abs(outs[i].estimate - sparse.x[i])) for i in late)
    assert err < 3e-3


def test_runner_is_deterministic():
    """single_delay's runner on the same 300 samples in two fresh processes (their own
    imports, caches and string-hash seeds): the same outputs, bit for bit."""
    a, b = run_twice("runner_streams:single_delay_run", 300)
    assert len(a["index"]) == 300
    assert assert_bitwise_equal(a, b) > 300 * 8


# -- rejections: exact reason, count, and no trace in the estimate -------------------------------------
def bad_measurement(y):
    def inject(r, s, k):
        return r.process(s.t[k - 1] + 0.0004, y)
    return inject


def bad_input(u, dt=0.0004):
    def inject(r, s, k):
        return r.set_input(s.t[k - 1] + dt, u)
    return inject


def repeated(r, s, k):
    return r.process(s.t[k - 1], s.y[k - 1] + 0.5)


def backwards(dt):
    def inject(r, s, k):
        return r.process(s.t[k - 1] - dt, s.y[k - 1])
    return inject


def bad_stamp(t):
    def inject(r, s, k):
        return r.process(t, s.y[k - 1])
    return inject


def bad_input_stamp(r, s, k):
    return r.set_input(NAN, s.u[0])


REJECTIONS = {
    "measurement_nan": (bad_measurement([NAN]), "measurement_non_finite"),
    "measurement_inf": (bad_measurement([-INF]), "measurement_non_finite"),
    "measurement_long": (bad_measurement([0.1, 0.2]), "measurement_wrong_length"),
    "measurement_empty": (bad_measurement([]), "measurement_wrong_length"),
    "measurement_scalar": (bad_measurement(0.3), "measurement_not_an_array"),
    "measurement_stamp_nan": (bad_stamp(NAN), "bad_stamp"),
    "measurement_stamp_inf": (bad_stamp(INF), "bad_stamp"),
    "input_nan": (bad_input([NAN]), "input_non_finite"),
    "input_inf": (bad_input([INF]), "input_non_finite"),
    "input_long": (bad_input([1.0, 2.0]), "input_wrong_length"),
    "input_empty": (bad_input([]), "input_wrong_length"),
    "input_stamp_nan": (bad_input_stamp, "input_bad_stamp"),
    "repeated_stamp": (repeated, "repeated_stamp"),
    "backwards_small": (backwards(0.0003), "stamp_backwards"),
    "backwards_under_threshold": (backwards(0.14), "stamp_backwards"),
    "measurement_stamp_negative": (bad_stamp(-1.0), "bad_stamp"),
    "measurement_stamp_beyond_int32": (bad_stamp(2.0 ** 31), "bad_stamp"),
    "measurement_implausible": (bad_measurement([1e300]), "measurement_implausible"),
    "input_implausible": (bad_input([-1e300]), "input_implausible"),
    "input_stamp_negative": (bad_input([1.0], dt=-5.0), "input_bad_stamp"),
}


@pytest.mark.parametrize("name", CONTINUOUS + ("single_delay_sampled",))
@pytest.mark.parametrize("case", sorted(REJECTIONS))
def test_rejection_leaves_no_trace(name, case, uniform, sparse):
    s = stream_for(name, uniform, sparse)
    inject, reason = REJECTIONS[case]
    ref = clean(name, s)
    k = 150                                     # after tau: the delay buffer is being read
    r = make(name)
    drive(r, s, 0, k)
    before = np.array(r.observer.estimate, copy=True)
    t_obs = getattr(r.observer, "_s", None)
    got = inject(r, s, k)
    assert got == reason
    assert r.rejected == {reason: 1}
    assert r.last_rejection == reason
    assert r.accepted == k
    assert not r.resets
    np.testing.assert_array_equal(r.observer.estimate, before)
    assert getattr(r.observer, "_s", None) == t_obs          # a rejected input does not advance
    after = drive(r, s, k, k + 120)
    for i, out in after.items():
        same_output(out, ref[i])


def test_several_rejections_in_a_row_are_all_counted(uniform):
    ref = clean("single_delay", uniform)
    r = make("single_delay")
    drive(r, uniform, 0, 200)
    t = uniform.t[199]
    reasons = [r.process(t + 1e-4, [NAN]), r.process(t, uniform.y[199]), r.set_input(t + 2e-4, [NAN]),
               r.process(t - 1e-4, uniform.y[199]), r.process(t + 3e-4, [1.0, 2.0]),
               r.process(t + 4e-4, [NAN])]
    assert reasons == ["measurement_non_finite", "repeated_stamp", "input_non_finite",
                       "stamp_backwards", "measurement_wrong_length", "measurement_non_finite"]
    assert r.rejected == {"measurement_non_finite": 2, "repeated_stamp": 1, "input_non_finite": 1,
                          "stamp_backwards": 1, "measurement_wrong_length": 1}
    for i, out in drive(r, uniform, 200, 260).items():
        same_output(out, ref[i])


@pytest.mark.parametrize("name", CONTINUOUS + ("single_delay_sampled",))
@pytest.mark.parametrize("bad", [[NAN], [1.0, 2.0], "stamp"])
def test_rejected_input_keeps_the_previous_input(name, bad, uniform, sparse):
    s = stream_for(name, uniform, sparse)
    k = int(np.searchsorted(s.t, 0.12))
    t_extra = s.t[k - 1] + 0.0005                       # a measurement before the next input
    y_extra = s.y[k - 1] + 1e-4
    runs = []
    for with_bad in (True, False):
        r = make(name, outlier__threshold=0.0)     # y_extra is an outlier of the smooth stream
        drive(r, s, 0, k)
        if with_bad:
            if bad == "stamp":
                assert r.set_input(NAN, [123.0]) == "input_bad_stamp"
            else:
                assert r.set_input(s.t[k - 1] + 0.0002, bad) is not None
        out = r.process(t_extra, y_extra)
        assert isinstance(out, Output)
        runs.append([out] + list(drive(r, s, k, k + 30).values()))
    for a, b in zip(*runs):
        same_output(a, b)


@pytest.mark.parametrize("name", CONTINUOUS + ("single_delay_sampled",))
def test_missing_input(name, uniform, sparse):
    s = stream_for(name, uniform, sparse)
    r = make(name)
    t0 = s.t[0]
    assert r.process(t0, s.y[0]) == "missing_input"
    assert r.process(t0 + 1e-4, s.y[0]) == "missing_input"
    assert r.rejected == {"missing_input": 2}
    assert r.state_name() == "waiting"
    # once the input comes the run is the clean one
    ref = clean(name, s)
    for i, out in drive(r, s, 0, 150).items():
        same_output(out, ref[i])


@pytest.mark.parametrize("name", CONTINUOUS)
def test_stale_input(name, uniform):
    s = uniform
    k = 300
    rs = {}
    for variant in ("with_stale", "reference"):
        r = make(name, input__timeout=0.0105)
        drive(r, s, 0, k)
        got = []
        for j in range(15):                           # inputs stop after t[k-1]
            i = k + j
            if variant == "reference" and j >= 10:
                continue
            out = r.process(s.t[i], s.y[i])
            got.append(out if isinstance(out, str) else "ok")
        if variant == "with_stale":
            assert got == ["ok"] * 10 + ["stale_input"] * 5
            assert r.rejected == {"stale_input": 5}
        else:
            assert got == ["ok"] * 10
        rs[variant] = (r, drive(r, s, k + 15, k + 60))
    for i, out in rs["with_stale"][1].items():
        same_output(out, rs["reference"][1][i])


def test_input_age_in_status(uniform):
    r = make("luenberger")
    assert dict(r.status(0.0).values)["input age (s)"] == "never received"
    drive(r, uniform, 0, 10)
    assert dict(r.status(uniform.t[9] + 0.25).values)["input age (s)"] == "0.2500"
    assert dict(r.status(None).values)["input age (s)"] == "n/a"


def test_observer_without_input(uniform):
    r = make("luenberger", luenberger__n_inputs=0, luenberger__B=[])
    st = r.status(0.0)
    assert "input age (s)" not in dict(st.values)
    for i in range(50):                                       # no set_input needed
        out = r.process(uniform.t[i], uniform.y[i])
        assert isinstance(out, Output)
        check_finite(out)
    assert r.set_input(0.1, []) is None
    assert r.set_input(0.1, [1.0]) == "input_wrong_length"
