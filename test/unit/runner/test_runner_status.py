"""The runner's status (levels, values, rates, restarts, single_delay's figures, the converged
flag) and the estimated joint state built from the estimate.

On test_runner.py's simulated DC motor (test/support/runner_streams.py).
"""
from __future__ import annotations

import re

import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.runner import OK, WARN, Output
from runner_streams import CONTINUOUS, NAN, clean, drive, make
from runner_streams import uniform  # noqa: F401 (fixtures)


# -- status -----------------------------------------------------------------------------------------------
def values(st):
    return dict(st.values)


def test_status_levels_and_values(uniform):
    r = make("luenberger", diagnostics__window=0.25)
    st = r.status(0.0)
    v = values(st)
    assert st.level == WARN
    assert st.message == "waiting: no accepted measurement yet"
    assert v["observer"] == "luenberger" and v["state"] == "waiting"
    assert v["samples accepted"] == "0" and v["samples rejected"] == "0"
    assert v["update time p50/p99 (us)"] == "nan / nan"
    assert "measurement rate (Hz)" not in v                   # no window yet
    assert "observer gain L" in v and "closed-loop poles" in v

    drive(r, uniform, 0, 501)
    st = r.status(0.5)
    v = values(st)
    assert (st.level, st.message) == (OK, "converged"), st
    assert v["state"] == "converged"
    assert v["samples accepted"] == "501" and v["samples rejected"] == "0"
    assert v["measurement rate (Hz)"] == "1002.0"              # 501 samples in 0.5 s
    assert v["expected rate (Hz)"] == "1000.0"
    assert v["time since start (s)"] == "0.5000"
    assert v["guaranteed convergence time (s)"] == "none"
    assert v["input age (s)"] == "0.0000"
    assert re.fullmatch(r"\d+\.\d / \d+\.\d", v["update time p50/p99 (us)"])
    p50, p99 = (float(x) for x in v["update time p50/p99 (us)"].split(" / "))
    assert 0 < p50 <= p99
    assert not any(k.startswith("rejected: ") or k.startswith("restarts: ") for k in v)

    # a window with one rejection: WARN naming the reason
    drive(r, uniform, 501, 600)
    assert r.process(uniform.t[599] + 5e-4, [NAN]) == "measurement_non_finite"
    drive(r, uniform, 600, 701)
    st = r.status(0.7)
    v = values(st)
    assert st.level == WARN
    assert st.message == ("converged: 1 sample(s) rejected in the last 0.25 s "
                          "(last: measurement_non_finite)")
    assert v["rejected: measurement_non_finite"] == "1"
    assert v["samples rejected"] == "1" and v["samples accepted"] == "701"
    assert v["measurement rate (Hz)"] == "1000.0"

    # the next clean window is OK again; the totals stay
    drive(r, uniform, 701, 1001)
    st = r.status(1.0)
    v = values(st)
    assert (st.level, st.message) == (OK, "converged")
    assert v["rejected: measurement_non_finite"] == "1"
    assert v["samples accepted"] == "1001"


def test_status_rate_below_expected(uniform):
    r = make("luenberger")
    r.status(0.0)
    s = uniform
    for i in range(0, 1001, 2):                               # 500 Hz
        r.set_input(s.t[i], s.u[i])
        assert isinstance(r.process(s.t[i], s.y[i]), Output)
    st = r.status(1.0)
    v = values(st)
    assert st.level == WARN
    assert v["measurement rate (Hz)"] == "501.0"
    assert "rate 501 Hz below expected 1000 Hz" in st.message
    # 90 % of the expected rate is fine (threshold 80 %)
    r = make("luenberger")
    r.status(0.0)
    for i in range(1001):
        if i % 10 == 5:
            continue
        r.set_input(s.t[i], s.u[i])
        r.process(s.t[i], s.y[i])
    st = r.status(1.0)
    assert st.level == OK, st.message
    assert values(st)["measurement rate (Hz)"] == "901.0"
    # expected_rate 0 disables the check
    r = make("luenberger", diagnostics__expected_rate=0.0)
    r.status(0.0)
    drive(r, s, 0, 101)
    st = r.status(1.0)
    assert st.level == OK and "expected rate (Hz)" not in values(st)
    assert values(st)["measurement rate (Hz)"] == "101.0"


