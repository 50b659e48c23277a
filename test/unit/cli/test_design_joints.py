"""fto-design on a per-joint plant (issue 26 item 5): config/arm7_plant.yaml (constants
'name=[v1, ..., vJ]') used to fail with "'List' is not allowed in a model expression"; now
it designs joint by joint and prints the joint table."""
from __future__ import annotations

import io
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

from fto_ros.cli.design import main

ROOT = Path(__file__).resolve().parents[3]
CONFIG = ROOT / "config"


def run(*args):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main([str(a) for a in args])
    return rc, out.getvalue(), err.getvalue()


def test_the_plant_file_alone():
    rc, out, err = run(CONFIG / "arm7_plant.yaml")
    assert rc == 0 and err == "", err
    assert "per-joint plant: 7 joints" in out and "List" not in out
    assert "    joint_a7  J=0.0619, b=0.1, fc=0.15, kt=1.0" in out
    assert "joint_kalman      applies" in out and "ekf               applies" in out
    # the derived value that differs per joint gets a joint table (the EKF's constants)
    assert "  constants per joint:" in out
    assert "[J=3.9137, b=1.0, fc=1.2, kt=1.0, w=0.02]" in out


def test_tuning_files_per_joint():
    rc, out, err = run(CONFIG / "arm7_plant.yaml", CONFIG / "arm7_luenberger.yaml",
                       CONFIG / "arm7_joint_kalman.yaml", CONFIG / "arm7_hosm.yaml")
    assert rc == 0 and err == "", err
    assert "== luenberger (arm7_luenberger.yaml), joint_a1: the observer built" in out
    assert "  observer gain L per joint:" in out
    assert "== joint_kalman (arm7_joint_kalman.yaml), joint_a1" in out
    assert "  bandwidth (Hz): 60" in out and "  NIS mean since reset: nan over 0 updates" in out


def test_a_refused_tuning_file_is_exit_2():
    bad = ROOT / "config" / "arm7_hosm.yaml"
    rc, out, err = run(CONFIG / "arm7_plant.yaml", bad, "--set", "joints:=[a, a]")
    assert rc == 2 and "listed twice" in err
