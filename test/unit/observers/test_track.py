"""observer.type: track (observers/track/): a guaranteed-time acquirer hands over to a
Kalman tracker, with innovation-gated re-acquisition.

What is checked:
- the targets of the composition on the committed DC-motor bags and on a bag simulated here
  with another seed, jump size and time (benchmarks/bench_track.py measures them):
  acquisition by the guaranteed time + two samples within 3x the tracker's steady-state
  max error from initial estimates far from the state, steady-state RMS within 1.1x the
  tracker alone started at the true state, back within 3x after a velocity jump of
  several rad/s by the guaranteed time + 50 ms, no re-acquisition on the noisy bag;
- the hand-over on a noise-free bag: acquiring before tau, tracking from tau on, the
  tracker seeded with the acquirer's (exact) estimate; the mode, counts and converged flag
  on ``convergence`` and in /diagnostics; the replay metrics;
- the window test: one spike does not re-acquire, min_inconsistent samples do;
- refusals naming the parameter (a tracker with no noise model, an unknown acquirer,
  a missing tracker); the live node runs the composition with both sections declared;
- the compiled composition (with a test-only compiled acquirer until the acquirer families
  are compiled): the Python composition's decisions bit for bit, the runner's block loop,
  copies; which of the two runs the committed configs; the window's exact sum.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.observers.track import MODE_NAMES, TrackObserver
from fto_ros.replay.replay import replay
from fto_ros.runner import Output, Runner
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_track import PLANT, TRACK, measure, run, simulate  # noqa: E402

BAGS = ROOT / "bags"


def _runner(**changes) -> Runner:
    flat = load_params_files([str(PLANT), str(TRACK)])
    flat.update(changes)
    return Runner(flat)


def _check_targets(m: dict, jump: bool) -> None:
    assert np.all(m["acquisition_ratio"] <= 3.0), m
    assert np.all(m["steady_ratio"] <= 1.1), m
    if jump:
        assert np.all(m["after_jump_ratio"] <= 3.0), m
        assert m["reacquisitions"] >= 1, m
    else:
        assert m["reacquisitions"] == 0, m


@pytest.mark.slow
@pytest.mark.parametrize("bag, jump", [("dc_motor_noisy", False), ("dc_motor_collision", True)])
def test_targets_on_the_committed_bags(bag, jump):
    _check_targets(measure(BAGS / bag), jump)


@pytest.mark.slow
def test_targets_on_a_bag_not_tuned_on(tmp_path):
    """Another seed, a jump of the other sign and size at another time."""
    bag = simulate(tmp_path / "unseen", 4.0, 12, "1.7,q_dot,-6")
    _check_targets(measure(bag, seed=3), True)


def test_hand_over_at_the_guaranteed_time_on_clean_data():
    r = run((PLANT, TRACK), BAGS / "dc_motor_nominal", **{"observer.initial_estimate": [2.0, -30.0, 10.0]})
    fields = r.runner.convergence_fields
    assert fields[-3:] == ("mode", "handovers", "reacquisitions")
    mode = r.conv[:, fields.index("mode")]
    since = r.conv[:, 0]
    tau = r.runner.observer.guaranteed_time
    assert tau == pytest.approx(0.1)
    assert np.all(mode[since < tau - 1e-9] == 0) and np.all(mode[since >= tau - 1e-9] == 1)
    converged = r.conv[:, fields.index("converged")]
    np.testing.assert_array_equal(converged, mode == 1)
    # single_delay is exact from tau on (to its discretisation), so the tracker starts (and
    # stays) on the state
    k = int(np.argmax(mode == 1))
    assert np.max(np.abs(r.err[k])) < 1e-4, r.err[k]      # the acquirer's discretisation error
    assert np.max(np.abs(r.err[k:])) < 1e-3
    assert r.conv[-1, fields.index("handovers")] == 1
    assert r.conv[-1, fields.index("reacquisitions")] == 0
    status = dict(r.runner.status(float(r.t[-1])).values)
    assert status["mode"] == "tracking" and status["hand-overs"] == "1"
    assert "per hour" in status["false alarms (bound)"]


def test_replay_metrics_report_the_composition(tmp_path):
    m = replay(BAGS / "dc_motor_collision", [PLANT, TRACK], tmp_path / "out", progress=False,
               plot=False)
    c = m["composition"]
    assert c["acquisition_time_s"] == pytest.approx(0.1, abs=1e-6)
    assert c["handovers"] == 2 and c["reacquisitions"] == 1
    # the jump is at 2.5 s: detected within 50 ms, handed over again tau later
    assert 2.5 < c["reacquisition_times_s"][0] < 2.55
    assert c["handover_times_s"][1] == pytest.approx(c["reacquisition_times_s"][0] + 0.1, abs=2e-3)
    assert m["observer_type"] == "track"


def test_one_spike_is_not_a_reacquisition_but_a_run_of_them_is():
    """Each NIS term counts at most threshold / min_inconsistent: one spike on a consistent
    window (terms of mean p = 1) does not re-acquire, a run of min_inconsistent does."""
    obs = _runner().observer
    assert isinstance(obs, TrackObserver)
    assert obs.clip * 5 == pytest.approx(obs.threshold)
    big = 1e6
    assert not any(obs._inconsistent(1.0) for _ in range(obs.window))
    assert not obs._inconsistent(big)
    assert not any(obs._inconsistent(1.0) for _ in range(obs.window))   # the spike leaves
    fired = [obs._inconsistent(big) for _ in range(5)]
    assert fired[-1] and not fired[0], fired
    assert MODE_NAMES[0] == "acquiring"


def test_the_threshold_is_the_chi_square_quantile():
    from scipy.stats import chi2
    obs = _runner(**{"track.window": 20, "track.false_alarm": 1e-3}).observer
    assert obs.threshold == pytest.approx(chi2.isf(1e-3, 20))


def test_handover_covariance_reflects_the_acquirer_noise_gain():
    obs = _runner().observer
    sd = np.sqrt(np.diag(obs.handover_covariance))
    # the single-delay noise gain on the velocity is about 100 (sigma_y = 1e-3 rad)
    assert 0.02 < sd[1] < 0.5, sd
    given = _runner(**{"track.initial_covariance": [1e-6, 1e-2, 1e-3]}).observer
    np.testing.assert_allclose(np.diag(given.handover_covariance), [1e-6, 1e-2, 1e-3])


@pytest.mark.parametrize("changes, name", [
    ({"luenberger.design": "poles", "luenberger.poles": [-50.0, -60.0, -70.0]}, "track.tracker"),
    ({"track.acquirer": "luenberger"}, "track.acquirer"),
    ({"track.tracker": None}, "track.tracker"),
    ({"track.window": 1}, "track.window"),
    ({"track.initial_covariance": [1.0, 2.0]}, "track.initial_covariance"),
])
def test_refusals_name_the_parameter(changes, name):
    with pytest.raises(ConfigError) as err:
        _runner(**changes)
    assert name in str(err.value)


def test_refused_samples_leave_the_composition_untouched():
    r = _runner()
    x = None
    for k in range(300):
        r.set_input(k * 1e-3, [2.0])
        out = r.process(k * 1e-3, [0.0])
        assert isinstance(out, Output)
        x = out.estimate.copy()
        assert math.isfinite(out.convergence[-1])
    assert r.process(0.3, [float("nan")]) == "measurement_non_finite"
    out = r.process(0.301, [0.0])
    assert isinstance(out, Output) and np.all(np.isfinite(out.estimate))
    assert np.linalg.norm(out.estimate - x) < 1.0


@pytest.mark.live
@pytest.mark.slow
def test_live_node_runs_the_composition(tmp_path):
    pytest.importorskip("rclpy")
    import domains
    import live_node as L
    from live_node import Driver, NodeProcess
    plant = L.simulate(1.0)
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, PLANT, "--params-file", str(TRACK))
    driver = Driver(domain, outputs=("state_estimate", "convergence"))
    try:
        driver.wait_connected(node, [driver.pub_y, driver.pub_u])
        L.feed(driver, plant, 400, rate=500.0)
        driver.wait_for(lambda: any(c[5] == 1.0 for c in driver.got("convergence")), 15,
                        "mode = tracking on convergence", node)
        conv = driver.got("convergence")[-1]
        assert conv.shape == (8,) and conv[6] >= 1.0, conv
        st = driver.status_where(lambda s: s["values"].get("mode") == "tracking", 15,
                                 "mode: tracking in /diagnostics", node)
        assert st["values"]["observer"] == "track"
        assert all(np.all(np.isfinite(c)) for c in driver.got("state_estimate"))
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


# -- the compiled composition ---------------------------------------------------------------
from fto_ros.observers import kernel as K  # noqa: E402
from fto_ros.core.params import resolve
from fto_ros.observers.base import SampleRejected  # noqa: E402
from fto_ros.observers.luenberger import LuenbergerObserver  # noqa: E402
from fto_ros.observers.single_delay import SingleDelayObserver  # noqa: E402
from fto_ros.observers.track import (LegacyTrackObserver, TrackKernelObserver,  # noqa: E402
                                     kernel as TK)
from fto_ros.observers.track.design import compiled_child  # noqa: E402
from fto_ros.core.reasons import CODE  # noqa: E402
from fto_ros.runner import settings as S  # noqa: E402

CONFIG = ROOT / "config"


class _GuaranteedLuenberger(LuenbergerObserver):
    """Test-only acquirer: a compiled kernel claiming a guaranteed time of 0.1 s (luenberger
    is not an acquirer of the package: it guarantees nothing)."""

    def __init__(self, cfg):
        super().__init__(cfg)
        self._st[K.GUARANTEED] = 0.1


def _section(name: str):
    _, cls, cfg = S.split(load_params_files([str(PLANT), str(CONFIG / name)]))
    return cls, cfg


def _composition_cfg(guaranteed: bool, tracker: str) -> dict:
    cfg = resolve(TrackObserver.PARAMS, {"acquirer": "single_delay", "tracker": tracker},
                  prefix="track.")
    acq = _section("dc_motor_luenberger_poles.yaml")[1]
    cfg["acquirer_observer"] = (_GuaranteedLuenberger if guaranteed else LuenbergerObserver, acq)
    cfg["tracker_observer"] = _section("dc_motor_ekf.yaml" if tracker == "ekf"
                                       else "dc_motor_luenberger.yaml")
    return cfg


def _stream(seed: int = 1, n: int = 4000):
    """Noisy DC-motor samples with a 0.3 rad jump of the measurement at 2.5 s (a slipped
    encoder: the tracker becomes inconsistent and re-acquires, again and again)."""
    from fto_ros.models import dc_motor
    from fto_ros.models.simulate import simulate as sim_plant
    t = np.arange(n) * 1e-3
    sim = sim_plant(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage)
    y = sim.x[:, :1] + 1e-3 * np.random.default_rng(seed).standard_normal((n, 1))
    y[2500:, 0] += 0.3
    return t, y, sim.u


def _outputs(obs):
    return (obs.estimate.tolist(), obs.output_residual, obs.health, obs.converged,
            obs.guaranteed_time, obs.convergence_extra())


def _stand_in_flat(monkeypatch) -> dict:
    """The DC motor's track with the test-only acquirer registered as single_delay (its
    luenberger section as the plant block derives it) and the ekf as tracker."""
    from fto_ros.observers import REGISTRY
    monkeypatch.setitem(REGISTRY, "single_delay", _GuaranteedLuenberger)
    flat = load_params_files([str(PLANT), str(CONFIG / "dc_motor_ekf.yaml")])
    flat.update({"luenberger." + k: v for k, v in _section("dc_motor_luenberger_poles.yaml")[1].items()})
    flat.update({"observer.type": "track", "track.acquirer": "single_delay",
                 "track.tracker": "ekf"})
    return flat


@pytest.mark.parametrize("guaranteed, tracker", [(True, "ekf"), (False, "ekf"),
                                                 (True, "luenberger")])
def test_the_compiled_composition_decides_as_the_python_one(guaranteed, tracker):
    """The compiled composition and the Python one (legacy.py) on the same compiled
    children: every output equal bit for bit at every sample, through hand-overs by the
    guaranteed time or by the certificate, re-acquisitions, a restart from a given estimate
    and samples the children reject."""
    cfg = _composition_cfg(guaranteed, tracker)
    compiled, python = TrackObserver(cfg), LegacyTrackObserver(cfg)
    assert type(compiled) is TrackKernelObserver
    np.testing.assert_array_equal(compiled.handover_covariance, python.handover_covariance)
    t, y, u = _stream()
    modes = set()
    for obs in (compiled, python):
        obs.reset(None, [1.0, 5.0, 0.0])
    for k in range(len(t)):
        if k == 3000:
            for obs in (compiled, python):
                obs.reset(None, [0.5, -2.0, 1.0])
        tk = t[k] if k % 500 != 7 else t[k - 1]          # now and then a stamp too close
        got = []
        for obs in (compiled, python):
            try:
                obs.update_checked(tk, y[k], u[k])
                got.append(None)
            except SampleRejected as e:
                got.append(e.reason)
        assert got[0] == got[1], k
        assert repr(_outputs(compiled)) == repr(_outputs(python)), k
        modes.add(compiled.convergence_extra()[0])
    assert modes == {0.0, 1.0, 2.0}
    assert compiled.diagnostics()["hand-overs"] == python.diagnostics()["hand-overs"]
    assert int(compiled.diagnostics()["re-acquisitions"]) >= 2


def test_the_compiled_composition_runs_in_the_runner(monkeypatch):
    """Through Runner (its compiled block loop, a block and one event at a time alike) with a
    compiled acquirer: the outputs of the observer driven sample by sample; a copy of the
    runner goes on as the original."""
    import copy
    from fto_ros.runner import loop as L
    flat = _stand_in_flat(monkeypatch)
    runner, block_runner = Runner(flat), Runner(flat)
    assert type(runner) is Runner and type(runner.observer) is TrackKernelObserver
    direct = TrackObserver(runner.observer_config)
    direct.reset()
    t, y, u = _stream(seed=2, n=3000)
    kind = np.tile(np.array([L.INPUT, L.MEASUREMENT], np.int8), len(t))
    blk = block_runner.process_block(kind, np.repeat(t, 2),
                                     np.stack([u[:, 0], y[:, 0]], axis=1).reshape(-1, 1))
    twin, gated = None, 0
    for k in range(len(t)):
        if k == 2000:
            twin = copy.deepcopy(runner)
        outs = []
        for r in (runner, twin) if twin is not None else (runner,):
            r.set_input(t[k], u[k])
            outs.append(r.process(t[k], y[k]))
        out = outs[0]
        assert blk.status[2 * k + 1, 0] == (L.OUTPUT if isinstance(out, Output)
                                            else CODE[out]), k
        if not isinstance(out, Output):               # the outlier gate: the jump
            assert out == "outlier", (k, out)
            gated += 1
            continue
        direct.update_checked(t[k], y[k], u[k])
        np.testing.assert_array_equal(out.estimate, direct.estimate)
        np.testing.assert_array_equal(blk.estimate[2 * k + 1, 0], out.estimate)
        np.testing.assert_array_equal(blk.convergence[2 * k + 1, 0], out.convergence)
        assert out.convergence[5:].tolist() == list(direct.convergence_extra())
        if len(outs) > 1:
            np.testing.assert_array_equal(outs[1].convergence, out.convergence)
    assert gated and runner.observer.diagnostics()["mode"] in ("tracking", "re-acquiring")
    np.testing.assert_array_equal(twin.observer.estimate, runner.observer.estimate)
    assert max(blk.convergence[:, 0, 6]) >= 1                      # hand-overs


def test_the_compiled_composition_runs_per_joint(monkeypatch):
    """Three joints' compositions in one runner (the joints axis: the runner's rows of
    every array, each joint's model list its own): each joint's outputs are those of a
    runner of that joint alone, bit for bit, through its hand-over."""
    flat = _stand_in_flat(monkeypatch)
    multi = Runner(dict(flat, joints=["j1", "j2", "j3"], source="joint_states"))
    alone = [Runner(flat) for _ in range(3)]
    assert multi.n_joints == 3 and type(multi.observer) is TrackKernelObserver
    t, y, u = _stream(seed=5, n=1500)
    ys = y + np.array([0.0, 0.01, -0.02])            # three joints, three measurements
    for k in range(len(t)):
        outs = multi.process_joints(t[k], ys[k][:, None], np.repeat(u[k][None, :], 3, axis=0))
        for j, r in enumerate(alone):
            r.set_input(t[k], u[k])
            ref = r.process(t[k], ys[k, j:j + 1])
            assert isinstance(outs[j], Output) and isinstance(ref, Output), (k, j)
            np.testing.assert_array_equal(outs[j].estimate, ref.estimate)
            np.testing.assert_array_equal(outs[j].convergence, ref.convergence)
    assert all(o.observer.diagnostics()["mode"] == "tracking" for o in alone)
    assert [o.diagnostics()["mode"] for o in multi.observers] == ["tracking"] * 3


def test_the_composition_is_compiled_when_its_acquirer_is():
    """The committed configs run the compiled composition once their acquirer family is a
    compiled kernel, the Python one (legacy.py) before."""
    obs = _runner().observer
    expected = TrackKernelObserver if compiled_child(SingleDelayObserver) else LegacyTrackObserver
    assert type(obs) is expected and isinstance(obs, TrackObserver)
    assert not compiled_child(LegacyTrackObserver)


def test_the_window_sum_is_math_fsum():
    """The window's once-per-fill exact sum (kernel.exact_sum) is math.fsum, also on sums
    that cancel and span many magnitudes (the window's terms are >= 0; the algorithm is not
    restricted to them)."""
    rng = np.random.default_rng(4)
    cap = 301
    for trial in range(200):
        count = int(rng.integers(1, cap))
        terms = rng.standard_normal(count) * 10.0 ** rng.integers(-30, 30, count)
        if trial % 2:
            terms = np.abs(terms)
        wk = np.zeros(cap + TK.PARTIALS)
        head = int(rng.integers(0, cap))
        for q in range(count):
            wk[(head - count + q) % cap] = terms[q]
        assert TK.exact_sum(wk, 0, cap, head, count, cap) == math.fsum(terms), trial


def _asks_forever(op, st, nx, c, ic, wk, a, b, y, u, models):
    """A broken composition kernel: it asks for its acquirer's sample again and again."""
    rq = ic[ic[K.COMPOSED] + K.TAB_REQUEST]
    wk[rq + K.RQ_CHILD] = 1.0
    wk[rq + K.RQ_OP] = K.CALL_UPDATE
    return K.CALL


def test_a_composition_that_never_decides_is_stopped():
    """More than MAX_CALLS calls in one sample: the sample is rejected (observer_error) with
    the state as it was, instead of a loop without end."""
    from fto_ros.core import jit as J
    obs = TrackObserver(_composition_cfg(True, "ekf"))
    t, y, u = _stream(n=20)
    for k in range(10):
        obs.update_checked(t[k], y[k], u[k])
    before = obs._st.copy()
    kids = [J.kernel(_asks_forever, J.KERNEL)] + \
        [J.kernel(kid.KERNEL.kernel, J.KERNEL) for kid in (obs.acquirer, obs.tracker)]
    obs._kernels = J.function_list(kids, J.KERNELS)
    with pytest.raises(SampleRejected) as err:
        obs.update_checked(t[10], y[10], u[10])
    assert err.value.reason == "observer_error"
    np.testing.assert_array_equal(obs._st, before)
