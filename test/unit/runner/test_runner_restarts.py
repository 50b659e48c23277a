"""The runner's restarts (time jumps, gaps, resets) and run-time reconfiguration: a restart
gives exactly a fresh run's outputs; a refused change keeps the old observer.

On test_runner.py's simulated DC motor (test/support/runner_streams.py).
"""
from __future__ import annotations

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.runner import WARN, Output, Runner
from fto_ros.runner.runner import HELD
from runner_streams import CONTINUOUS, clean, drive, flat, make, same_output, stream_for
from runner_streams import uniform, sparse  # noqa: F401 (fixtures)


# -- restarts ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", CONTINUOUS + ("single_delay_sampled",))
def test_time_jump_restarts_like_a_fresh_run(name, uniform, sparse):
    s = stream_for(name, uniform, sparse)
    ref = clean(name, s)
    r = make(name)
    k = int(np.searchsorted(s.t, 0.55))              # t[k-1] - t[0] > jump_threshold (0.5)
    drive(r, s, 0, k)
    assert s.t[k - 1] - s.t[0] > 0.5
    # the bag loops: the same stream again from its start; its first sample is held until
    # the second confirms the jump, then the new run starts on it
    after = drive(r, s, 0, 200, held_first=True)
    assert r.resets == {"time_jump": 1}
    assert not r.rejected
    assert after[1].convergence[0] == pytest.approx(s.t[1] - s.t[0], abs=1e-12)
    for i, out in after.items():
        same_output(out, ref[i])


@pytest.mark.parametrize("name", CONTINUOUS)
def test_time_jump_rejected_when_reset_on_jump_is_off(name, uniform):
    ref = clean(name, uniform)
    r = make(name, time__reset_on_jump=False)
    drive(r, uniform, 0, 700)
    before = np.array(r.observer.estimate, copy=True)
    assert r.process(uniform.t[0], uniform.y[0]) == "stamp_backwards"
    assert r.process(uniform.t[699] - 0.6, uniform.y[0]) == "stamp_backwards"
    assert r.rejected == {"stamp_backwards": 2}
    assert not r.resets
    np.testing.assert_array_equal(r.observer.estimate, before)
    for i, out in drive(r, uniform, 700, 800).items():
        same_output(out, ref[i])


@pytest.mark.parametrize("name", CONTINUOUS)
def test_jump_threshold_is_respected(name, uniform):
    r = make(name, time__jump_threshold=0.05)
    drive(r, uniform, 0, 200)
    assert r.process(uniform.t[199] - 0.04, uniform.y[0]) == "stamp_backwards"
    # a jump is held until the next sample confirms it; the current input is stamped after
    # the jump target (old timeline), so the held sample cannot start the new run and the
    # first one that can waits for an input of the new timeline
    t_new = uniform.t[199] - 0.06
    assert r.process(t_new, uniform.y[0]) == HELD
    assert not r.resets
    assert r.process(t_new + 1e-3, uniform.y[0]) == "missing_input"
    assert r.resets == {"time_jump": 1}
    # the small jump back, then the held sample and this one
    assert r.rejected == {"stamp_backwards": 1, "missing_input": 2}
    assert r.set_input(t_new + 2e-3, uniform.u[0]) is None
    out = r.process(t_new + 2e-3, uniform.y[0])
    assert isinstance(out, Output) and out.convergence[0] == 0.0
    assert r.resets == {"time_jump": 1}


@pytest.mark.parametrize("name", CONTINUOUS + ("single_delay_sampled",))
def test_gap_restarts_like_a_fresh_run(name, uniform, sparse):
    s = stream_for(name, uniform, sparse)
    r = make(name)
    k1 = int(np.searchsorted(s.t, 0.05))
    k2 = int(np.searchsorted(s.t, 0.56))              # gap > time.max_gap = 0.5
    drive(r, s, 0, k1)
    after = drive(r, s, k2, None, held_first=True)   # the gap is confirmed by the next sample
    assert r.resets == {"gap": 1}
    assert not r.rejected
    fresh = drive(make(name), s, k2, None)
    assert after[k2 + 1].convergence[0] == pytest.approx(s.t[k2 + 1] - s.t[k2], abs=1e-12)
    assert set(after) == set(fresh) - {k2}
    for i in after:
        same_output(after[i], fresh[i])


