"""The issue's expensive expressions (F5, F6) and the name "q\\n" (F20) through fto-design,
as a user's params file reaches them: each refused with one line naming the parameter, exit
2, within the subprocess's 20 s (before the budget, fto-design ran past 120-180 s with no
output).  No timing is asserted beyond that bound."""
from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
PLANT = REPO / "config" / "dc_motor_plant.yaml"


def plant_with(tmp_path: Path, key: str, index: int, text: str) -> Path:
    doc = yaml.safe_load(PLANT.read_text())
    plant = copy.deepcopy(doc)["/**"]["ros__parameters"]["plant"]
    plant[key][index] = text
    doc["/**"]["ros__parameters"]["plant"] = plant
    path = tmp_path / "plant.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("key,index,text,parameter,words", [
    ("constants", 0, "b0=((10**300)**1000)**1000", "plant.constants[0]", "exponent"),
    ("constants", 5, "a4=exp(exp(exp(exp(exp(exp(1))))))", "plant.constants[5]", "nested"),
    ("f", 1, "(q_dot + current + q + V)**300", "plant.f[1]", "terms"),
    ("f", 2, "(q + V + 1)**1000*current", "plant.f[2]", "terms"),
    ("states", 0, "q\n", "plant.states", "not a valid name"),
])
def test_fto_design_refuses_in_one_line(tmp_path, key, index, text, parameter, words):
    params = plant_with(tmp_path, key, index, text)
    env = dict(os.environ, FTO_ROS_NUMBA="0", FTO_ROS_CACHE=str(tmp_path / "cache"))
    res = subprocess.run([sys.executable, "-m", "fto_ros.cli.design", str(params)],
                         capture_output=True, text=True, timeout=20, env=env, cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith(f"fto-design: error: parameter '{parameter}'")
    assert words in lines[0] and "Traceback" not in res.stderr
