"""Fault injection on the runner (the code path of the node and the replay), for every
committed config on its own bag: junk of every family mixed into the clean stream, and
random operation sequences (gaps from 1 ms to 1e6 s, backward, negative and far-future
stamps, resets, time jumps, missing inputs, spikes, denormals).

What must hold: no exception escapes, nothing non-finite comes out, no call hangs (each
is bounded), junk that is refused leaves no trace (the outputs equal a clean run's bit
for bit), and after any sequence and a restart a clean stream gives exactly what a fresh
runner gives.  Seeded and bounded by count: the same seeds give the same operations.
"""
from __future__ import annotations

import math
import time
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from faultkit import (COUNTS, check_result, committed_configs, feed, junk_stamps, junk_values,
                      runner_for, stream_for)
from fto_ros.runner import Output

CONFIGS = committed_configs()
IDS = [c.name for c in CONFIGS]
#: a call that takes longer than this has hung (a refusal or a step takes microseconds to
#: milliseconds; this is a hang detector, not a speed test)
HANG_S = 30.0
#: random operation sequences per config: examples x operations each (>= 10,000 in all)
EXAMPLES, OPS = 20, 520
#: measurements of the clean stream compared after the restart
AFTER = 300


def timed(fn, *args):
    t0 = time.perf_counter()
    res = fn(*args)
    assert time.perf_counter() - t0 < HANG_S, f"{fn.__name__}{args[:1]} took too long"
    return res


@pytest.mark.slow
@pytest.mark.parametrize("cfg", CONFIGS, ids=IDS)
def test_refused_junk_leaves_no_trace(cfg):
    """Junk the runner refuses, mixed into the clean stream, changes no output at all."""
    s = stream_for(cfg)
    ref: list = []
    feed(runner_for(cfg), s.events, ref)
    # seeded by the config's name, the same in every process (str hash is salted per process)
    rng = np.random.default_rng(zlib.crc32(cfg.name.encode()))
    r = runner_for(cfg)
    got: list = []
    t_last = None
    for t, kind, v in s.events:
        # junk from the first measurement on: before it, any finite stamp is a valid start
        while t_last is not None and rng.random() < 0.3:   # ~0.4 junk operations per event
            what = rng.integers(5)
            if what == 0:
                fam, y = junk_values(s.n_out, rng)
                res = timed(r.process, t_last + 1e-4, y)
                COUNTS[f"y_{fam}"] += 1
            elif what == 1:
                fam, u = junk_values(s.n_in, rng)
                if s.n_in == 0 and isinstance(u, list) and len(u) == 0:
                    continue
                res = timed(r.set_input, t_last + 1e-4, u)
                COUNTS[f"u_{fam}"] += 1
            elif what == 2:
                fam, ts = junk_stamps(t_last, rng)
                res = timed(r.process, ts, v if kind == "y" else [0.0] * s.n_out)
                COUNTS[fam] += 1
            elif what == 3:
                res = timed(r.set_input, float(rng.choice([float("nan"), -2.0, 2.0 ** 31])),
                            [0.0] * s.n_in)
                COUNTS["u_stamp"] += 1
            else:
                timed(r.status, t_last)
                COUNTS["status"] += 1
                continue
            assert isinstance(res, str) or res is None, f"junk accepted: {res}"
            assert res is not None, "junk accepted"
        if kind == "u":
            assert r.set_input(t, v) is None
        else:
            res = r.process(t, v)
            check_result(res)
            got.append(res)
            t_last = t
        COUNTS["clean"] += 1
    assert len(got) == len(ref)
    for a, b in zip(got, ref):
        if isinstance(b, Output):
            assert isinstance(a, Output), a
            np.testing.assert_array_equal(a.estimate, b.estimate)
            np.testing.assert_array_equal(a.convergence, b.convergence)
            assert (a.unknown_input is None) == (b.unknown_input is None)
            if a.unknown_input is not None:
                np.testing.assert_array_equal(a.unknown_input, b.unknown_input)
        else:
            assert a == b


