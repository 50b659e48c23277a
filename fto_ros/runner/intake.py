"""A JointState's entries -> each joint's samples, by name: the one intake of the per-joint
mode, used by the live node and the replay alike (duck-typed on the fields rclpy's and
rosbags' messages share, or plain sequences).

For every configured joint (``joints``) the intake finds its entry by name, in any order,
and reads y from ``joint_states.output_fields`` and u from the first m of
``joint_states.input_fields``.  Nothing is ever mis-assigned: a joint missing from the
message (``joint_states_joint_missing``), a joint named twice
(``joint_states_duplicate_joint``), or a field the joint needs whose array is not as long as
``name`` (``joint_states_<field>_missing``) refuses that joint's sample, counted with its
reason; the other joints go on.  Values are not judged here (a NaN or 1e300 is the
runner's to reject, per joint).  The index of each joint is kept while a stream keeps the
same name list (the common case: one lookup per message is a tuple comparison).

ROS-free.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..core.reasons import CODE
from .messages import stamp_check, stamp_seconds

MISSING = CODE["joint_states_joint_missing"]
DUPLICATE = CODE["joint_states_duplicate_joint"]
NOT_NUMERIC = CODE["measurement_not_numeric"]
FIELD_MISSING = {f: CODE[f"joint_states_{f}_missing"] for f in ("position", "velocity", "effort")}


class JointIntake:
    """Samples of ``joints`` from JointState entries (see the module doc)."""

    def __init__(self, joints: Sequence[str], output_fields: Sequence[str],
                 input_fields: Sequence[str], n_inputs: int):
        self.joints = list(joints)
        self.out_fields = list(output_fields)
        self.in_fields = list(input_fields)[:n_inputs]
        self._names: tuple | None = None
        self._index = np.zeros(len(self.joints), np.int64)
        self._refused = np.zeros(len(self.joints), np.int16)

    def _lookup(self, names: tuple) -> None:
        where: dict[str, int] = {}
        twice: set[str] = set()
        for i, name in enumerate(names):
            if name in where:
                twice.add(name)
            where[name] = i
        for j, joint in enumerate(self.joints):
            if joint in twice:
                self._index[j], self._refused[j] = 0, DUPLICATE
            elif joint in where:
                self._index[j], self._refused[j] = where[joint], 0
            else:
                self._index[j], self._refused[j] = 0, MISSING
        self._names = names

    def take(self, names, fields) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """(y (J x p), u (J x m) or None without inputs, refused (J,) rejection codes, 0 =
        taken) from a message's ``names`` and ``fields`` (field name -> values)."""
        names = tuple(names)
        if names != self._names:
            self._lookup(names)
        refused = self._refused.copy()
        count = len(names)
        idx = self._index
        y = np.zeros((len(self.joints), len(self.out_fields)))
        u = np.zeros((len(self.joints), len(self.in_fields))) if self.in_fields else None
        for target, which in ((y, self.out_fields), (u, self.in_fields)):
            for c, field in enumerate(which or ()):
                values = fields[field]
                if len(values) != count:
                    refused[refused == 0] = FIELD_MISSING[field]
                    continue
                try:
                    arr = np.asarray(values, dtype=float)
                except (TypeError, ValueError):
                    refused[refused == 0] = NOT_NUMERIC
                    continue
                if count:
                    target[:, c] = arr[idx]
        return y, u, refused

    def take_message(self, msg) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """``take`` of a JointState message (rclpy or rosbags)."""
        fields = {f: getattr(msg, f) for f in set(self.out_fields) | set(self.in_fields)}
        return self.take(msg.name, fields)


def joint_sample(intake: JointIntake, msg, settings, clock: float | None, width: int):
    """One JointState of the per-joint mode as the runner takes it: ``(t s, stamp ns, y (J,
    width), u (J, width) or None, refused (J,) codes, None)``; the header stamp is checked
    against ``clock`` as :func:`~fto_ros.runner.messages.joint_state_sample` does (a
    ``zero_stamp`` or ``future_stamp`` refuses every joint).  The node and the replay both
    hand ``Runner.process_joints`` / ``process_block`` these."""
    stamp = msg.header.stamp
    t = stamp_seconds(stamp)
    y, u, refused = intake.take_message(msg)
    why = stamp_check(stamp.sec, stamp.nanosec, t, settings, clock)
    if why is not None:
        refused[:] = CODE[why]
    J = len(intake.joints)
    yv = np.zeros((J, width))
    yv[:, :y.shape[1]] = y
    uv = None
    if u is not None:
        uv = np.zeros((J, width))
        uv[:, :u.shape[1]] = u
    return t, stamp.sec * 1_000_000_000 + stamp.nanosec, yv, uv, refused, None
