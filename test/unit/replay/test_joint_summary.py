"""The per-joint replay's summary and metrics (issue 26 item 5): each quantity in its own
unit (rad, rad/s, N m never pooled into one norm), no bare None per joint."""
from __future__ import annotations

from pathlib import Path

import joint_streams as JS
from fto_ros.replay.cli import summary
from fto_ros.replay.replay import replay

ROOT = Path(__file__).resolve().parents[3]


def test_fields_in_their_units(tmp_path):
    bag = JS.write_bag(tmp_path / "bag", JS.stream(3, duration=1.0))
    params = [ROOT / "config" / "arm7_plant.yaml", ROOT / "config" / "arm7_joint_kalman.yaml"]
    m = replay(bag, params, tmp_path / "out", progress=False, plot=False)
    je = m["joint_errors"]
    assert je["fields"] == ["position", "velocity"]
    assert je["units"] == {"position": "rad", "velocity": "rad/s"}
    for entry in list(je["per_joint"].values()) + [je["all_joints"]]:
        assert "norm" not in entry and set(entry["per_state"]) == {"position", "velocity"}
    text = summary(m)
    assert "None" not in text
    assert "position [rad], velocity [rad/s]" in text
    assert text.count("joint_a") == 7 and "all joints" in text


def test_one_observer_with_mixed_units_has_no_norm(tmp_path):
    params = [ROOT / "config" / "dc_motor_plant.yaml", ROOT / "config" / "dc_motor_luenberger.yaml"]
    m = replay(ROOT / "bags" / "dc_motor_nominal", params, tmp_path / "out", progress=False,
               plot=False)
    e = m["errors"]
    assert e["units"] == {"q": "rad", "q_dot": "rad/s", "current": "A"}
    assert "norm" not in e and "norm_note" in e