def _random_operations(cfg, seed: int, n_ops: int) -> None:
    s = stream_for(cfg)
    ev = s.events
    rng = np.random.default_rng(seed)
    changes = {}
    keeps = _keeps_estimate(cfg)
    if keeps and seed % 2 == 0:
        # a restart that keeps the estimate cannot equal a fresh run before T: half of the
        # seeds start every run from a given estimate instead, so the comparison is exact
        changes = {"observer.initial_estimate": [0.0] * runner_for(cfg).observer.n_states}
        keeps = False
    r = runner_for(cfg, **changes)
    offset, pos, skip_inputs = 0.0, 0, 0

    def now():
        return offset + ev[min(pos, len(ev) - 1)][0]
    for _ in range(n_ops):
        op = rng.choice(["clean"] * 8 + ["y_junk", "u_junk", "stamp", "gap", "jump_back",
                                         "reset", "time_jump", "status", "no_input",
                                         "spike", "denormal", "repeat_sample"])
        COUNTS[f"op_{op}"] += 1
        if op == "clean":
            k = int(rng.integers(1, 30))
            for _ in range(k):
                if pos >= len(ev):                    # wrap: the signal jumps back to its start
                    offset, pos = offset + ev[-1][0] + 1e-3, 0
                t, kind, v = ev[pos]
                pos += 1
                if kind == "u":
                    if skip_inputs:
                        skip_inputs -= 1
                        continue
                    res = timed(r.set_input, offset + t, v)
                    assert res is None or isinstance(res, str)
                else:
                    check_result(timed(r.process, offset + t, v))
        elif op == "y_junk":
            check_result(timed(r.process, now(), junk_values(s.n_out, rng)[1]))
        elif op == "u_junk":
            res = timed(r.set_input, now(), junk_values(s.n_in, rng)[1])
            assert res is None or isinstance(res, str)
        elif op == "stamp":
            check_result(timed(r.process, junk_stamps(now(), rng)[1], [0.0] * s.n_out))
        elif op == "gap":                              # 1 ms .. 1e6 s
            offset += float(10.0 ** rng.uniform(-3, 6))
        elif op == "jump_back":
            offset = max(0.0, offset - float(10.0 ** rng.uniform(-3, 3)))
        elif op == "reset":
            r.reset()
        elif op == "time_jump":
            r.time_jump(now())
        elif op == "status":
            st_ = timed(r.status, now())
            assert st_.level in (0, 1, 2) and st_.message
        elif op == "no_input":
            skip_inputs = int(rng.integers(1, 2000))
        elif op in ("spike", "denormal", "repeat_sample"):
            last = next((v for _, k_, v in reversed(ev[:max(pos, 1)]) if k_ == "y"), [0.0] * s.n_out)
            y = {"spike": [x + float(rng.normal(0, 10)) for x in last],
                 "denormal": [5e-324] * s.n_out, "repeat_sample": last}[op]
            check_result(timed(r.process, now() + 1e-4, y))
    # after all that and a restart, a clean stream is exactly what a fresh runner makes of it
    r.reset()
    if keeps:
        return                  # (its estimate is carried over; checked above: finite, no hang)
    base = offset + ev[-1][0] + 10.0
    n_meas = 0
    clean = []
    for t, k, v in ev:
        clean.append((t + base, k, v))
        n_meas += k == "y"
        if n_meas == AFTER:
            break
    a: list = []
    b: list = []
    feed(r, clean, a)
    feed(runner_for(cfg, **changes), clean, b)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert type(x) is type(y), (x, y)
        if isinstance(x, Output):
            # equal to rounding: a step matrix may come from the step-size cache the junk
            # filled (composed of cached power-of-two steps) rather than a new expm
            np.testing.assert_allclose(x.estimate, y.estimate, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(x.convergence, y.convergence, rtol=1e-12, atol=1e-12)
        else:
            assert x == y


def _keeps_estimate(cfg) -> bool:
    obs = runner_for(cfg).observer
    return obs.TYPE == "prescribed_time" and obs.reset_keeps_estimate


@pytest.mark.slow
@pytest.mark.parametrize("cfg", CONFIGS, ids=IDS)
@settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1))
def test_random_operation_sequences(cfg, seed):
    _random_operations(cfg, seed, OPS)


