"""The offline replay harness (`fto-replay`): its output bag, metrics and plot, the error after
settling against a bound from the observer's matrices, determinism across processes, bad
samples, the joint_states source, the node name, a bag without truth.  (Its fast paths:
test_replay_fast_paths.py; metrics: test_replay_metrics.py; its command line:
test_replay_cli.py; fto-report: test/unit/cli/test_report.py.)

The bag (test/support/replay_bags.py): a 2 s, 1 kHz DC-motor bag (config/dc_motor_luenberger_poles.yaml's plant, x(0) = (0.5, -1, 0.2),
the model's default voltage profile, no noise) is simulated with fto_ros.models and
written with fto_ros.bag.BagWriter: measured_output, input, joint_states (position = q,
effort = V), true_state and /clock, all at the sample times.

Error bound after settling (test_errors_after_settling_are_small), from the observer's
own matrices rather than a tuned number.  The Luenberger error obeys
    e' = Acl e + L (y - y_foh) + (F(y) - F_foh)(t),     Acl = A - L C,
because the observer integrates exactly with y and F(y) = (0, -35 sin y, 0) held
first-order between samples and the input held zero-order like the simulator.  So
    |e_i(t)| <= kappa(V) e^(-50 t) |e(0)|  +  ||h_i||_1 dy  +  ||g_i||_1 dF
with h = e^(Acl t) L and g = e^(Acl t) (0, 1, 0)^T (their L1 norms over t >= 0),
kappa(V) the eigenvector condition number of Acl (slowest pole -50), and the linear
interpolation errors dy <= h^2/8 max|q''|, dF <= h^2/8 * 35 (max|q''| + max q'^2)
(h = 1 ms).  At t >= 0.5 s the transient term is 3e-6 (kappa = 2e5, e^-25 = 1.4e-11) and
the bound is (6e-6, 2.5e-4, 3e-3) for (q, q_dot, I); the replay measures
(1.2e-6, 4e-5, 4.5e-4), the largest just after the voltage steps.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from fto_ros.bag import BagReader
from fto_ros.core.errors import ConfigError
from fto_ros.models import dc_motor
from fto_ros.replay import replay
from fto_ros.runner.runner import CONVERGENCE_FIELDS, Runner
from fto_ros.runner.settings import load_params_file
from replay_bags import DURATION, LUENBERGER, NS, RATE, read_topic, write_bag
from replay_bags import sim, bag, bad_bag, run  # noqa: F401 (fixtures)
from two_processes import assert_bitwise_equal, run_twice

METRIC_FIELDS = {
    "schema", "bag", "params_file", "params_files", "overrides", "node_name", "observer_type",
    "state_names", "source",
    "input_topics", "output_bag", "output_topics", "plot", "bag_start_s", "bag_duration_s",
    "sample_count", "input_count", "samples_accepted", "samples_rejected", "rejected_by_reason",
    "restarts", "restarts_by_reason", "guaranteed_time_s", "guarantee", "settle_time_s",
    "settle_time_rule", "tolerance", "convergence_time_s", "convergence_time_definition",
    "observer_start_s", "truth_topic", "errors", "errors_note", "update_time_us",
    "observer_update_time_us", "replay_speed_x_realtime", "replay_speed_definition", "timing_s",
    "reader", "decoded_by_rosbags", "diagnostics_levels", "final_status",
    "observer_diagnostics",
}


# ------------------------------------------------------------------ outputs
def test_output_bag_has_one_estimate_per_accepted_sample(run, bag, sim):
    out, m = run
    est = read_topic(out, "/observer_node/state_estimate")
    assert len(est) == m["samples_accepted"] == len(sim.t)
    # log time = sample time = the measurement's log time
    meas_times = [t for t, _ in read_topic(bag, f"{NS}/measured_output")]
    assert [t for t, _ in est] == meas_times
    # one labelled dimension per element, as the node publishes it
    assert [(d.label, d.size, d.stride) for d in est[0][1].layout.dim] == [
        ("q", 1, 1), ("q_dot", 1, 1), ("current", 1, 1)]
    conv = read_topic(out, "/observer_node/convergence")
    assert [d.label for d in conv[0][1].layout.dim] == list(CONVERGENCE_FIELDS)
    with BagReader(out) as b:
        topics = b.topics
    n = len(sim.t)
    assert topics["/observer_node/convergence"].count == n
    assert topics["/observer_node/estimated_joint_states"].count == n
    assert topics["/observer_node/state_estimate_stamped"].count == n
    assert "/observer_node/unknown_input_estimate" not in topics  # Luenberger has none
    assert topics[f"{NS}/true_state"].count == n
    # self-contained: what the estimates were made from is copied, at the same log times
    for topic in (f"{NS}/measured_output", f"{NS}/input"):
        assert [(t, list(m.data)) for t, m in read_topic(out, topic)] == \
            [(t, list(m.data)) for t, m in read_topic(bag, topic)], topic
    assert "ros_distro: jazzy" in (out / "metadata.yaml").read_text()
    # /diagnostics once per second of bag time (t = 1 s, 2 s) plus the final one
    assert topics["/diagnostics"].count == 3
    assert m["output_topics"]["/observer_node/state_estimate"] == n


def test_outputs_match_the_runner_driven_directly(run, sim):
    """The replay gives exactly what the runner gives when driven sample by sample."""
    out, _ = run
    runner = Runner(load_params_file(LUENBERGER))
    ref = []
    for k, t in enumerate(sim.t):
        t_s = int(round(t * 1e9)) / 1e9
        assert runner.set_input(t_s, sim.u[k].tolist()) is None
        ref.append(runner.process(t_s, sim.y[k].tolist()).estimate)
    est = np.array([msg.data for _, msg in read_topic(out, "/observer_node/state_estimate")])
    np.testing.assert_array_equal(est, np.array(ref))


def test_stamped_named_estimate(run, sim):
    """state_estimate_stamped: header stamp = the sample time (the bag's log time), names =
    the state names, position = the estimate; the same values as the labelled array."""
    out, _ = run
    st = read_topic(out, "/observer_node/state_estimate_stamped")
    est = read_topic(out, "/observer_node/state_estimate")
    assert len(st) == len(est)
    for (t, msg), (t_e, arr) in zip(st[::97], est[::97]):
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == t == t_e
        assert list(msg.name) == ["q", "q_dot", "current"] and msg.header.frame_id == ""
        np.testing.assert_array_equal(msg.position, arr.data)
        assert len(msg.velocity) == len(msg.effort) == 0


def test_joint_states_and_truth_copied(run, sim):
    out, _ = run
    js = read_topic(out, "/observer_node/estimated_joint_states")
    est = read_topic(out, "/observer_node/state_estimate")
    t, msg = js[1000]
    assert (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec) == t == est[1000][0]
    assert list(msg.name) == ["joint1"]
    np.testing.assert_array_equal([msg.position[0], msg.velocity[0], msg.effort[0]],
                                  est[1000][1].data)
    truth = np.array([m.data for _, m in read_topic(out, f"{NS}/true_state")])
    np.testing.assert_array_equal(truth, sim.x)
    conv = np.array([m.data for _, m in read_topic(out, "/observer_node/convergence")])
    assert np.all(np.isfinite(conv))
    assert np.all(conv[:, 3] == -1.0)  # no guaranteed time, published as -1 like the node
    diag = read_topic(out, "/diagnostics")
    st = diag[-1][1].status[0]
    assert st.name == "observer_node: observer"
    values = {kv.key: kv.value for kv in st.values}
    assert values["samples accepted"] == str(len(sim.t))
    assert values["messages received: measured_output"] == str(len(sim.t))


def test_metrics_json_fields_and_values(run, sim):
    out, m = run
    on_disk = json.loads((out / "metrics.json").read_text())
    assert set(on_disk) == METRIC_FIELDS
    assert on_disk["samples_accepted"] == m["samples_accepted"]
    assert m["observer_type"] == "luenberger"
    assert m["state_names"] == ["q", "q_dot", "current"]
    assert m["sample_count"] == m["input_count"] == len(sim.t)
    assert m["samples_accepted"] == len(sim.t) and m["samples_rejected"] == 0
    assert m["rejected_by_reason"] == {} and m["restarts"] == 0
    assert m["bag_duration_s"] == pytest.approx(DURATION)
    # no guarantee: the settle time is the fixed 0.11 s, and says so
    assert on_disk["guaranteed_time_s"] is None
    assert m["settle_time_s"] == pytest.approx(0.11) and "fixed" in m["settle_time_rule"]
    assert m["tolerance"] == 1e-2
    # poles -50..-70: the error falls below 1e-2 well before 1 s (measured 0.289 s)
    assert 0.1 < m["convergence_time_s"] < 0.5
    err = m["errors"]
    assert set(err["per_state"]) == {"q", "q_dot", "current"}
    for s in err["per_state"].values():
        assert set(s) == {"rms", "max_abs", "rms_after_settle", "max_abs_after_settle"}
        assert 0 <= s["rms_after_settle"] <= s["max_abs_after_settle"] <= s["max_abs"]
    assert err["matched_samples"] == len(sim.t) and err["unmatched_samples"] == 0
    u = m["update_time_us"]
    assert u["count"] == len(sim.t) and 0 < u["p50"] <= u["p99"]
    assert m["replay_speed_x_realtime"] > 0
    t = m["timing_s"]
    assert t["replay_total"] >= t["runner"] > 0
    assert m["replay_speed_x_realtime"] == pytest.approx(m["bag_duration_s"] / t["replay_total"])
    assert m["reader"] == "MCAP fast path" and m["decoded_by_rosbags"] == 0
    assert m["final_status"]["message"].startswith("converged")
    assert "closed-loop poles" in m["observer_diagnostics"]


def test_plot_written(run):
    out, m = run
    png = out / "replay.png"
    assert m["plot"] == "replay.png"
    assert png.stat().st_size > 10_000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _error_bound(runner: Runner, sim, after: float) -> np.ndarray:
    """The bound of the module docstring, per state."""
    obs = runner.observer
    acl = obs.A - obs.L @ obs.C
    lam, V = np.linalg.eig(acl)
    t = np.linspace(0.0, 1.0, 200_001)  # every mode is below e^-50 of its start by t = 1 s
    dt = t[1] - t[0]
    modes = np.exp(np.outer(t, lam))                           # (N, 3)

    def l1(b):
        c = np.linalg.solve(V, b)
        resp = np.real((modes * c) @ V.T)                      # e^(Acl t) b on the grid
        return np.sum(np.abs(resp), axis=0) * dt * 1.05         # Riemann sum + 5 %

    h1 = l1(obs.L[:, 0])
    g1 = l1(np.array([0.0, 1.0, 0.0]))
    h = 1.0 / RATE
    qdd = np.abs(np.diff(sim.x[:, 1])) / np.diff(sim.t)
    qd2 = sim.x[:, 1] ** 2
    dy = h * h / 8 * qdd.max()
    dF = h * h / 8 * 35.0 * (qdd.max() + qd2.max())
    e0 = np.linalg.norm(np.asarray(dc_motor.DEFAULT_X0))       # the observer starts at 0
    transient = np.linalg.cond(V) * math.exp(np.max(lam.real) * after) * e0
    return transient + h1 * dy + g1 * dF


def test_errors_after_settling_are_small(bag, sim, tmp_path):
    after = 0.5
    m = replay(bag, LUENBERGER, tmp_path / "out", progress=False, after=after, plot=False)
    assert m["settle_time_s"] == after and "given" in m["settle_time_rule"]
    bound = _error_bound(Runner(load_params_file(LUENBERGER)), sim, after)
    assert np.all(bound < [1e-4, 1e-2, 5e-2])  # a bound worth checking
    per = m["errors"]["per_state"]
    measured = np.array([per[s]["max_abs_after_settle"] for s in ("q", "q_dot", "current")])
    assert np.all(measured <= bound), (measured, bound)
    # and far below the initial error (0.5, 1, 0.2)
    assert np.all(measured < [1e-4, 1e-3, 1e-2])


def test_deterministic(bag, tmp_path):
    """The same replay in two fresh processes (their own imports, caches and string-hash
    seeds): the same estimates, convergence values and error metrics, bit for bit."""
    a, b = run_twice("replay_bags:replay_estimates", str(bag), str(tmp_path))
    assert a["estimate"].shape == (int(DURATION * RATE) + 1, 3)
    assert assert_bitwise_equal(a, b) > 3 * len(a["estimate"])


def test_bad_samples_are_rejected_and_counted(bad_bag, sim, tmp_path):
    out = tmp_path / "out"
    m = replay(bad_bag, LUENBERGER, out, progress=False, plot=False)
    assert m["rejected_by_reason"] == {"input_non_finite": 1, "measurement_non_finite": 1,
                                       "measurement_wrong_length": 1, "repeated_stamp": 1}
    assert m["samples_rejected"] == 4
    n_meas = len(sim.t) + 1  # one extra message with a repeated stamp
    assert m["sample_count"] == n_meas
    assert m["samples_accepted"] == n_meas - 3
    est = read_topic(out, "/observer_node/state_estimate")
    assert len(est) == m["samples_accepted"]
    times = [t for t, _ in est]
    assert len(set(times)) == len(times)
    assert 500_000_000 not in times and 600_000_000 not in times
    for topic in ("/observer_node/state_estimate", "/observer_node/convergence"):
        data = np.array([msg.data for _, msg in read_topic(out, topic)])
        assert np.all(np.isfinite(data)), topic
    js = read_topic(out, "/observer_node/estimated_joint_states")
    assert all(np.all(np.isfinite(np.r_[m_.position, m_.velocity, m_.effort])) for _, m_ in js)
    diag = read_topic(out, "/diagnostics")
    values = {kv.key: kv.value for kv in diag[0][1].status[0].values}
    assert values["rejected: measurement_non_finite"] == "1"
    assert diag[0][1].status[0].level == 1  # WARN in the second with rejections
    # the estimate still converges: the bad samples did not corrupt it
    assert m["errors"]["per_state"]["current"]["max_abs"] > 1  # the start-up transient
    assert m["convergence_time_s"] is not None and m["convergence_time_s"] < 0.5


def test_joint_states_source_gives_the_same_estimates(bag, run, tmp_path):
    doc = yaml.safe_load(LUENBERGER.read_text())
    p = doc["observer_node"]["ros__parameters"]
    p["source"] = "joint_states"
    p["joint_states"].update(input_joints=["joint1"], input_field="effort")
    params = tmp_path / "js.yaml"
    params.write_text(yaml.safe_dump(doc))
    m = replay(bag, params, tmp_path / "out", progress=False, plot=False)
    assert m["source"] == "joint_states" and m["samples_accepted"] == run[1]["samples_accepted"]
    e1 = np.array([x.data for _, x in read_topic(run[0], "/observer_node/state_estimate")])
    e2 = np.array([x.data for _, x in read_topic(tmp_path / "out",
                                                  "/observer_node/state_estimate")])
    np.testing.assert_array_equal(e1, e2)


def test_node_name_sets_the_output_namespace(bag, tmp_path):
    # the config's block is for /observer_node: as ROS does, another node gets nothing from it
    with pytest.raises(ConfigError, match="none is for node '/robot/motor_observer'"):
        replay(bag, LUENBERGER, tmp_path / "refused", node_name="/robot/motor_observer",
               progress=False, plot=False)
    params = tmp_path / "renamed.yaml"
    params.write_text(Path(LUENBERGER).read_text().replace("observer_node:", "/robot/motor_observer:"))
    m = replay(bag, params, tmp_path / "out", node_name="/robot/motor_observer",
               progress=False, plot=False)
    assert m["node_name"] == "/robot/motor_observer"
    with BagReader(tmp_path / "out") as b:
        assert "/robot/motor_observer/state_estimate" in b.topics


def test_no_truth_gives_metrics_without_errors(sim, tmp_path):
    bag = write_bag(tmp_path / "notruth", sim, truth=False)
    m = replay(bag, LUENBERGER, tmp_path / "out", progress=False)
    assert m["errors"] is None and m["convergence_time_s"] is None
    assert "no ground truth" in m["errors_note"]
    assert m["samples_accepted"] == len(sim.t)
    assert (tmp_path / "out" / "replay.png").stat().st_size > 0
