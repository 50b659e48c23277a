"""``fto-simulate --urdf`` on the arm class of docs/arm_class.md: each option of a real arm's
stream does what it says in the bag it writes, the drawn parameters are recorded, and bad
values are refused in one line with exit code 2."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fto_ros.bag import BagReader
from fto_ros.cli.arm_bag import read_arm_bag
from fto_ros.cli.simulate import main
from fto_ros.models.arm_urdf import without_mimic
from fto_ros.arm import load_model

ROOT = Path(__file__).resolve().parents[2]
URDF = ROOT / "urdf" / "panda_gripper.urdf"
ARM = [f"panda_joint{i}" for i in range(1, 8)]
FINGERS = ["panda_finger_joint1", "panda_finger_joint2"]


def simulate(out: Path, *args) -> int:
    """The exit code (argparse's refusals exit through SystemExit)."""
    try:
        return main(["--urdf", str(URDF), "--out", str(out), *args])
    except SystemExit as done:
        return done.code


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("armclass")
    runs = {
        "stream": ["--duration", "0.6", "--seed", "3", "--jitter", "50", "--stamp-noise", "20",
                   "--loss", "0.05", "--loss-burst", "3", "--effort", "commanded_no_gravity",
                   "--topic", "franka/joint_states", "--gripper-period", "0.5"],
        "measured": ["--duration", "0.3", "--effort", "measured", "--friction", "0.5,1,0.5,1",
                     "--model-error", "0.05", "--model-seed", "4"],
        "current": ["--duration", "0.2", "--effort", "current", "--kt",
                    "0.1,0.1,0.1,0.1,0.2,0.2,0.2", "--gear", "100,100,100,100,80,80,80"],
    }
    for name, args in runs.items():
        assert simulate(d / name, *args) == 0
    return d


def test_the_stream_jitter_stamp_noise_losses_topic_and_fingers(bags):
    with BagReader(bags / "stream") as bag:
        topics = set(bag.topics)
    assert "/franka/joint_states" in topics and "/arm/joint_states" not in topics
    run, meta = read_arm_bag(bags / "stream")
    assert run.names == tuple(ARM + FINGERS) and meta["driven"] == ARM
    assert meta["samples"] == 601 and run.t.size == 601 - meta["stream"]["lost"]
    lost = np.setdiff1d(np.arange(601), run.index)
    assert lost.size == meta["stream"]["lost"] >= 10               # ~5 % of 601
    runs = np.diff(np.flatnonzero(np.diff(np.r_[-2, lost]) > 1).tolist() + [lost.size])
    assert runs.max() <= 3
    u = run.t - run.index * 1e-3                                    # the actual instants
    assert np.abs(u).max() <= 50e-6 + 1e-9 and u.std() > 20e-6
    e = run.stamp_ns * 1e-9 - run.t                                 # the stamps' error
    assert np.abs(e).max() <= 20e-6 + 2e-9 and e.std() > 8e-6
    f1, f2 = run.names.index(FINGERS[0]), run.names.index(FINGERS[1])
    np.testing.assert_array_equal(run.q_measured[:, f2], run.q_measured[:, f1])  # the mimic
    assert np.ptp(run.q_measured[:, f1]) > 0.02                     # the gripper moved
    assert np.all(run.effort[:, f1] == 0) and np.all(run.effort[:, f2] == 0)
    # effort = commanded - g(q_m), g of the URDF as given at the positions of the message
    nominal = load_model(ARM + FINGERS, robot_description=without_mimic(URDF.read_text()))
    g = np.array([nominal.gravity(q)[:7] for q in run.q_measured])
    np.testing.assert_allclose(run.effort[:, :7] + g, run.tau[:, :7], rtol=0, atol=1e-9)
    assert np.abs(g).max() > 10


def test_measured_torque_is_the_command_less_the_recorded_friction(bags):
    run, meta = read_arm_bag(bags / "measured")
    fr = meta["friction"]
    b, c, w = np.array(fr["viscous"]), np.array(fr["coulomb"]), fr["width"]
    assert np.all((0.5 <= b[:7]) & (b[:7] <= 1) & (0.5 <= c[:7]) & (c[:7] <= 1))
    assert np.all(b[7:] == 0) and np.all(c[7:] == 0) and fr["drawn"] == [0.5, 1, 0.5, 1]
    tau_f = b * run.v + c * np.tanh(run.v / w)
    np.testing.assert_allclose(run.effort[:, :7] + tau_f[:, :7], run.tau[:, :7], rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose(run.tau_j, run.effort, rtol=0, atol=1e-12)
    assert np.abs(tau_f[:, :7]).max() > 0.3
    links = meta["model_error"]["links"]
    assert meta["model_error"]["error"] == 0.05 and len(links) == 11
    assert all(0.95 <= r["mass_scale"] <= 1.05 and 0.95 <= r["inertia_scale"] <= 1.05
               for r in links.values())


def test_model_error_and_friction_are_drawn_by_the_model_seed(bags, tmp_path):
    _, first = read_arm_bag(bags / "measured")
    args = ["--duration", "0.01", "--friction", "0.5,1,0.5,1", "--model-error", "0.05"]
    assert simulate(tmp_path / "same", *args, "--model-seed", "4") == 0
    assert simulate(tmp_path / "other", *args, "--model-seed", "5", "--seed", "4") == 0
    _, same = read_arm_bag(tmp_path / "same")
    _, other = read_arm_bag(tmp_path / "other")
    for key in ("model_error", "friction"):
        assert json.dumps(same[key]) == json.dumps(first[key])
        assert json.dumps(other[key]) != json.dumps(first[key])


def test_current_times_kt_and_gear_is_the_motor_torque(bags):
    run, meta = read_arm_bag(bags / "current")
    kt = np.array([0.1] * 4 + [0.2] * 3)
    gear = np.array([100.0] * 4 + [80.0] * 3)
    assert meta["stream"]["kt"] == kt.tolist() and meta["stream"]["effort"] == "current"
    np.testing.assert_allclose(run.effort[:, :7] * kt * gear, run.tau[:, :7], rtol=1e-12,
                               atol=1e-12)
    assert np.abs(run.tau[:, :7]).max() > 10


@pytest.mark.parametrize("args, words", [
    (["--jitter", "500"], "half the period"),
    (["--jitter", "300", "--stamp-noise", "250"], "half the period"),
    (["--jitter", "-1"], "must be a finite number >= 0"),
    (["--loss", "1"], "probability"),
    (["--loss-burst", "0"], "integer >= 1"),
    (["--model-error", "1.5"], "relative error"),
    (["--friction", "1,2,3"], "VISC_LO"),
    (["--friction", "2,1,0,1"], "LO <= HI"),
    (["--effort", "torque"], "invalid choice"),
    (["--kt", "0"], "must be > 0"),
    (["--gear", "100,100"], "one value or one per driven joint (7)"),
    (["--topic", "a b"], "not a ROS topic name"),
    (["--gripper-period", "-1"], "must be a finite number >= 0"),
    (["--q0", "0,0"], "one value or one per driven joint"),
    (["--amplitude", "0,0,0,5,0,0,0"], "outside its limits"),
    (["--joints", "panda_finger_joint2"], "mimic joint of panda_finger_joint1"),
    (["--period", "0"], "must be > 0"),
    (["--substeps", "0"], "integer >= 1"),
])
def test_bad_values_are_refused_in_one_line(tmp_path, capsys, args, words):
    assert simulate(tmp_path / "x", "--duration", "0.01", *args) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err, err
    assert not (tmp_path / "x").exists()


def test_locking_the_parent_finger_locks_its_mimic(tmp_path):
    assert simulate(tmp_path / "locked", "--duration", "0.02",
                    "--lock", "panda_finger_joint1=0.03") == 0
    run, meta = read_arm_bag(tmp_path / "locked")
    assert run.names == tuple(ARM)
    assert meta["locked_joints"] == {"panda_finger_joint1": 0.03, "panda_finger_joint2": 0.03}