#: a 100 ms burst of plausible junk (y + N(0, 1)) at BURST_AT (or 0.2 s after the guaranteed
#: time, once the observer is exact, when that is later): the estimate is back within
#: twice its clean-run error (+1e-6) this long after the burst, at the latest.  Guaranteed-
#: time observers: their guaranteed time (single_delay: tau after the burst;
#: prescribed_time: the end of the window, at most T).  The others have none: their
#: measured re-acquisition time (the README's table) with a 1.5x margin.
BURST_AT, BURST = 0.8, 0.1
REACQUIRE = {"cubic_escape_global_norm": 0.2, "cubic_escape_high_gain": 1.3, "dc_motor_hosm": 0.4,
             "dc_motor_luenberger": 0.3, "dc_motor_luenberger_poles": 0.7, "dc_motor_newton": 1.0,
             "fld_example2_hosm": 3.0, "possieri_example_newton": 1.0,
             "possieri_example_newton_ndim": 1.0,
             # first measured once the burst reached them (before, the suite's deep-copied
             # runners froze the differentiators' estimates, so these looked unharmed): the
             # unstable Example 1 back after 3.15-3.59 s (the window's length), the notch
             # filter's 2.5/s poles after 1.93 s; 1.5x margin as the others
             "fld_example1_hosm": 5.4, "possieri_example_newton_notch": 3.0,
             "van_der_pol_global_norm": 0.4, "van_der_pol_high_gain": 1.4,
             # the EKF baselines (no guarantee: an EKF re-acquires at its own pace)
             "cubic_escape_ekf": 2.1, "dc_motor_ekf": 0.3, "double_integrator_ekf": 2.2,
             "fld_example1_ekf": 2.2, "fld_example2_ekf": 6.5, "msd_ekf": 0.1,
             "possieri_example_ekf": 3.3, "third_order_ekf": 7.0, "van_der_pol_ekf": 2.1,
             # the mass-spring-damper example's tunings
             "msd_global_norm": 0.1, "msd_high_gain": 0.7, "msd_hosm": 1.1, "msd_luenberger": 0.1,
             "msd_newton": 1.0,
             # windows cut at g_max (the sensor-noise design): no longer exact at T, so
             # re-acquisition takes a few windows rather than one
             "msd_prescribed_time": 1.5,
             # acquire then track: the burst is detected and re-acquired, and the acquirer
             # hands over tau later; junk still in its window makes the tracker inconsistent
             # again, a second re-acquisition: tau + the NIS window (measured 0.128 s)
             "dc_motor_acquire_track": 0.16,
             # the model-free joint_kalman alone (back 0.021-0.040 s after the bursts) and
             # acquired by hosm (0.199 s: a re-acquisition and hosm's 150-sample certificate)
             "msd_joint_kalman": 0.06, "msd_track_joint_kalman": 0.3}


def _noise(v, rng):
    return [x + float(rng.normal(0.0, 1.0)) for x in v]


def burst_run(cfg, at: float, seconds: float, corrupt=_noise, samples: int | None = None,
              changes=None):
    """(clean errors, errors with a burst, the burst's end, what the burst run published
    after it): a burst of measurements ``corrupt(y, rng)`` from ``at`` on, BURST s of them or
    ``samples`` of them; errors max_i |x_hat_i - x_i| by stamp (us)."""
    s = stream_for(cfg, seconds, truth=True)
    errs, end, published = [], at + BURST, []
    for burst in (False, True):
        r = runner_for(cfg, **(changes or {}))
        rng = np.random.default_rng(0)
        err, est, hit = {}, None, 0
        for t, kind, v in s.events:
            if kind == "u":
                r.set_input(t, v)
            elif kind == "y":
                if burst and at <= t and (hit < samples if samples else t < at + BURST):
                    v = corrupt(v, rng)
                    hit += 1
                    end = t if samples else end
                out = r.process(t, v)
                check_result(out)
                est = (t, out.estimate) if isinstance(out, Output) else None
                if burst and est is not None and t > end:
                    published.append(est)
            elif est is not None and est[0] == t:
                err[round(t * 1e6)] = float(np.max(np.abs(est[1] - np.asarray(v))))
        errs.append(err)
    return errs[0], errs[1], end, published


