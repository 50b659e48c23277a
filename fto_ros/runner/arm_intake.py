"""A JointState's entries -> the sample of an arm's external-torque family, by name: the one
intake of those families for the node and the replay (duck-typed on the JointState fields
rclpy's and rosbags' messages share, or plain sequences).

y = the listed joints' positions; u = [their efforts, the passive joints' positions]
(observers/arm_base.py). Nothing is mis-assigned: a listed joint missing from the message,
a name given twice, or a position or effort array not as long as ``name`` refuses the
sample with its reason (counted by the runner). A passive joint the message lacks keeps its
last known position (at first the URDF's neutral or plant.locked_positions): a gripper's
fingers may come on another topic or not at all. Values are not judged here (a NaN is the
runner's to reject). ROS-free.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np


class ArmIntake:
    """Samples of ``joints`` (and the ``passive`` joints' positions) from JointStates."""

    def __init__(self, joints: Sequence[str], passive: Sequence[str], passive_start):
        self.joints = list(joints)
        self.passive = list(passive)
        self.last = np.array(passive_start, dtype=float)
        self._names: tuple | None = None
        self._index = np.zeros(len(self.joints), np.int64)
        self._pidx = np.full(len(self.passive), -1, np.int64)
        self._why: str | None = None

    def _lookup(self, names: tuple) -> None:
        where: dict[str, int] = {}
        self._why = None
        for i, name in enumerate(names):
            if name in where:
                self._why = "joint_states_duplicate_name"
            where[name] = i
        for j, joint in enumerate(self.joints):
            if joint not in where:
                self._why = self._why or "joint_states_joint_missing"
            self._index[j] = where.get(joint, 0)
        for j, joint in enumerate(self.passive):
            self._pidx[j] = where.get(joint, -1)
        self._names = names

    def take(self, names, position, effort) -> tuple[np.ndarray, np.ndarray] | str:
        """(y, u) of one message, or the reason it is refused."""
        names = tuple(names)
        if names != self._names:
            self._lookup(names)
        if self._why is not None:
            return self._why
        count = len(names)
        if len(position) != count:
            return "joint_states_position_missing"
        if len(effort) != count:
            return "joint_states_effort_missing"
        try:
            pos = np.asarray(position, dtype=float)
            eff = np.asarray(effort, dtype=float)
        except (TypeError, ValueError):
            return "measurement_not_numeric"
        have = self._pidx >= 0
        if have.any():
            self.last[have] = pos[self._pidx[have]]
        return pos[self._index], np.concatenate((eff[self._index], self.last))


def arm_intake(obs, settings) -> ArmIntake:
    """The intake of the arm family ``obs``; its settings read JointStates (``source``)."""
    from ..core.errors import ConfigError
    x0 = settings["observer.initial_estimate"]
    if x0 and len(x0) != obs.n_states:
        raise ConfigError("observer.initial_estimate", f"expected {obs.n_states} values, got "
                          f"{len(x0)}")
    settings["source"] = "joint_states"
    return ArmIntake(*obs.intake_spec())
