"""The one rule for output folders (fto_ros/core/output_dir.py): what ``overwrite`` may
replace, what it recognises as an output fto_ros wrote, and the inputs it protects.  The
commands' side (every writing command, every attack, exit codes) is in test_faults_cli.py."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

from fto_ros.core.output_dir import (MARKER, REPORT_TITLE, OutputError, OutputExists,
                                     check_output, clear_output, create_output)

ROOT = Path(__file__).resolve().parents[3]


def _bag_like(folder: Path, custom: dict | None) -> Path:
    """A bag folder with a metadata.yaml (custom_data as given) and no marker."""
    folder.mkdir(parents=True)
    (folder / f"{folder.name}.mcap").write_bytes(b"\x89MCAP0\r\n")
    info = {"version": 9, "custom_data": custom} if custom is not None else {"version": 9}
    (folder / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))
    return folder


def test_create_marks_and_a_second_create_needs_overwrite(tmp_path):
    out = create_output(tmp_path / "a" / "b", "sweep")
    assert json.loads((out / MARKER).read_text()) == {"written_by": "fto_ros", "kind": "sweep"}
    (out / "results.csv").write_text("x\n")
    with pytest.raises(OutputExists, match="--overwrite"):
        create_output(out, "sweep")
    create_output(out, "sweep", overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == [MARKER]


def test_empty_folder_is_replaceable_only_with_overwrite(tmp_path):
    (tmp_path / "e").mkdir()
    with pytest.raises(OutputExists):
        check_output(tmp_path / "e", "bag")
    assert clear_output(tmp_path / "e", "bag", overwrite=True) == tmp_path / "e"
    assert not (tmp_path / "e").exists()


def test_a_bag_written_before_markers_is_recognised_by_its_custom_data(tmp_path):
    ours = _bag_like(tmp_path / "ours", {"fto_ros.simulation": "{}"})
    assert check_output(ours, "bag", overwrite=True) == ours
    for name, custom in (("recorded", {"someone.else": "x"}), ("plain", None)):
        theirs = _bag_like(tmp_path / name, custom)        # e.g. ros2 bag record's
        with pytest.raises(OutputError, match="not an output fto_ros wrote"):
            clear_output(theirs, "bag", overwrite=True)
        assert (theirs / "metadata.yaml").is_file()
    # a bag, not a report
    with pytest.raises(OutputError, match="'bag' output, not a report output"):
        check_output(ours, "report", overwrite=True)


def test_a_report_written_before_markers_is_recognised_by_its_title(tmp_path):
    report = tmp_path / "out"
    _bag_like(report / "dc_motor_nominal__dc_motor_luenberger", {"fto_ros.replay.bag": "b"})
    (report / "report.md").write_text(REPORT_TITLE + "\n\n| table |\n")
    assert check_output(report, "report", overwrite=True) == report
    (report / "report.md").write_text("# my own notes\n")
    with pytest.raises(OutputError, match="not an output fto_ros wrote"):
        clear_output(report, "report", overwrite=True)


def test_every_committed_bag_is_recognised_so_it_can_be_regenerated():
    bags = sorted(p for p in (ROOT / "bags").iterdir() if p.is_dir())
    assert bags
    for bag in bags:                          # a check only: nothing is removed
        assert check_output(bag, "bag", overwrite=True) == bag


def test_the_marker_must_be_a_valid_regular_file(tmp_path):
    real = create_output(tmp_path / "real", "bag")
    for name, make in (
            ("linked", lambda d: os.symlink(real / MARKER, d / MARKER)),
            ("junk", lambda d: (d / MARKER).write_text("not json")),
            ("other_writer", lambda d: (d / MARKER).write_text('{"written_by": "x", "kind": "bag"}')),
            ("unknown_kind", lambda d: (d / MARKER).write_text(
                '{"written_by": "fto_ros", "kind": "home"}')),
            ("a_folder", lambda d: (d / MARKER).mkdir())):
        d = tmp_path / name
        d.mkdir()
        make(d)
        (d / "metrics.json").write_text("{}")
        with pytest.raises(OutputError, match="not an output fto_ros wrote"):
            clear_output(d, "bag", overwrite=True)
        assert (d / "metrics.json").exists()


def test_nested_outputs_are_checked_all_the_way_down(tmp_path):
    report = create_output(tmp_path / "report", "report")
    (report / "report.md").write_text("#\n")
    pair = create_output(report / "bag__config", "bag")
    (pair / "metrics.json").write_text("{}")
    assert check_output(report, "report", overwrite=True) == report
    stray = pair / "stray"                      # a folder a bag output never holds
    stray.mkdir()
    with pytest.raises(OutputError, match="stray"):
        clear_output(report, "report", overwrite=True)
    stray.rmdir()
    os.mkfifo(pair / "replay.png")              # a special file under an expected name
    with pytest.raises(OutputError, match="special file"):
        clear_output(report, "report", overwrite=True)
    assert (report / "report.md").exists()


def test_a_sweeps_runs_folder_holds_only_replay_outputs(tmp_path):
    sweep = create_output(tmp_path / "sweep", "sweep")
    (sweep / "results.csv").write_text("x\n")
    run = create_output(sweep / "runs" / "0000_bag", "bag")
    (run / "metrics.json").write_text("{}")
    assert check_output(sweep, "sweep", overwrite=True) == sweep
    (sweep / "runs" / "notes.txt").write_text("mine\n")
    with pytest.raises(OutputError, match="notes.txt"):
        clear_output(sweep, "sweep", overwrite=True)
    assert run.is_dir()


def test_inputs_are_protected_through_symlinks_and_from_their_files(tmp_path):
    bag = _bag_like(tmp_path / "bag", {"fto_ros.simulation": "{}"})
    os.symlink(bag, tmp_path / "alias")
    with pytest.raises(OutputError, match="it is an input"):
        check_output(tmp_path / "alias", "bag", overwrite=True, inputs=[bag])
    # the bag given as its .mcap file protects the whole bag folder
    mcap = bag / "bag.mcap"
    with pytest.raises(OutputError, match="it is an input"):
        check_output(bag, "bag", overwrite=True, inputs=[mcap])
    with pytest.raises(OutputError, match="inside the input"):
        check_output(bag / "new", "bag", inputs=[mcap])
    with pytest.raises(OutputError, match="holds the input"):
        check_output(tmp_path, "bag", overwrite=True, inputs=[mcap])
    params = tmp_path / "p.yaml"
    params.write_text("{}")
    with pytest.raises(OutputError, match="it is an input"):
        check_output(params, "bag", overwrite=True, inputs=[params])


@pytest.mark.parametrize("bad", ["", "   ", "a\0b", b"bytes", 3])
def test_bad_paths_are_refused(bad):
    with pytest.raises(OutputError):
        check_output(bad, "bag", overwrite=True)