def test_status_restarts_and_single_delay_values(uniform):
    r = make("single_delay", diagnostics__expected_rate=0.0)
    r.status(0.0)
    drive(r, uniform, 0, 50)
    st = r.status(0.049)
    v = values(st)
    assert v["state"] == "converging" and st.message.startswith("converging")
    assert v["guaranteed convergence time (s)"] == "0.1"
    assert v["form"] == "continuous (Theorem 1)"
    drive(r, uniform, 600, 701, held_first=True)              # gap: a restart
    st = r.status(0.7)
    v = values(st)
    assert v["restarts: gap"] == "1"
    assert v["state"] == "converged"
    assert st.level == OK


def test_status_diverging_single_delay(uniform):
    r = make("single_delay", outlier__threshold=0.0)    # let the wrong measurement through
    drive(r, uniform, 0, 300)
    # after the guaranteed time, a measurement far from the prediction
    r.set_input(uniform.t[300], uniform.u[300])
    out = r.process(uniform.t[300], uniform.y[300] + 1.0)
    assert out.convergence[1] > 0.1
    assert r.state_name() == "diverging"
    st = r.status(uniform.t[300])
    assert st.level == WARN and "diverging" in st.message


def test_converged_flag_at_exactly_tau_despite_float_rounding(uniform):
    # started at 0.6, the sample at 0.7 is 0.09999999999999998 s later: the observer applies
    # the delayed correction there (it allows 1e-9), so the runner must call it converged too
    r = make("single_delay")
    outs = drive(r, uniform, 600, 701)
    assert outs[700].convergence[0] < 0.1
    assert outs[700].convergence[2] == 1.0
    assert outs[699].convergence[2] == 0.0


# -- estimated_joint_states ------------------------------------------------------------------------------
def test_joint_state_from_the_estimate(uniform):
    for name in CONTINUOUS:
        for out in list(clean(name, uniform).values())[::97]:
            x = out.estimate
            assert out.joint_state == (["joint1"], [float(x[0])], [float(x[1])], [float(x[2])])
            assert all(type(v) is float for f in out.joint_state[1:] for v in f)


def test_joint_state_mappings(uniform):
    r = make("luenberger", estimated_joint_states__effort_states=[-1],
             estimated_joint_states__velocity_states=[])
    out = drive(r, uniform, 0, 5)[4]
    assert out.joint_state == (["joint1"], [float(out.estimate[0])], [], [])
    r = make("luenberger", estimated_joint_states__joint_names=["a", "b"],
             estimated_joint_states__position_states=[0, 1],
             estimated_joint_states__velocity_states=[1, 2],
             estimated_joint_states__effort_states=[-1, -1])
    out = drive(r, uniform, 0, 5)[4]
    x = out.estimate
    assert out.joint_state == (["a", "b"], [float(x[0]), float(x[1])], [float(x[1]), float(x[2])], [])
    r = make("luenberger", estimated_joint_states__joint_names=[],
             estimated_joint_states__position_states=[], estimated_joint_states__velocity_states=[],
             estimated_joint_states__effort_states=[])
    assert drive(r, uniform, 0, 5)[4].joint_state is None


def test_joint_state_mixed_indices_refused():
    with pytest.raises(ConfigError) as e:
        make("luenberger", estimated_joint_states__joint_names=["a", "b"],
             estimated_joint_states__position_states=[0, -1],
             estimated_joint_states__velocity_states=[],
             estimated_joint_states__effort_states=[])
    assert e.value.parameter == "estimated_joint_states.position_states"
