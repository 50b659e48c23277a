"""The replay tests' DC-motor bag (test/unit/replay/, test/unit/cli/test_report.py): 2 s at
1 kHz of config/dc_motor_luenberger_poles.yaml's plant from x(0) = (0.5, -1, 0.2) under the
model's default voltage, no noise, written with fto_ros.bag.BagWriter (measured_output, input,
joint_states with position = q and effort = V, true_state, /clock, all at the sample times);
``replay_estimates``, what test_replay.py's determinism test runs in two processes."""
from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from fto_ros.bag import BagReader, BagWriter
from fto_ros.models import dc_motor, simulate
from fto_ros.models.simulate import uniform_grid
from fto_ros.replay import replay

REPO = Path(__file__).resolve().parents[2]
LUENBERGER = REPO / "test" / "data" / "dc_motor_explicit" / "dc_motor_luenberger_poles.yaml"  # poles -50..-70: the bounds below
NS = "/dc_motor"
RATE = 1000.0
DURATION = 2.0


def simulate_motor():
    """The bag's samples: fto_ros.models.simulate of the DC motor over DURATION at RATE."""
    t = uniform_grid(DURATION, RATE)
    return simulate(dc_motor.make_rhs(), dc_motor.DEFAULT_X0, t, dc_motor.default_voltage,
                    output=dc_motor.output)


def write_bag(path: Path, sim, *, bad: bool = False, truth: bool = True,
              measured_topic: str = f"{NS}/measured_output") -> Path:
    """The test bag; ``bad`` adds a NaN and a wrong-length measurement, a repeated stamp
    and a NaN input."""
    ns_of = [int(round(t * 1e9)) for t in sim.t]
    with BagWriter(path) as bag:
        for k, t_ns in enumerate(ns_of):
            bag.clock(t_ns)
            u = sim.u[k]
            y = sim.y[k]
            if bad and k == 800:
                u = [math.nan]
            bag.float_array(f"{NS}/input", t_ns, u)
            if bad and k == 500:
                y = [math.nan]
            elif bad and k == 600:
                y = [float(sim.y[k][0]), 0.0]
            bag.float_array(measured_topic, t_ns, y)
            if bad and k == 700:
                bag.float_array(measured_topic, t_ns, sim.y[k])  # same stamp again
            bag.joint_state(f"{NS}/joint_states", t_ns, t_ns, ["joint1"], position=sim.y[k],
                            effort=sim.u[k])
            if truth:
                bag.float_array(f"{NS}/true_state", t_ns, sim.x[k])
    return path


def read_topic(path: Path, topic: str):
    with BagReader(path) as b:
        return [(t, msg) for _, t, msg in b.messages([topic])]


def replay_estimates(bag: str, folder: str) -> dict[str, np.ndarray]:
    """A replay of ``bag`` with LUENBERGER into a new folder under ``folder``: its estimates,
    convergence values and error metrics (what must not change from one process to another)."""
    out = Path(tempfile.mkdtemp(dir=folder)) / "out"
    m = replay(Path(bag), LUENBERGER, out, progress=False, plot=False)
    est = np.array([msg.data for _, msg in read_topic(out, "/observer_node/state_estimate")])
    conv = np.array([msg.data for _, msg in read_topic(out, "/observer_node/convergence")])
    return {"estimate": est, "convergence": conv,
            "errors": np.array(json.dumps(m["errors"], sort_keys=True)),
            "convergence_time_s": np.array(m["convergence_time_s"], dtype=float)}


# -- fixtures (import them into a test module to use them) ------------------------------------
@pytest.fixture(scope="module")
def sim():
    """The bag's samples (``simulate_motor``)."""
    return simulate_motor()


@pytest.fixture(scope="module")
def bag(sim, tmp_path_factory):
    """The clean bag."""
    return write_bag(tmp_path_factory.mktemp("bags") / "dc_motor_test", sim)


@pytest.fixture(scope="module")
def bad_bag(sim, tmp_path_factory):
    """The bag with a NaN and a wrong-length measurement, a repeated stamp, a NaN input."""
    return write_bag(tmp_path_factory.mktemp("bags") / "dc_motor_bad", sim, bad=True)


@pytest.fixture(scope="module")
def run(bag, tmp_path_factory):
    """(output folder, metrics) of the clean bag's replay with LUENBERGER."""
    out = tmp_path_factory.mktemp("replay") / "out"
    metrics = replay(bag, LUENBERGER, out, progress=False)
    return out, metrics