def back_after(clean, junk, end, need_harm=True) -> float | None:
    """Seconds after ``end`` from which the error stays within twice the clean run's (+1e-6)
    to the end; None if it never does."""
    keys = sorted(k for k in junk if k in clean and k > end * 1e6)
    harm = any(junk[k] > 2 * clean[k] + 1e-6 for k in keys[:5])
    # the burst does harm on every config (the check can fail; hosm and newton_inversion
    # once looked unharmed: the fault suites' deep-copied runners had their differentiators'
    # estimates frozen at the copy)
    assert keys and (harm or not need_harm), "the burst did no harm: nothing to re-acquire"
    for i, k in enumerate(keys):
        if all(junk[j] <= 2 * clean[j] + 1e-6 for j in keys[i:]):
            return k / 1e6 - end
    return None


def back_to_level(clean, junk, end, settled) -> float | None:
    """Seconds after ``end`` from which the error stays within twice the largest error of the
    clean run once settled (from ``settled`` s on) (+1e-6) to the end; None if it never does.
    A level, not stamp by stamp: a restart moves a windowed observer's window ends (where
    the noise peaks) off the clean run's."""
    level = 2 * max(e for k, e in clean.items() if k >= settled * 1e6) + 1e-6
    keys = sorted(k for k in junk if k > end * 1e6)
    worst = 0.0
    for k in reversed(keys):                  # the last stamp where the error was above
        worst = max(worst, junk[k])
        if worst > level:
            nxt = [j for j in keys if j > k]
            return nxt[0] / 1e6 - end if nxt else None
    return keys[0] / 1e6 - end if keys else None


def reacquisition_time(cfg, at: float, seconds: float) -> float | None:
    """Seconds after the end of a burst at ``at`` from which the error stays within twice the
    clean run's (+1e-6) to the end; None if it never does."""
    clean, junk, end, _ = burst_run(cfg, at, seconds)
    return back_after(clean, junk, end)


@pytest.mark.slow
@pytest.mark.parametrize("cfg", CONFIGS, ids=IDS)
def test_reacquires_after_a_burst_of_plausible_junk(cfg):
    gt = runner_for(cfg).observer.guaranteed_time
    bound = REACQUIRE.get(cfg.name, gt + 0.01)
    # once the observer has settled: after its guaranteed time, or the config's settle time
    settle = gt if math.isfinite(gt) else runner_for(cfg).settings["metrics.settle_time"]
    at = max(BURST_AT, settle + 0.2)
    t = reacquisition_time(cfg, at, at + BURST + bound + 0.5)
    COUNTS["reacquisition"] += 1
    print(f"{cfg.name}: back within the clean error {t} s after the burst (bound {bound:g} s)")
    assert t is not None and t <= bound, (t, bound)


#: junk inside the plausibility limits (issue 19, item 11): BIG_SAMPLES measurements of
#: +-BIG, each sign at random
BIG, BIG_SAMPLES = 1e6, 500


def _big(v, rng):
    return [float(rng.choice([-BIG, BIG]))] * len(v)


def _settled_at(cfg) -> float:
    gt = runner_for(cfg).observer.guaranteed_time
    settle = gt if math.isfinite(gt) else runner_for(cfg).settings["metrics.settle_time"]
    return max(BURST_AT, settle + 0.2)


def _big_burst(cfg, changes=None):
    """(seconds back at the clean run's error level after the big burst, the burst's end, the
    largest |estimate| published after it, the largest |x| of the truth)."""
    bound = REACQUIRE.get(cfg.name, runner_for(cfg).observer.guaranteed_time + 0.01)
    at = _settled_at(cfg)
    seconds = at + BIG_SAMPLES * 0.01 + bound + 0.5      # long enough at 100 Hz and faster
    clean, junk, end, published = burst_run(cfg, at, seconds, _big, BIG_SAMPLES, changes)
    s = stream_for(cfg, seconds, truth=True)
    truth = max(abs(x) for t, kind, v in s.events if kind == "x" for x in v)
    big = max((float(np.max(np.abs(e))) for _, e in published), default=0.0)
    return back_to_level(clean, junk, end, at), end, big, truth


