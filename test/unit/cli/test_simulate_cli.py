"""fto-simulate (fto_ros/cli/simulate.py): the documented topics, sparse and noisy sampling,
sample times from a file, bad arguments (exit 2, one line), an existing output, the state
jump, and the command run as a module.  No ROS needed."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bag_samples import CLOCK, F64, JS, stamp_ns
from fto_ros.bag import bag_info, list_topics, read_messages
from fto_ros.cli import simulate as cli
from fto_ros.models import get_model
from fto_ros.models.simulate import simulate, uniform_grid

ROOT = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------- fto-simulate
def run_cli(*argv) -> int:
    return cli.main([str(a) for a in argv])


def test_simulate_cli_records_the_documented_topics(tmp_path, capsys):
    out = tmp_path / "dcm"
    assert run_cli("dc_motor", "--out", out, "--duration", 0.2) == 0
    assert "wrote" in capsys.readouterr().out
    assert list_topics(out) == {
        "/clock": (CLOCK, 201), "/dc_motor/input": (F64, 201),
        "/dc_motor/joint_states": (JS, 201), "/dc_motor/measured_output": (F64, 201),
        "/dc_motor/true_state": (F64, 201)}
    spec = get_model("dc_motor")
    t = uniform_grid(0.2, 1000.0)
    ref = simulate(spec.make_rhs(dict(spec.default_params)), spec.default_x0, t,
                   spec.default_input)
    rows: dict[str, list] = {}
    for topic, t_ns, msg in read_messages(out):
        rows.setdefault(topic, []).append((t_ns, msg))
    assert [t_ns for t_ns, _ in rows["/clock"]] == [k * 1_000_000 for k in range(201)]
    truth = np.array([m.data for _, m in rows["/dc_motor/true_state"]])
    np.testing.assert_array_equal(truth, ref.x)
    np.testing.assert_array_equal([m.data[0] for _, m in rows["/dc_motor/input"]], ref.u[:, 0])
    np.testing.assert_array_equal([m.data[0] for _, m in rows["/dc_motor/measured_output"]],
                                  ref.x[:, 0])  # no noise by default
    for t_ns, js in rows["/dc_motor/joint_states"]:
        assert stamp_ns(js.header.stamp) == t_ns and js.name == ["joint1"]
        assert len(js.velocity) == 0 and len(js.effort) == 0
    settings = json.loads(bag_info(out).custom_data[cli.METADATA_KEY])
    assert settings["model"] == "dc_motor" and settings["x0"] == [0.5, -1.0, 0.2]
    assert settings["params"]["a4"] == 200.0 and settings["seed"] == 0


def test_simulate_cli_sparse_noisy(tmp_path):
    out = tmp_path / "sparse"
    assert run_cli("dc_motor", "--out", out, "--duration", 1.0, "--noise", 1e-3,
                   "--uncertainty", "--seed", 5, "--sparse-min", 0.02, "--sparse-max", 0.05) == 0
    rows: dict[str, list] = {}
    for topic, t_ns, msg in read_messages(out):
        rows.setdefault(topic, []).append((t_ns, msg))
    t_meas = np.array([t for t, _ in rows["/dc_motor/measured_output"]])
    gaps = np.diff(t_meas)
    assert t_meas[0] == 0 and gaps.min() >= 20_000_000 and gaps.max() <= 50_000_000
    assert len(rows["/dc_motor/input"]) == 1001
    truth = {t: m.data for t, m in rows["/dc_motor/true_state"]}
    clock = {t for t, _ in rows["/clock"]}
    assert set(t_meas) <= set(truth) and set(t_meas) <= clock  # truth wherever y exists
    err = np.array([m.data[0] - truth[t][0] for t, m in rows["/dc_motor/measured_output"]])
    assert 0 < np.abs(err).max() < 6e-3
    settings = json.loads(bag_info(out).custom_data[cli.METADATA_KEY])
    assert settings["measurement_sampling"]["mode"] == "sparse"
    assert settings["uncertainty"]["enabled"] is True
    assert settings["measurement_noise"]["sigma"] == 1e-3
    # same seed, same bag contents
    out2 = tmp_path / "sparse2"
    assert run_cli("dc_motor", "--out", out2, "--duration", 1.0, "--noise", 1e-3,
                   "--uncertainty", "--seed", 5, "--sparse-min", 0.02, "--sparse-max", 0.05) == 0
    a = [(tp, t, list(m.data)) for tp, t, m in read_messages(out, ["/dc_motor/measured_output"])]
    b = [(tp, t, list(m.data)) for tp, t, m in read_messages(out2, ["/dc_motor/measured_output"])]
    assert a == b


def test_simulate_cli_sample_times_file(tmp_path):
    times = tmp_path / "times.txt"
    times.write_text("# instants\n0.0, 0.0105\n0.05 0.1234\n")
    out = tmp_path / "file"
    assert run_cli("dc_motor", "--out", out, "--duration", 0.2, "--sample-times", times) == 0
    got = [t for _, t, _ in read_messages(out, ["/dc_motor/joint_states"])]
    assert got == [0, 10_500_000, 50_000_000, 123_400_000]


@pytest.mark.parametrize("argv,message", [
    (["nope", "--out", "X"], "unknown model 'nope'; known models: "),
    (["dc_motor"], "--out"),
    (["dc_motor", "--out", "X", "--duration", "-1"], "--duration"),
    (["dc_motor", "--out", "X", "--rate", "abc"], "--rate"),
    (["dc_motor", "--out", "X", "--noise", "-0.1"], "--noise"),
    (["dc_motor", "--out", "X", "--sparse-min", "0.1"], "together"),
    (["dc_motor", "--out", "X", "--sparse-min", "0.2", "--sparse-max", "0.1"], "<="),
    (["dc_motor", "--out", "X", "--sparse-min", "0.1", "--sparse-max", "0.2",
      "--sample-times", "f"], "mutually exclusive"),
])
def test_simulate_cli_bad_arguments_exit_2(tmp_path, capsys, argv, message):
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "X").exists()


def test_simulate_cli_existing_output(tmp_path, capsys):
    out = tmp_path / "dcm"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert run_cli("dc_motor", "--out", out, "--duration", 0.01) == 1
    assert "exists already" in capsys.readouterr().err
    assert run_cli("dc_motor", "--out", out, "--duration", 0.01, "--overwrite") == 2
    assert "refusing to replace" in capsys.readouterr().err
    assert (out / "keep.txt").exists()
    shutil.rmtree(out)
    assert run_cli("dc_motor", "--out", out, "--duration", 0.01) == 0
    assert run_cli("dc_motor", "--out", out, "--duration", 0.02, "--overwrite") == 0
    assert list_topics(out)["/clock"].count == 21


def test_simulate_runs_as_module(tmp_path):
    out = tmp_path / "m"
    proc = subprocess.run([sys.executable, "-m", "fto_ros.cli.simulate", "dc_motor", "--out",
                           str(out), "--duration", "0.05"], cwd=ROOT, capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    assert "/dc_motor/true_state 51" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "fto_ros.cli.simulate", "nope", "--out",
                           str(out)], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 2 and "unknown model" in proc.stderr and "dc_motor" in proc.stderr


def test_simulate_cli_state_jump(tmp_path, capsys):
    """--state-jump: the state jumps by DELTA at T (the sample at T sees it), nothing else
    changes before T, the metadata records it; bad values are refused (exit 2)."""
    plain, jump = tmp_path / "plain", tmp_path / "jump"
    assert run_cli("dc_motor", "--out", plain, "--duration", 0.3) == 0
    assert run_cli("dc_motor", "--out", jump, "--duration", 0.3,
                   "--state-jump", "0.15,q_dot,4") == 0
    a, b = ({t: np.array(m.data) for topic, t, m in read_messages(p)
             if topic == "/dc_motor/true_state"} for p in (plain, jump))
    t_j = 150_000_000
    assert all(np.array_equal(a[t], b[t]) for t in a if t < t_j)
    assert b[t_j][1] - a[t_j][1] == pytest.approx(4.0, abs=1e-9)
    assert b[t_j][0] == pytest.approx(a[t_j][0], abs=1e-12)       # q itself does not jump
    settings = json.loads(bag_info(jump).custom_data[cli.METADATA_KEY])
    assert settings["state_jumps"] == [{"t": 0.15, "state": "q_dot", "delta": 4.0}]
    capsys.readouterr()
    for bad in ("0.15,speed,4", "0.15,q_dot", "9.0,q_dot,1", "0.1,7,1", "nan,q_dot,1"):
        with pytest.raises(SystemExit) as exc:
            run_cli("dc_motor", "--out", tmp_path / "bad", "--duration", 0.3, "--state-jump", bad)
        assert exc.value.code == 2
        assert "--state-jump" in capsys.readouterr().err
