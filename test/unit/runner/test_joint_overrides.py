"""joint_overrides: observer parameters that differ per joint ('section.name=[v_1, ..., v_J]'),
what fto-tune writes: each joint's observer gets its own value, a scalar stands for a
one-element array, malformed entries are refused naming the entry, and the setting needs
the per-joint mode."""
from __future__ import annotations

from pathlib import Path

import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.runner import Runner
from fto_ros.runner.joints import overrides_by_joint
from fto_ros.runner.params_file import load_params_files

ROOT = Path(__file__).resolve().parents[3]
ARM = [ROOT / "config" / "arm7_plant.yaml"]


def flat(tuning: str, **extra):
    f = load_params_files(ARM + [ROOT / "config" / f"arm7_{tuning}.yaml"])
    f.update(extra)
    return f


def test_each_joint_gets_its_value():
    bw = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0]
    r = Runner(flat("joint_kalman", joint_overrides=[
        "joint_kalman.bandwidth=" + str(bw), "joint_kalman.order=[2, 2, 2, 2, 2, 2, 2]"]))
    assert [o.bandwidth[0] for o in r.observers] == bw
    assert {o.order for o in r.observers} == {2}


def test_array_values_per_joint():
    poles = [[-60.0 - k, -70.0 - k] for k in range(7)]
    r = Runner(flat("hosm", joint_overrides=[f"hosm.poles={poles}"]))
    diag = [o.diagnostics()["Luenberger poles"] for o in r.observers]
    assert diag[0] == "-70, -60" and diag[6] == "-76, -66" and len(set(diag)) == 7


@pytest.mark.parametrize("entry, needle", [
    ("joint_kalman.bandwidth=[1, 2]", "7 values"),
    ("joint_kalman.bandwidth", "not an observer parameter"),
    ("joint_kalman.nothing=[1, 2, 3, 4, 5, 6, 7]", "not an observer parameter"),
    ("nothing.bandwidth=[1, 2, 3, 4, 5, 6, 7]", "not an observer parameter"),
    ("joint_kalman.bandwidth=[1, 2, 3, 4, 5, 6, x]", "7 values"),
    ("joint_kalman.bandwidth=[1, 2, 3, 4, 5, 6, [[7]]]", "7 values"),
    ("joint_kalman.bandwidth=[1, 2, 3, 4, 5, 6, 1e999]", None),
])
def test_malformed_entries_are_refused(entry, needle):
    with pytest.raises(ConfigError) as err:
        Runner(flat("joint_kalman", joint_overrides=[entry]))
    if needle:
        assert err.value.parameter == "joint_overrides[0]" and needle in err.value.problem


def test_twice_and_without_joints_refused():
    with pytest.raises(ConfigError, match="twice"):
        overrides_by_joint(["joint_kalman.order=[2]", "joint_kalman.order=[3]"], 1)
    f = load_params_files([ROOT / "config" / "dc_motor_plant.yaml",
                           ROOT / "config" / "dc_motor_luenberger.yaml"])
    f["joint_overrides"] = ["luenberger.design=[1]"]
    with pytest.raises(ConfigError) as err:
        Runner(f)
    assert err.value.parameter == "joint_overrides"


def test_a_runtime_change_takes_new_values():
    r = Runner(flat("joint_kalman"))
    new = flat("joint_kalman", joint_overrides=["joint_kalman.bandwidth=[5, 5, 5, 5, 5, 5, 9]"])
    r.reconfigure(new)
    assert [o.bandwidth[0] for o in r.observers] == [5.0] * 6 + [9.0]
