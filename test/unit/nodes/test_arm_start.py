"""fto-external-torque's arguments (nodes/arm_start.py): the observer node's, with the
arm's node name and observer.type added only where the user gave none."""
from __future__ import annotations

from fto_ros.nodes.arm_start import arm_arguments


def test_the_defaults_are_added_when_nothing_is_given():
    assert arm_arguments([]) == ["--ros-args", "-r", "__node:=external_torque_node",
                                 "-p", "observer.type:=external_torque"]


def test_a_remap_and_a_type_given_on_the_command_line_are_kept():
    args = ["--ros-args", "-r", "__node:=arm", "-p", "observer.type:=momentum_observer"]
    assert arm_arguments(args) == args


def test_a_type_in_a_params_file_for_the_node_counts(tmp_path):
    mine = tmp_path / "mine.yaml"
    mine.write_text("external_torque_node:\n  ros__parameters:\n    observer.type: momentum_observer\n")
    other = tmp_path / "other.yaml"
    other.write_text("/**:\n  ros__parameters:\n    external_torque.window: 0.05\n"
                     "someone_else:\n  ros__parameters:\n    observer.type: momentum_observer\n")
    assert arm_arguments(["--ros-args", "--params-file", str(mine)])[-2:] == \
        ["-r", "__node:=external_torque_node"]
    assert arm_arguments(["--ros-args", "--params-file", str(other)])[-2:] == \
        ["-p", "observer.type:=external_torque"]


def test_help_is_left_alone():
    assert arm_arguments(["--help"]) == ["--help"]
