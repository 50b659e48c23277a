"""The observer node's command line, started as a user starts it (`python -m
fto_ros.nodes.observer_node --ros-args ...`): a bad params file exits 2 with one line, `-p`
wins over every params file, --help; fto-play on a missing bag exits 1.  Each command runs
in a session of its own on a domain of its own (test/support/processes.py, domains.py)."""
from __future__ import annotations

import sys

import pytest

pytest.importorskip("rclpy")
import domains  # noqa: E402
import live_node as L  # noqa: E402
import processes  # noqa: E402
from live_node import ROOT, Driver, NodeProcess  # noqa: E402

#: live DDS nodes: scripts/run-tests runs these after the rest, one at a time
pytestmark = pytest.mark.live


# ------------------------------------------------------------ bad configuration
def _positive_pole(p):
    p["luenberger"]["poles"] = [-50.0, 60.0, -70.0]


def _typo(p):
    p["luenberger"]["polse"] = p["luenberger"].pop("poles")


def _mixed_list(p):
    p["luenberger"]["poles"] = [-50, -60.5, -70]


def _no_type(p):
    del p["observer"]


@pytest.mark.parametrize("edit, names", [
    (_positive_pole, "luenberger.poles"),
    (_typo, "luenberger.polse"),
    (_mixed_list, "luenberger.poles"),
    (_no_type, "observer.type"),
])
def test_bad_params_file_exits_2_with_one_line(tmp_path, edit, names):
    params = L.params_file(tmp_path, "bad", edit)
    cmd = [sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args",
           "--params-file", str(params)]
    res = processes.run(cmd, cwd=ROOT, env=L.ros_env(domains.take(), tmp_path),
                        capture_output=True, timeout=60)
    out = (res.stdout + res.stderr).strip()
    assert res.returncode == 2, out
    assert "Traceback" not in out, out
    lines = [line for line in out.splitlines() if line.strip()]
    assert len(lines) == 1, out
    assert "fto_ros: bad parameter:" in lines[0] and f"'{names}'" in lines[0], out


@pytest.mark.slow
def test_command_line_p_wins_over_the_params_files(tmp_path):
    """Was: `-p single_delay.tau:=-1.0` before the params files was silently ignored (their
    node-specific block outranks -p in rcl when it comes later).  -p wins in any order: a bad
    value is refused in one line, a good one is what the node runs with."""
    plant, tuning = ROOT / "config" / "dc_motor_plant.yaml", ROOT / "config" / "dc_motor_single_delay.yaml"
    files = ["--params-file", str(plant), "--params-file", str(tuning)]
    for order in (["-p", "single_delay.tau:=-1.0", *files], [*files, "-p", "single_delay.tau:=-1.0"]):
        cmd = [sys.executable, "-m", "fto_ros.nodes.observer_node", "--ros-args", *order]
        res = processes.run(cmd, cwd=ROOT, env=L.ros_env(domains.take(), tmp_path),
                            capture_output=True, timeout=60)
        out = (res.stdout + res.stderr).strip()
        assert res.returncode == 2 and len(out.splitlines()) == 1, out
        assert "'single_delay.tau'" in out and "-1.0" in out, out
    domain = domains.take()
    node = NodeProcess(tmp_path, domain, None, "-p", "single_delay.tau:=0.05",
                       "-p", "diagnostics.period:=0.2", *files)
    driver = Driver(domain, outputs=())
    try:
        st = driver.wait_for(driver.last_status, 60, "the first /diagnostics", node)
        assert st["values"]["tau (guaranteed convergence time, s)"] == "0.05", st["values"]
        assert st["values"]["observer"] == "single_delay"
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


def test_help_prints_usage():
    res = processes.run([sys.executable, "-m", "fto_ros.nodes.observer_node", "--help"], cwd=ROOT,
                        capture_output=True, timeout=60)
    assert res.returncode == 0
    assert "usage: fto-observer" in res.stdout and "time.jump_threshold" in res.stdout


def test_player_missing_bag_exits_1(tmp_path):
    res = processes.run([sys.executable, "-m", "fto_ros.nodes.player", str(tmp_path / "nope")],
                        cwd=ROOT, env=L.ros_env(domains.take(), tmp_path), capture_output=True,
                        timeout=60)
    assert res.returncode == 1
    assert "fto-play: error:" in res.stderr and "nope" in res.stderr and "Traceback" not in res.stderr