def test_prescribed_time_recovers_from_junk_inside_the_limits():
    """Issue 19 item 11: msd (T = 0.5 s) after 500 samples of +-1e6 rejected thousands of
    clean samples as estimate_implausible (every fault restart kept the absurd estimate, a
    warm start) and then published estimates up to 1e15.  A restart after a fault starts
    cold: back at the clean run's error level within the config's bound (windows cut at
    g_max) and, without g_max (exact at T), within T (+ one sample: the first clean sample
    still steps with the last junk one's model term, and restarts) of the first clean
    sample; nothing published after the burst is beyond the true state's size."""
    cfg = next(c for c in CONFIGS if c.name == "msd_prescribed_time")
    T = runner_for(cfg).observer.guaranteed_time
    exact = {"prescribed_time.g_max": 0.0}
    for changes, bound in ((None, REACQUIRE[cfg.name]), (exact, T + 0.002)):
        back, end, big, truth = _big_burst(cfg, changes)
        print(f"{changes}: back {back} s after the burst (bound {bound:g} s); largest "
              f"|estimate| after it {big:.3g} (truth {truth:.3g})")
        assert back is not None and back <= bound, (back, bound)
        assert big <= truth, (big, truth)


#: configs the +-1e6 burst still takes beyond their REACQUIRE bound (measured on faults19,
#: seconds after the burst until back at the clean error level, None: not within the run;
#: the largest |estimate| published after the burst): the accepted junk drives the
#: observer far off and it re-acquires at its own pace from there (no fault restart: the
#: estimates stay inside limits.estimate).  Not fixed by item 11's cold restart; a restart
#: when the clean data comes back (e.g. at the outlier gate's rebase) is the open question.
BIG_NOT_YET = {
    "dc_motor_acquire_track": "0.258 s (bound 0.16), 1.9e7",
    "dc_motor_ekf": "0.349 s (bound 0.3), 1.9e7",
    "dc_motor_hosm": "3.41 s (bound 0.4), 4.9e7", "dc_motor_luenberger": "0.308 s (0.3), 1.9e7",
    "dc_motor_newton": "None, 3.0e4", "dc_motor_single_delay_sampled": "0.182 s (0.11), 5.1e7",
    "double_integrator_ekf": "2.79 s (2.2), 2.8e6", "fld_example1_ekf": "None, 1.3e6",
    "fld_example1_hosm": "None, 2.1e5", "fld_example2_ekf": "None, 6.9e11",
    "fld_example2_hosm": "None, 6.9e11", "msd_newton": "None, 1.2e4",
    "possieri_example_ekf": "4.81 s (3.3), 9.6e4", "possieri_example_newton": "None, 1.4e4",
    "possieri_example_newton_ndim": "4.66 s (1.0), 843",
    "possieri_example_newton_notch": "None, 6.4e3", "third_order_ekf": "10.4 s (7.0), 3.0e6",
    "third_order_prescribed_time": "3.08 s (2.01), 3.5e5",
    "van_der_pol_global_norm": "None, 1.5e9", "van_der_pol_high_gain": "1.73 s (1.4), 1.7e9"}
BIG_PARAMS = [pytest.param(c, marks=pytest.mark.xfail(
    strict=True, reason=f"+-1e6 burst: not yet within the bound ({BIG_NOT_YET[c.name]})"))
    if c.name in BIG_NOT_YET else c for c in CONFIGS]


@pytest.mark.slow
@pytest.mark.parametrize("cfg", BIG_PARAMS, ids=IDS)
def test_reacquires_after_junk_inside_the_limits(cfg):
    """The same +-1e6 burst on every family: back at the clean run's error level within its
    REACQUIRE bound (the configs of BIG_NOT_YET are not yet: strict xfail, so one that
    starts passing is reported)."""
    bound = REACQUIRE.get(cfg.name, runner_for(cfg).observer.guaranteed_time + 0.01)
    back, end, big, truth = _big_burst(cfg)
    COUNTS["reacquisition"] += 1
    print(f"{cfg.name}: back {back} s after the +-1e6 burst (bound {bound:g} s); largest "
          f"|estimate| after it {big:.3g} (truth {truth:.3g})")
    assert back is not None and back <= bound, (back, bound)
