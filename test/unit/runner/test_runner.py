"""The runner shared by the node and the replay (fto_ros/runner/runner.py), on a simulated DC motor.

The stream is the paper's DC-motor manipulator (Mazenc & Malisoff 2022, eq. 65) simulated
with the ZOH simulator: q measured at 1 kHz, V at every sample (continuous configs), or q at
irregular 1-2 ms instants with V at 1 kHz (sampled single_delay).  Every rejection is checked
for its exact reason and count, and for leaving the observer as if the bad sample had never
come: the following outputs are compared bit for bit with a clean run.
"""
from __future__ import annotations

import copy
import math
import re
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core import jit
from fto_ros.core.errors import ConfigError
from fto_ros.models import dc_motor
from fto_ros.models.simulate import simulate, uniform_grid
from fto_ros.runner import CONVERGENCE_FIELDS, ERROR, OK, WARN, Output, Runner, load_params_file
from fto_ros.observers import kernel as kernel_protocol
from fto_ros.observers.luenberger import kernel as luenberger_kernel
from fto_ros.runner.runner import HELD

ROOT = Path(__file__).resolve().parents[3]
# the pole-placement Luenberger: its poles make the runner tests' expectations exact
CONFIG = {name: load_params_file(ROOT / "test" / "data" / "dc_motor_explicit" / f"dc_motor_{file}.yaml")
          for name, file in (("luenberger", "luenberger_poles"), ("single_delay", "single_delay"),
                             ("single_delay_sampled", "single_delay_sampled"))}
CONTINUOUS = ("luenberger", "single_delay")
NAN, INF = float("nan"), float("inf")

_TEMPLATES: dict = {}


def flat(name: str, **changes) -> dict:
    """The config ``name`` with changes (``a__b=v`` for ``a.b``; None removes the key)."""
    out = dict(CONFIG[name])
    for k, v in changes.items():
        k = k.replace("__", ".")
        if v is None:
            out.pop(k, None)
        else:
            out[k] = v
    return out


def make(name: str, **changes) -> Runner:
    """A fresh Runner (built once per configuration, then deep-copied: single_delay's design is slow)."""
    key = (name, repr(sorted(changes.items())))
    if key not in _TEMPLATES:
        _TEMPLATES[key] = Runner(flat(name, **changes))
    return copy.deepcopy(_TEMPLATES[key])


# -- streams --------------------------------------------------------------------------------------
class Stream:
    """Measurements (t, y, x true) and inputs (t_u, u) with an event order."""

    def __init__(self, t, y, x, t_u, u):
        self.t, self.y, self.x, self.t_u, self.u = t, y, x, t_u, u
        ev = [(tt, 0, i) for i, tt in enumerate(t_u)] + [(tt, 1, i) for i, tt in enumerate(t)]
        self.events = sorted(ev)          # an input at the same stamp comes first
        # position in events right after measurement i
        self.after = {i: n + 1 for n, (_, kind, i) in enumerate(self.events) if kind == 1}


@pytest.fixture(scope="module")
def uniform():
    t = uniform_grid(1.0, 1000.0)
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage,
                   output=dc_motor.output)
    return Stream(t, sim.y, sim.x, sim.t_u, sim.u_k)


@pytest.fixture(scope="module")
def sparse():
    # irregular gaps in [1, 2] ms on a 0.1 ms clock: few distinct step sizes, so the expm cache
    # works (with arbitrary nanosecond gaps nearly every sub-step costs an expm)
    gaps = np.random.default_rng(2022).integers(10, 21, size=400) * 100_000
    t = np.concatenate(([0], np.cumsum(gaps)))
    t = t[t <= 600_000_000] / 1e9
    t_in = uniform_grid(0.6, 1000.0)
    sim = simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage,
                   t_input=t_in, output=dc_motor.output)
    return Stream(t, sim.y, sim.x, sim.t_u, sim.u_k)


def stream_for(name, uniform, sparse):
    return sparse if name == "single_delay_sampled" else uniform


def drive(r: Runner, s: Stream, lo: int = 0, hi: int | None = None,
          held_first: bool = False) -> dict[int, Output]:
    """Feed measurements lo..hi-1 (and the inputs between them): {measurement index: Output}.
    ``held_first``: measurement lo is after a time discontinuity, held until the next
    confirms it (no Output for it)."""
    hi = len(s.t) if hi is None else hi
    start = 0 if lo == 0 else s.after[lo - 1]
    end = s.after[hi - 1]             # the inputs after measurement hi-1 belong to the next call
    outs = {}
    for t, kind, i in s.events[start:end]:
        if kind == 0:
            assert r.set_input(t, s.u[i]) is None
        else:
            out = r.process(t, s.y[i])
            if held_first and i == lo:
                assert out == HELD, f"sample {i} at {t}: {out}"
                continue
            assert isinstance(out, Output), f"sample {i} at {t}: {out}"
            outs[i] = out
    return outs


def check_finite(out: Output):
    assert np.all(np.isfinite(out.estimate))
    assert np.all(np.isfinite(out.convergence[[0, 1, 2, 4]]))
    assert out.unknown_input is None or np.all(np.isfinite(out.unknown_input))
    if out.joint_state is not None:
        for field in out.joint_state[1:]:
            assert all(math.isfinite(v) for v in field)


