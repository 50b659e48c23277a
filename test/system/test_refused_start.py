"""A node that refuses its start (a bad parameter, an unreadable URDF) says so in its first
stderr line, exit 2, before any DDS participant exists (item 6: Fast DDS's shared-memory
warnings were seen in front of the refusal): the configuration is built before
rclpy.init."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PLANT = REPO / "config" / "dc_motor_plant.yaml"
TUNING = REPO / "config" / "dc_motor_single_delay.yaml"
ENV = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", ROS_DOMAIN_ID="221")

rclpy = pytest.importorskip("rclpy")


def bad_tau(tmp_path: Path, node: str = "observer_node") -> Path:
    path = tmp_path / "bad.yaml"
    path.write_text(f"{node}:\n  ros__parameters:\n    single_delay:\n      tau: -1.0\n")
    return path


def not_urdf(tmp_path: Path) -> Path:
    path = tmp_path / "arm.urdf"
    path.write_text("<robot name='x'><link name='a'>")       # cut off: not XML
    return path


CASES = {
    "observer, bad value": (
        "fto_ros.nodes.observer_node",
        lambda t: ["--params-file", str(PLANT), "--params-file", str(TUNING),
                   "--params-file", str(bad_tau(t))], "single_delay.tau"),
    "managed autostart, bad value": (
        "fto_ros.nodes.managed_node",
        lambda t: ["--params-file", str(PLANT), "--params-file", str(TUNING),
                   "--params-file", str(bad_tau(t)), "-p", "autostart:=true"],
        "single_delay.tau"),
    "observer, bad -p": (
        "fto_ros.nodes.observer_node",
        lambda t: ["--params-file", str(PLANT), "--params-file", str(TUNING),
                   "-p", "single_delay.tau:=-2.0"], "single_delay.tau"),
    "torque, missing URDF": (
        "fto_ros.nodes.torque_node", lambda t: ["-p", f"plant.urdf:={t / 'none.urdf'}"],
        "plant.urdf"),
    "torque, URDF not XML": (
        "fto_ros.nodes.torque_node", lambda t: ["-p", f"plant.urdf:={not_urdf(t)}"],
        "plant.urdf"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_refusal_is_the_first_line(tmp_path, case):
    module, args, parameter = CASES[case]
    res = subprocess.run([sys.executable, "-m", module, "--ros-args", *args(tmp_path)],
                         capture_output=True, text=True, timeout=300, env=ENV, cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert "fto_ros: bad parameter:" in lines[0] and f"'{parameter}'" in lines[0], res.stderr
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr


def test_no_participant_is_made_for_a_refused_start(tmp_path, monkeypatch):
    """rclpy.init (where rcl makes the context the DDS participant belongs to) is never
    called when the parameters are refused; the node's class is never built."""
    from fto_ros.nodes import entry
    monkeypatch.setattr(entry.rclpy, "init", lambda **kw: pytest.fail("rclpy.init called"))
    code = entry.run(lambda: pytest.fail("node built"), "fto-observer", "observer_node", False,
                     ["--ros-args", "--params-file", str(PLANT), "--params-file", str(TUNING),
                      "--params-file", str(bad_tau(tmp_path))])
    assert code == 2


def test_a_managed_node_without_autostart_still_starts_unconfigured(tmp_path):
    """No refusal at start where the node would not refuse: its configure reports."""
    from fto_ros.nodes import entry
    entry.preflight("managed_observer_node",
                    ["--ros-args", "--params-file", str(bad_tau(tmp_path))])   # no error
    with pytest.raises(entry.ConfigError):
        entry.preflight("observer_node", ["--ros-args", "--params-file", str(PLANT),
                                          "--params-file", str(TUNING), "--params-file",
                                          str(bad_tau(tmp_path))])
