"""fto-tune (issue 26 item 3): each joint's bandwidth from a contact-free bag by a residual the
data can check, never by a truth.

The bar: tuned on one simulated stream (test/support/joint_streams.py: smooth motion with
reversals, 1e-5 rad encoder noise, 2^-18 rad quantisation, +-50 us jittered instants) and
scored on another seed of the same kind of motion, the data-tuned velocity RMS is within
1.2x of the truth-tuned one (the best bandwidth of a fine grid chosen with the truth on the
scoring stream).  Measured per joint (joint_kalman, order 3, 7 joints of speeds 0.5-2):

    prediction: 1.077 1.095 0.998 1.081 1.037 1.003 1.005
    heldout:    the same values (both scores chose the same bandwidths)

and on the tuning stream itself the data-tuned RMS is the truth-tuned one within 0.7 %: the
rest is the other stream's different optimum.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

import joint_streams as JS
from fto_ros.cli.tune import MARKER, main
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.runner.plant_files import params_files

ROOT = Path(__file__).resolve().parents[3]
PARAMS = [ROOT / "config" / "arm7_plant.yaml", ROOT / "config" / "arm7_joint_kalman.yaml"]
GRID = np.geomspace(5.0, 300.0, 60)


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("tune")
    return JS.write_bag(d / "tune_on", JS.stream(1)), JS.stream(2), d


def tuned_rms(out: Path, s) -> np.ndarray:
    return JS.velocity_rms(Runner(load_params_files(PARAMS + [out])), s)


def truth_tuned(s) -> np.ndarray:
    curve = []
    for f in GRID:
        flat = load_params_files(PARAMS)
        flat["joint_kalman.bandwidth"] = [float(f)]
        curve.append(JS.velocity_rms(Runner(flat), s))
    return np.min(curve, axis=0)


@pytest.fixture(scope="module")
def truth(bags):
    return truth_tuned(bags[1])


def tune(bag, out, *extra):
    return main([str(bag), *sum((["--params", str(p)] for p in PARAMS), []), "--out", str(out),
                 *extra])


@pytest.mark.parametrize("score", ["prediction", "heldout"])
def test_data_tuned_within_1_2_of_truth_tuned(bags, truth, score, capsys):
    bag, score_on, d = bags
    out = d / f"{score}.yaml"
    assert tune(bag, out, "--score", score, "--points", "20") == 0
    printed = capsys.readouterr().out
    assert "joint_a7" in printed and "residual min" in printed
    ratio = tuned_rms(out, score_on) / truth
    print(score, "data-tuned / truth-tuned per joint:", np.round(ratio, 3))
    assert np.all(ratio <= 1.2), ratio
    bd = JS.backward_difference_rms(score_on)
    assert np.all(tuned_rms(out, score_on) < 0.25 * bd)     # measured 0.03-0.14x


def test_the_file_is_read_by_the_runner_per_joint(bags):
    bag, _, d = bags
    out = d / "prediction.yaml"
    if not out.exists():
        assert tune(bag, out, "--points", "10") == 0
    text = out.read_text()
    assert text.startswith(MARKER + "\n")
    doc = yaml.safe_load(text)
    (entry,) = doc["/**"]["ros__parameters"]["joint_overrides"]
    assert entry.startswith("joint_kalman.bandwidth=[")
    runner = Runner(load_params_files(PARAMS + [out]))
    got = [o.bandwidth[0] for o in runner.observers]
    assert len(set(got)) > 1                           # the joints differ (speeds 0.5-2)
    assert max(got) / min(got) > 1.5                   # measured 3.2


def test_one_observer_writes_its_parameter(tmp_path, capsys):
    """Without joints: the parameter itself (luenberger's Kalman design: its process noise
    scaled), and the file takes the replay."""
    params = [ROOT / "config" / "dc_motor_plant.yaml", ROOT / "config" / "dc_motor_luenberger.yaml"]
    out = tmp_path / "t.yaml"
    rc = main([str(ROOT / "bags" / "dc_motor_noisy"), "--params", str(params[0]), "--params",
               str(params[1]), "--out", str(out), "--points", "5"])
    assert rc == 0, capsys.readouterr().err
    doc = yaml.safe_load(out.read_text())["/**"]["ros__parameters"]
    q = doc["luenberger"]["process_noise"]
    assert len(q) == 3 and all(v > 0 for v in q)
    Runner(load_params_files(params + [out]))


def test_exit_codes_and_what_it_writes(bags, tmp_path, capsys):
    bag, _, _ = bags
    # a params file fto-tune has no knob for: 2
    files = params_files(ROOT / "config" / "double_integrator_prescribed_time.yaml")
    rc = main([str(ROOT / "bags" / "double_integrator"),
               *sum((["--params", str(p)] for p in files), []), "--out", str(tmp_path / "x.yaml")])
    assert rc == 2 and "fto-tune tunes" in capsys.readouterr().err
    assert not (tmp_path / "x.yaml").exists()
    # a missing bag: 1
    assert tune(tmp_path / "nope", tmp_path / "x.yaml") == 1
    assert not (tmp_path / "x.yaml").exists()
    # the input as output: 2
    assert tune(bag, PARAMS[1]) == 2
    assert tune(bag, bag / "metadata.yaml") == 2
    # a file fto-tune did not write is never replaced, even with --overwrite: 2
    other = tmp_path / "mine.yaml"
    other.write_text("# my notes\n")
    assert tune(bag, other, "--overwrite") == 2
    assert other.read_text() == "# my notes\n"
    # its own file: 1 without --overwrite, replaced with it
    own = tmp_path / "own.yaml"
    own.write_text(MARKER + "\n# old\n")
    assert tune(bag, own, "--points", "3") == 1
    assert own.read_text() == MARKER + "\n# old\n"
    assert tune(bag, own, "--points", "3", "--overwrite") == 0
    assert "joint_overrides" in own.read_text()
    # a symlink to its own file is not replaced
    link = tmp_path / "link.yaml"
    link.symlink_to(own)
    assert tune(bag, link, "--overwrite") == 2
    # bad arguments: argparse's 2
    with pytest.raises(SystemExit) as err:
        main([str(bag), "--out", str(tmp_path / "y.yaml")])
    assert err.value.code == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.yaml", "mine.yaml", "own.yaml"]


@pytest.mark.parametrize("tuning, entries", [("hosm", ("hosm.poles=", "hosm.M=")),
                                             ("single_delay", ("single_delay.tau=",))])
def test_the_gain_scale_of_the_guaranteed_time_families(bags, tmp_path, capsys, tuning, entries):
    """hosm (poles x s, M x s^N) and single_delay (tau / s), per joint: a grid of 3 (0.05, 1,
    20) and the refinement; hosm's scale 0.05 puts M below the paper's bound the config
    checks (refused: the table says so), and the file's values reach each joint."""
    bag, _, _ = bags
    params = [ROOT / "config" / "arm7_plant.yaml", ROOT / "config" / f"arm7_{tuning}.yaml"]
    out = tmp_path / "t.yaml"
    rc = main([str(bag), *sum((["--params", str(p)] for p in params), []), "--out", str(out),
               "--points", "3"])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    doc = yaml.safe_load(out.read_text())["/**"]["ros__parameters"]["joint_overrides"]
    assert sorted(e.split("=")[0] + "=" for e in doc) == sorted(entries)
    if tuning == "hosm":
        assert "refused by the observer" in printed
    runner = Runner(load_params_files(params + [out]))
    assert runner.n_joints == 7
