"""fto-design: what the plant block derives, per observer type, without running anything."""
from __future__ import annotations

from pathlib import Path

import pytest

from fto_ros.cli import design

ROOT = Path(__file__).resolve().parents[3]
PLANT = str(ROOT / "config" / "dc_motor_plant.yaml")


def test_dc_motor_design(capsys):
    rc = design.main([PLANT, str(ROOT / "config" / "dc_motor_single_delay.yaml"),
                      str(ROOT / "config" / "dc_motor_hosm.yaml")])
    out = capsys.readouterr().out
    assert rc == 0
    # which types apply, and the one line for the others
    assert "  luenberger        applies" in out
    assert "global_norm       does not apply: parameter 'plant.f[1]': global_norm needs the " \
           "plant in observability form" in out
    # derived forms: the paper's eq. (67), the canonical form and its conditioning
    assert "single_delay.A1 (2x2) =\n      [-1, 15]\n      [-36.4, -200]" in out
    assert "prescribed_time.a = [201, 746, 0]" in out and "cond(T): 2.102e+06" in out
    assert "invariant zeros: -200" in out
    # the observers built from the derived parameters, with their design figures
    assert "guaranteed time: 0.1 s" in out and "noise gain" in out and "cond(S)" in out
    assert "M check: M[0] = 100 > 25.5" in out


def test_bad_input_exits_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad_plant.yaml"
    bad.write_text("/**:\n  ros__parameters:\n    plant:\n      states: [x]\n"
                   "      f: ['-x + y']\n      h: [x]\n")
    assert design.main([str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'plant.f[0]'" in err and "unknown name(s) y" in err
    assert design.main([str(tmp_path / "missing.yaml")]) == 2
    tuning = tmp_path / "gn.yaml"
    tuning.write_text("observer_node:\n  ros__parameters:\n    observer: {type: global_norm}\n")
    assert design.main([PLANT, str(tuning)]) == 2           # the plant is outside its class
    assert "'plant.f[1]'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        design.main([])
    assert e.value.code == 2
