"""fto-replay's command line (fto_ros/replay/cli.py): success, and every refusal as one line
with the contract's exit code (a missing or foreign bag, missing or unknown parameters, an
existing output, a bag without the measured topic, usage errors); the library's argument
errors; the console script as a subprocess."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from fto_ros.replay import ReplayError, replay
from fto_ros.replay import cli as replay_cli
from replay_bags import LUENBERGER, write_bag
from replay_bags import sim, bag  # noqa: F401 (fixtures)

REPO = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------ CLI
def _cli(capsys, *argv):
    rc = replay_cli.main(list(map(str, argv)))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("fto-replay: error: ")
    assert "Traceback" not in err
    return lines[0]


def test_cli_success(bag, tmp_path, capsys):
    rc, out, err = _cli(capsys, bag, "--params", LUENBERGER, "--out", tmp_path / "o",
                        "--no-progress", "--tolerance", "0.05", "--after", "0.3")
    assert rc == 0, err
    assert "luenberger" in out and "real time" in out
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["tolerance"] == 0.05 and m["settle_time_s"] == 0.3


def test_cli_missing_bag(tmp_path, capsys):
    rc, _, err = _cli(capsys, tmp_path / "nope", "--params", LUENBERGER, "--out", tmp_path / "o")
    assert rc == 1
    assert "nope" in _one_error_line(err)
    assert not (tmp_path / "o").exists()


def test_cli_not_a_bag(tmp_path, capsys):
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "metadata.yaml").write_text("garbage: [")
    rc, _, err = _cli(capsys, tmp_path / "junk", "--params", LUENBERGER, "--out", tmp_path / "o")
    assert rc == 1
    _one_error_line(err)


def test_cli_missing_params(bag, tmp_path, capsys):
    rc, _, err = _cli(capsys, bag, "--params", tmp_path / "none.yaml", "--out", tmp_path / "o")
    assert rc == 2                          # bad parameters (the node exits 2 for them too)
    assert "none.yaml" in _one_error_line(err)


def test_cli_unknown_parameter(bag, tmp_path, capsys):
    doc = yaml.safe_load(LUENBERGER.read_text())
    doc["observer_node"]["ros__parameters"]["luenberger"]["polse"] = [-1.0, -2.0, -3.0]
    params = tmp_path / "typo.yaml"
    params.write_text(yaml.safe_dump(doc))
    rc, _, err = _cli(capsys, bag, "--params", params, "--out", tmp_path / "o")
    assert rc == 2
    line = _one_error_line(err)
    assert "luenberger.polse" in line and "unknown parameter" in line


def test_cli_existing_out_needs_overwrite(bag, tmp_path, capsys):
    (tmp_path / "o").mkdir()
    rc, _, err = _cli(capsys, bag, "--params", LUENBERGER, "--out", tmp_path / "o")
    assert rc == 1
    assert "exists" in _one_error_line(err) and "--overwrite" in err
    rc, _, err = _cli(capsys, bag, "--params", LUENBERGER, "--out", tmp_path / "o",
                      "--overwrite", "--no-progress")
    assert rc == 0, err


def test_cli_bag_without_the_measured_topic(sim, tmp_path, capsys):
    bag = write_bag(tmp_path / "other", sim, measured_topic="/elsewhere/y")
    rc, _, err = _cli(capsys, bag, "--params", LUENBERGER, "--out", tmp_path / "o")
    assert rc == 1
    line = _one_error_line(err)
    assert "/dc_motor/measured_output" in line and "/elsewhere/y" in line


def test_cli_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        replay_cli.main(["only-a-bag"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        replay_cli.main(["b", "--params", "p", "--out", "o", "--tolerance", "-1"])
    assert exc.value.code == 2


def test_library_argument_errors(bag, tmp_path):
    with pytest.raises(ReplayError):
        replay(bag, LUENBERGER, tmp_path / "o", tolerance=0)
    with pytest.raises(ReplayError):
        replay(bag, LUENBERGER, tmp_path / "o", after=-1.0)


def test_console_script_as_subprocess(bag, tmp_path):
    """`python -m fto_ros.replay.cli` exits 1 with one line, never a traceback."""
    proc = subprocess.run([sys.executable, "-m", "fto_ros.replay.cli", str(tmp_path / "missing"),
                           "--params", str(LUENBERGER), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 1
    assert proc.stderr.startswith("fto-replay: error: ") and "Traceback" not in proc.stderr
