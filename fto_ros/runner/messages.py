"""Message fields <-> runner values, for rclpy and rosbags messages alike.

Duck-typed on the attribute names the ROS message definitions share (both
rclpy's generated classes and rosbags' deserialised dataclasses have them), so
the node and the replay harness convert messages the same way.  No rclpy here.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence


def stamp_seconds(stamp) -> float:
    """builtin_interfaces/Time -> seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def seconds_to_stamp_parts(t: float) -> tuple[int, int]:
    """seconds -> (sec, nanosec) with 0 <= nanosec < 1e9 (rounded to the nanosecond)."""
    ns = round(t * 1e9)
    return ns // 1_000_000_000, ns % 1_000_000_000


def _pick(msg, joints: Sequence[str], field: str) -> list[float] | str:
    names = list(msg.name)
    values = getattr(msg, field)
    if len(values) != len(names):
        return f"joint_states_{field}_missing"
    out = []
    for j in joints:
        try:
            out.append(float(values[names.index(j)]))
        except ValueError:
            return "joint_states_joint_missing"
    return out


def joint_state_sample(msg, settings: Mapping[str, Any]) -> tuple[float, list[float], list[float] | None] | str:
    """(t, y, u) from a JointState per the ``joint_states.*`` settings, or a rejection reason.

    u is None when no input joints are configured.
    """
    t = stamp_seconds(msg.header.stamp)
    y = _pick(msg, settings["joint_states.output_joints"], settings["joint_states.output_field"])
    if isinstance(y, str):
        return y
    u = None
    if settings["joint_states.input_joints"]:
        u = _pick(msg, settings["joint_states.input_joints"], settings["joint_states.input_field"])
        if isinstance(u, str):
            return u
    return t, y, u
