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


def _pick(names: list[str], values, joints: Sequence[str], field: str) -> list[float] | str:
    if len(values) != len(names):
        return f"joint_states_{field}_missing"
    out = []
    for j in joints:
        try:
            out.append(float(values[names.index(j)]))
        except ValueError:
            return "joint_states_joint_missing"
    return out


def joint_state_sample(msg, settings: Mapping[str, Any], clock: float | None = None,
                       intake=None) -> tuple[float, list[float], list[float] | None] | str:
    """(t, y, u) from a JointState per the ``joint_states.*`` settings, or a rejection reason:
    the one intake of the node and the replay.  u is None when no input joints are configured.
    ``intake``: an arm family's (runner/arm_intake.py, ``Runner.intake``), which takes the
    joints by name instead of the settings.

    ``clock`` is the time (s) the header stamp is checked against, one that cannot lag the
    data: the node's wall clock, the replay's log time (the recording's receipt time); None
    (the node on sim time, where /clock comes from the player of the data and may lag it,
    or before any /clock): no check, the runner's own stamp rules apply, as in the replay.
    Rejected, in this order:

    - ``joint_states_duplicate_name``: a joint named twice (which value is meant?);
    - ``joint_states_joint_missing``: a configured joint absent; ``joint_states_<field>_missing``:
      a field that is used whose length is not that of ``name``;
    - ``zero_stamp``: a header stamp of exactly 0 (an unstamped message) while the clock reads
      more than ``time.max_gap``: a bag or a simulation that starts at 0 may stamp 0;
    - ``future_stamp``: a stamp more than ``time.future_tolerance`` ahead of the clock.
    """
    if intake is not None:
        sample = intake.take(msg.name, msg.position, msg.effort)
        if sample.__class__ is str:
            return sample
        y, u = sample
    else:
        sample = _configured(msg, settings)
        if sample.__class__ is str:
            return sample
        y, u = sample
    stamp = msg.header.stamp
    t = stamp_seconds(stamp)
    bad = stamp_check(stamp.sec, stamp.nanosec, t, settings, clock)
    return bad if bad is not None else (t, y, u)


def _configured(msg, settings: Mapping[str, Any]):
    """(y, u) of the joint_states.* settings, or the reason."""
    names = list(msg.name)
    if len(set(names)) != len(names):
        return "joint_states_duplicate_name"
    y = _pick(names, getattr(msg, settings["joint_states.output_field"]),
              settings["joint_states.output_joints"], settings["joint_states.output_field"])
    if isinstance(y, str):
        return y
    u = None
    if settings["joint_states.input_joints"]:
        u = _pick(names, getattr(msg, settings["joint_states.input_field"]),
                  settings["joint_states.input_joints"], settings["joint_states.input_field"])
        if isinstance(u, str):
            return u
    return y, u


def stamp_check(sec: int, nanosec: int, t: float, settings: Mapping[str, Any],
                clock: float | None) -> str | None:
    """Why a JointState stamped (sec, nanosec) = t s is refused against ``clock`` (see
    ``joint_state_sample``: ``zero_stamp``, ``future_stamp``), or None.  The per-joint mode
    applies it to the whole message (every joint); the one stamp check of every JointState
    intake (the node's, raw or rclpy, and the replay's)."""
    if clock is not None:
        if sec == 0 and nanosec == 0 and clock > settings["time.max_gap"]:
            return "zero_stamp"
        if t - clock > settings["time.future_tolerance"]:
            return "future_stamp"
    return None
