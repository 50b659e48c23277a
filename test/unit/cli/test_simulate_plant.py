"""fto-simulate --params: a user's plant block simulated into a bag of the package's layout."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from scipy.integrate import solve_ivp

from fto_ros.bag import read_messages
from fto_ros.cli import simulate

PLANT = """\
/**:
  ros__parameters:
    plant:
      states: [theta, omega]
      inputs: [tau]
      unknown_inputs: [d]
      constants: ["g=9.81", "l=0.5", "c=0.4", "J=0.2"]
      f: ["omega", "-g/l*sin(theta) - c*omega + (tau + d)/J"]
      h: ["theta"]
fto_simulate:
  ros__parameters:
    simulation:
      system: pendulum
      duration: 1.0
      rate: 200.0
      initial_state: [1.0, 0.0]
      input: ["0.3*sin(2*t)"]
      unknown_input: ["0.05*sin(5*t)"]
      noise: [0.01]
      seed: 4
      joint_names: [joint1]
"""


def rhs(u_of_t, held_at=None):
    def f(t, x):
        tk = t if held_at is None else held_at
        u = u_of_t(tk)
        return [x[1], -9.81 / 0.5 * math.sin(x[0]) - 0.4 * x[1] + (u + 0.05 * math.sin(5 * t)) / 0.2]
    return f


def topics(bag):
    out: dict = {}
    for topic, t, msg in read_messages(bag):
        out.setdefault(topic, []).append((t * 1e-9, msg))
    return out


def test_a_plant_block_becomes_a_bag_with_ground_truth(tmp_path, capsys):
    (tmp_path / "p.yaml").write_text(PLANT)
    bag = tmp_path / "bag"
    assert simulate.main(["--params", str(tmp_path / "p.yaml"), "--out", str(bag)]) == 0
    got = topics(bag)
    assert {k: len(v) for k, v in got.items()} == {
        "/clock": 201, "/pendulum/input": 201, "/pendulum/measured_output": 201,
        "/pendulum/joint_states": 201, "/pendulum/true_state": 201,
        "/pendulum/true_unknown_input": 201}
    t = np.array([s for s, _ in got["/pendulum/true_state"]])
    x = np.array([m.data for _, m in got["/pendulum/true_state"]])
    u = np.array([m.data[0] for _, m in got["/pendulum/input"]])
    assert np.allclose(u, 0.3 * np.sin(2 * t))
    d = np.array([m.data[0] for _, m in got["/pendulum/true_unknown_input"]])
    assert np.allclose(d, 0.05 * np.sin(5 * t))
    # the truth: the plant with u held between the 200 Hz samples (zoh), checked against an
    # independent integration of the same equations written out here
    xs = [np.array([1.0, 0.0])]
    for k in range(200):
        sol = solve_ivp(rhs(lambda s: 0.3 * math.sin(2 * s), held_at=t[k]), (t[k], t[k + 1]),
                        xs[-1], rtol=1e-11, atol=1e-12)
        xs.append(sol.y[:, -1])
    assert np.max(np.abs(np.array(xs) - x)) < 1e-7
    y = np.array([m.data[0] for _, m in got["/pendulum/measured_output"]])
    assert 0.006 < np.std(y - x[:, 0]) < 0.014                # sigma = 0.01
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    settings = json.loads(meta["rosbag2_bagfile_information"]["custom_data"]["fto_ros.simulation"])
    assert settings["plant"]["f"][1].startswith("-g/l*sin(theta)") and settings["seed"] == 4


def test_smooth_input_and_command_line_overrides(tmp_path):
    (tmp_path / "p.yaml").write_text(PLANT)
    bag = tmp_path / "bag"
    assert simulate.main(["--params", str(tmp_path / "p.yaml"), "--out", str(bag), "--noise", "0",
                          "--set", "simulation.input_hold=smooth", "--duration", "0.5"]) == 0
    got = topics(bag)
    x = np.array([m.data for _, m in got["/pendulum/true_state"]])
    sol = solve_ivp(rhs(lambda s: 0.3 * math.sin(2 * s)), (0.0, 0.5), [1.0, 0.0], rtol=1e-11,
                    atol=1e-12, t_eval=np.arange(101) / 200)
    assert x.shape == (101, 2) and np.max(np.abs(sol.y.T - x)) < 1e-7
    y = np.array([m.data[0] for _, m in got["/pendulum/measured_output"]])
    assert np.array_equal(y, x[:, 0])                           # --noise 0 overrides


@pytest.mark.parametrize("change, parameter", [
    ({"system": ""}, "simulation.system"),
    ({"input": ["0.3*sin(2*s)"]}, "simulation.input[0]"),
    ({"initial_state": [1.0]}, "simulation.initial_state"),
    ({"noise": [0.1, 0.2, 0.3]}, "simulation.noise"),
    ({"durations": 2.0}, "simulation.durations"),
])
def test_bad_simulation_parameters_exit_2_in_one_line(tmp_path, capsys, change, parameter):
    doc = yaml.safe_load(PLANT)
    doc["fto_simulate"]["ros__parameters"]["simulation"].update(change)
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(doc))
    rc = simulate.main(["--params", str(tmp_path / "p.yaml"), "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and f"'{parameter}'" in err, err
    assert not (tmp_path / "b").exists()
