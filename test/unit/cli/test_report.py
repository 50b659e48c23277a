"""fto-report (fto_ros/cli/report.py): the plan pairs bags with configs (and notes a config it
cannot run), the report runs and fails on a missing bag, then succeeds."""
from __future__ import annotations

import shutil

import yaml

from replay_bags import LUENBERGER
from replay_bags import sim, bag  # noqa: F401 (fixtures)


# ------------------------------------------------------------------ fto-report
def test_report_plan_pairs_variants(tmp_path):
    from fto_ros.cli import report
    bags, cfg = tmp_path / "bags", tmp_path / "config"
    for b in ("dc_motor_nominal", "dc_motor_noisy", "dc_motor_sampled"):
        (bags / b).mkdir(parents=True)
    cfg.mkdir()
    for c in ("dc_motor_luenberger", "dc_motor_single_delay", "dc_motor_single_delay_sampled"):
        shutil.copy(LUENBERGER, cfg / f"{c}.yaml")
    doc = yaml.safe_load(LUENBERGER.read_text())
    doc["observer_node"]["ros__parameters"]["observer"]["type"] = "not_an_observer_yet"
    (cfg / "dc_motor_future.yaml").write_text(yaml.safe_dump(doc))
    pairs, notes = report.plan(bags, cfg)
    got = [(p.bag.name, p.config.name) for p in pairs]
    assert got == [
        ("dc_motor_nominal", "dc_motor_single_delay.yaml"),
        ("dc_motor_nominal", "dc_motor_luenberger.yaml"),
        ("dc_motor_noisy", "dc_motor_single_delay.yaml"),
        ("dc_motor_noisy", "dc_motor_luenberger.yaml"),
        ("dc_motor_sampled", "dc_motor_single_delay_sampled.yaml"),
        ("dc_motor_sampled", "dc_motor_luenberger.yaml"),
    ]
    assert any("dc_motor_future.yaml" in n and "not_an_observer_yet" in n for n in notes)


def test_report_runs_and_fails_on_a_missing_bag(bag, tmp_path, capsys):
    from fto_ros.cli import report
    bags, cfg, out = tmp_path / "bags", tmp_path / "config", tmp_path / "out"
    bags.mkdir()
    cfg.mkdir()
    shutil.copytree(bag, bags / "dc_motor_nominal")  # dc_motor_noisy is missing
    shutil.copy(LUENBERGER, cfg / "dc_motor_luenberger.yaml")
    rc = report.main(["--out", str(out), "--bags-dir", str(bags), "--config-dir", str(cfg),
                      "--no-progress"])
    cap = capsys.readouterr()
    assert rc == 1
    assert "| dc_motor_nominal | luenberger (dc_motor_luenberger.yaml) | none |" in cap.out
    assert "dc_motor_noisy" in cap.out and "FAILED" in cap.out
    md = (out / "report.md").read_text()
    assert "dc_motor_nominal__dc_motor_luenberger/replay.png" in md
    assert (out / "dc_motor_nominal__dc_motor_luenberger" / "metrics.json").is_file()
    # with both bags present it succeeds
    shutil.copytree(bag, bags / "dc_motor_noisy")
    assert report.main(["--out", str(out), "--bags-dir", str(bags), "--config-dir", str(cfg),
                        "--no-progress"]) == 0
