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
- the compiled composition against its rules in Python, in the runner's block loop, per
  joint, with a mapped acquirer: test/unit/observers/test_track_composition.py.
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