def same_output(a: Output, b: Output):
    assert a.t == b.t
    np.testing.assert_array_equal(a.estimate, b.estimate)
    np.testing.assert_array_equal(a.convergence, b.convergence)
    assert a.joint_state == b.joint_state


_CLEAN: dict = {}


def clean(name, s: Stream) -> dict[int, Output]:
    key = (name, id(s))
    if key not in _CLEAN:
        _CLEAN[key] = drive(make(name), s)
    return _CLEAN[key]


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


def test_runner_is_deterministic(uniform):
    a = drive(make("single_delay"), uniform, 0, 300)
    b = drive(make("single_delay"), uniform, 0, 300)
    for i in a:
        same_output(a[i], b[i])


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


_LUENBERGER = jit.kernel(luenberger_kernel.kernel, jit.KERNEL)


def _nan_kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The Luenberger kernel with a bug: from the 101st step on it commits a NaN estimate."""
    code = _LUENBERGER(op, st, nx, c, ic, wk, a, b, y, u, models)
    if op == jit.STEP and wk[wk.shape[0] - 1] > 0.0:
        nx[ic[kernel_protocol.EST] + 1] = math.nan
    return code


def test_observer_letting_nan_through_is_never_published(uniform):
    r = make("luenberger")
    drive(r, uniform, 0, 100)
    obs = r.observer
    broken = jit.function_list([jit.kernel(_nan_kernel, jit.KERNEL)], jit.KERNELS)
    good = r._prog[0]
    obs._wk = np.append(obs._wk, 1.0)             # the bug's switch, in the work memory
    obs._kernels = broken
    r._stack()
    r.set_input(uniform.t[100], uniform.u[100])
    assert r.process(uniform.t[100], uniform.y[100]) == "non_finite_estimate"
    assert r.rejected == {"non_finite_estimate": 1}
    assert r.resets == {"non_finite_state": 1}
    st = r.status(uniform.t[100])
    assert st.level == ERROR
    assert "non-finite" in st.message
    obs._kernels = good                                       # fixed: restarts at the next sample
    r._stack()
    out = drive(r, uniform, 101, 110)
    assert out[101].convergence[0] == 0.0
    for o in out.values():
        check_finite(o)


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


# -- non-finite values from the model terms ----------------------------------------------------------------
# 1e-300 exp(y0) is nothing for |y0| < 600 and overflows for y0 > 709.8: the plant is unchanged.
OVERFLOW = {
    "luenberger": dict(luenberger__F=["0", "-35*sin(y0) + 1e-300*exp(y0)", "0"]),
    "single_delay": dict(single_delay__F1=["-35*sin(y0) + 1e-300*exp(y0)", "40*u0"]),
    "single_delay_sampled": dict(single_delay__F1=["-35*sin(y0) + 1e-300*exp(y0)", "40*u0"]),
}
OVERFLOW_REASON = {"luenberger": "non_finite_estimate", "single_delay": "non_finite_model_term"}


@pytest.mark.parametrize("name", CONTINUOUS)
def test_overflowing_model_term_rejects_the_sample(name, uniform):
    ref = drive(make(name, **OVERFLOW[name]), uniform, 0, 400)
    r = make(name, outlier__threshold=0.0, **OVERFLOW[name])  # y = 1000 is also an outlier
    drive(r, uniform, 0, 200)
    before = np.array(r.observer.estimate, copy=True)
    got = r.process(uniform.t[199] + 5e-4, [1000.0])
    assert got == OVERFLOW_REASON[name]
    assert r.rejected == {got: 1}
    assert not r.resets
    np.testing.assert_array_equal(r.observer.estimate, before)
    for i, out in drive(r, uniform, 200, 400).items():
        check_finite(out)
        same_output(out, ref[i])


def test_exp_1000_y_is_rejected_and_nothing_non_finite_is_published():
    # the model itself grows to 1e17 (within limits.estimate); y jumps are no outliers here
    r = make("luenberger", luenberger__F=["0", "exp(1000*y0)", "0"], limits__estimate=1e300,
             outlier__threshold=0.0)
    outs = []
    t = 0.0
    for k in range(40):
        t = k * 1e-3
        r.set_input(t, [1.0])
        y = 1.0 if k in (20, 21, 30) else 1e-3 * k             # exp(1000) overflows
        out = r.process(t, [y])
        if k in (20, 21, 30):
            assert out == "non_finite_estimate"
            np.testing.assert_array_equal(r.observer.estimate, outs[-1].estimate)
        else:
            assert isinstance(out, Output)
            check_finite(out)
            outs.append(out)
    assert r.rejected == {"non_finite_estimate": 3}
    assert r.accepted == 37
    assert not r.resets


def test_luenberger_first_sample_with_non_finite_model_term(uniform):
    r = make("luenberger", **OVERFLOW["luenberger"])
    r.set_input(uniform.t[0], uniform.u[0])
    r.process(uniform.t[0], [1000.0])
    outs = drive(r, uniform, 1, 50)                           # asserts every sample is accepted
    assert len(outs) == 49


def test_sampled_overflowing_measurement_does_not_poison_the_predictor(sparse):
    s = sparse
    r = make("single_delay_sampled", **OVERFLOW["single_delay_sampled"])
    drive(r, s, 0, 150)
    r.process(s.t[149] + 2e-4, [1000.0])
    outs = drive(r, s, 150, 200)                              # asserts every sample is accepted
    assert len(outs) == 50


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