def test_gap_just_under_max_gap_does_not_restart(uniform):
    r = make("luenberger", time__max_gap=0.02)
    drive(r, uniform, 0, 100)
    out = r.process(uniform.t[118], uniform.y[118])            # 19 ms later
    assert isinstance(out, Output) and out.convergence[0] > 0.1
    r.set_input(uniform.t[140], uniform.u[140])
    assert r.process(uniform.t[140], uniform.y[140]) == HELD   # 22 ms later
    r.set_input(uniform.t[141], uniform.u[141])
    out = r.process(uniform.t[141], uniform.y[141])            # confirms it: one restart
    assert out.convergence[0] == pytest.approx(1e-3)
    assert r.resets == {"gap": 1}


@pytest.mark.parametrize("name", CONTINUOUS + ("single_delay_sampled",))
def test_reset_restarts(name, uniform, sparse):
    s = stream_for(name, uniform, sparse)
    r = make(name)
    k = int(np.searchsorted(s.t, 0.2))
    drive(r, s, 0, k)
    assert r.state_name() == "converged"
    r.reset()
    assert r.resets == {"service": 1}
    assert r.state_name() == "waiting"
    st = r.status(s.t[k - 1])
    assert st.level == WARN and "restarted, waiting for a sample" in st.message
    after = drive(r, s, k, k + 150)
    assert after[k].convergence[0] == 0.0
    assert after[k + 149].convergence[0] == pytest.approx(s.t[k + 149] - s.t[k])
    fresh = drive(make(name), s, k, k + 150)
    for i in after:
        same_output(after[i], fresh[i])
    r.reset("custom")
    assert r.resets == {"service": 1, "custom": 1}


# -- reconfigure -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name,key,value", [
    ("luenberger", "luenberger.poles", [1.0, 2.0, 3.0]),
    ("luenberger", "luenberger.poles", [-50.0, -60.0]),
    ("luenberger", "input.timeout", -1.0),
    ("luenberger", "luenberger.typo", 1.0),
    ("single_delay", "single_delay.tau", 0.0),
    ("single_delay", "single_delay.k", "100"),
    ("single_delay", "estimated_joint_states.position_states", [5]),
])
def test_reconfigure_bad_value_keeps_the_old_observer(name, key, value, uniform):
    ref = clean(name, uniform)
    r = make(name)
    drive(r, uniform, 0, 200)
    obs, settings = r.observer, dict(r.settings)
    with pytest.raises(ConfigError) as e:
        r.reconfigure(flat(name, **{key.replace(".", "__"): value}))
    assert e.value.parameter == key
    assert r.observer is obs and r.settings == settings
    assert not r.resets
    for i, out in drive(r, uniform, 200, 300).items():
        same_output(out, ref[i])


def test_reconfigure_cannot_change_the_type(uniform):
    r = make("luenberger")
    drive(r, uniform, 0, 10)
    with pytest.raises(ConfigError) as e:
        r.reconfigure(flat("single_delay"))
    assert e.value.parameter == "observer.type"
    assert r.observer_type == "luenberger"


def test_reconfigure_good_value_restarts(uniform):
    r = make("luenberger")
    drive(r, uniform, 0, 200)
    old = r.observer
    new_flat = flat("luenberger", luenberger__poles=[-40.0, -45.0, -55.0], input__timeout=0.2)
    r.reconfigure(new_flat)
    assert r.resets == {"reconfigure": 1}
    assert r.observer is not old
    assert r.settings["input.timeout"] == 0.2
    assert not np.allclose(r.observer.L, old.L)
    np.testing.assert_allclose(sorted(r.observer.closed_loop_poles.real), [-55.0, -45.0, -40.0])
    after = drive(r, uniform, 200, 300)
    assert after[200].convergence[0] == 0.0
    fresh = drive(Runner(new_flat), uniform, 200, 300)
    for i in after:
        same_output(after[i], fresh[i])


def test_reconfigure_single_delay_tau(uniform):
    r = make("single_delay")
    drive(r, uniform, 0, 200)
    r.reconfigure(flat("single_delay", single_delay__tau=0.05))
    assert r.resets == {"reconfigure": 1}
    after = drive(r, uniform, 200, 320)
    assert after[200].convergence[0] == 0.0
    assert after[200].convergence[3] == pytest.approx(0.05)
    err = max(np.max(np.abs(after[i].estimate - uniform.x[i])) for i in range(251, 320))
    assert err < 1e-3
