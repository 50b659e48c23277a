"""The node's command line before rcl sees it (fto_ros.nodes.entry): `-p NAME:=VALUE` restated
for the node in a params file given last, so that it wins over every params file (rcl lets a
file given after -p outrank it).  No DDS: rcl only parses the arguments here."""
from __future__ import annotations

import pytest

rclpy = pytest.importorskip("rclpy")
from fto_ros.nodes.entry import command_line_params_win  # noqa: E402

PLANT_TAU = "observer_node:\n  ros__parameters:\n    single_delay:\n      tau: 0.1\n"


def _overrides(args: list[str], node: str = "observer_node") -> dict:
    """What an rclpy node named ``node`` gets from ``args`` (rcl's own parser)."""
    ctx = rclpy.Context()
    rclpy.init(args=args, context=ctx)
    try:
        n = rclpy.create_node(node, context=ctx, start_parameter_services=False,
                              automatically_declare_parameters_from_overrides=False)
        try:
            return {k: v.value for k, v in n._parameter_overrides.items()}
        finally:
            n.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.parametrize("order", ["p_first", "file_first"])
def test_p_wins_over_a_params_file_in_either_order(tmp_path, order):
    params = tmp_path / "tuning.yaml"
    params.write_text(PLANT_TAU)
    p, f = ["-p", "single_delay.tau:=0.05"], ["--params-file", str(params)]
    args = ["fto-observer", "--ros-args", *(p + f if order == "p_first" else f + p)]
    if order == "p_first":           # what rcl alone does: the file's node block wins
        assert _overrides(args)["single_delay.tau"] == 0.1
    assert _overrides(command_line_params_win(args, str(tmp_path)))["single_delay.tau"] == 0.05


def test_the_block_is_for_the_remapped_node(tmp_path):
    args = ["x", "--ros-args", "-r", "__node:=motor", "-r", "__ns:=/robot", "-p", "a.b:=[1, 2]"]
    out = command_line_params_win(args, str(tmp_path))
    assert out[:len(args)] == args and out[len(args):-1] == ["--ros-args", "--params-file"]
    assert open(out[-1]).read() == "/robot/motor:\n  ros__parameters:\n    a.b: [1, 2]\n"


def test_values_rcl_refuses_or_unsets_are_left_to_it(tmp_path):
    args = ["x", "--ros-args", "-p", "a:=", "-p", "b:=#comment", "--", "-p", "c:=1"]
    assert command_line_params_win(args, str(tmp_path)) == args     # (c is not a ROS argument)
