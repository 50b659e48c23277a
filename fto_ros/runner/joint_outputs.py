"""What the per-joint mode publishes for one message: the runner's per-joint arrays ->
the fields of one JointState (position, velocity, effort per joint) and the labels of
the per-state outputs.  ROS-free: the node builds its messages from it, and the replay can.
(Without joints, ``estimated_joint_states`` reads the settings that map a whole plant's
estimate onto joints.)

Only the joints whose sample gave an output this message appear (a JointState may name a
subset of the joints, as ``robot_state_publisher`` and ``joint_state_publisher`` take it):
a joint whose sample was rejected is left out, never published with an old or a
non-finite value.  Which state fills which field is the runner's ``roles`` (per observer,
docs/ros_interface.md "Per-joint mode"): ``position`` the state the plant measures,
``velocity`` the state the position's derivative equals, ``effort`` the unknown-input
estimate where the observer has one; a field no joint's observer fills stays empty.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError
from .settings import FIELDS


def estimated_joint_states(settings: Mapping[str, Any]):
    """(names, per JointState field the state indices or None) of the
    ``estimated_joint_states.*`` settings, or None when they name no joint."""
    names = settings["estimated_joint_states.joint_names"]
    if not names:
        return None
    idx = []
    for field in FIELDS:
        ix = settings[f"estimated_joint_states.{field}_states"]
        if not ix or all(i < 0 for i in ix):
            idx.append(None)
        elif any(i < 0 for i in ix):
            raise ConfigError(f"estimated_joint_states.{field}_states",
                              "give an index for every joint or for none (JointState fields "
                              "are all-or-nothing)")
        else:
            idx.append(ix)
    return names, idx


class JointOutputPlan:
    """The per-joint mode's output layout (see the module doc)."""

    def __init__(self, joints: Sequence[str], roles, state_names: Sequence[str],
                 unknown_input_names: Sequence[str], convergence_fields: Sequence[str]):
        self.joints = tuple(joints)
        self.state_names = tuple(state_names)
        self.unknown_input_names = tuple(unknown_input_names)
        self.convergence_fields = tuple(convergence_fields)
        self._pos = np.array([r.position for r in roles], np.int64)
        vel = np.array([r.velocity for r in roles], np.int64)
        self._vel = vel if (vel >= 0).all() else None
        kinds = {r.effort[0] for r in roles}
        self._effort_kind = kinds.pop() if len(kinds) == 1 else "none"
        self._eff = np.array([r.effort[1] for r in roles], np.int64)
        self._rows = np.arange(len(self.joints))

    @property
    def has_velocity(self) -> bool:
        return self._vel is not None

    @property
    def has_effort(self) -> bool:
        return self._effort_kind != "none"

    def names(self, rows: np.ndarray) -> tuple[str, ...]:
        """The joint names of ``rows`` (indices of the joints with an output)."""
        return tuple(self.joints[j] for j in rows)

    def labels(self, rows: np.ndarray, what: str) -> tuple[str, ...]:
        """``joint/element`` labels of the per-state outputs of ``rows``: what is 'state',
        'unknown_input' or 'convergence'."""
        elems = {"state": self.state_names, "unknown_input": self.unknown_input_names,
                 "convergence": self.convergence_fields}[what]
        return tuple(f"{self.joints[j]}/{e}" for j in rows for e in elems)

    def fields(self, rows: np.ndarray, x: np.ndarray, ui: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
        """(position, velocity or None, effort or None) of ``rows`` from the estimates x
        (J x n) and the unknown-input estimates ui (J x r)."""
        pos = x[rows, self._pos[rows]]
        vel = None if self._vel is None else x[rows, self._vel[rows]]
        if self._effort_kind == "unknown_input":
            eff = ui[rows, self._eff[rows]]
        elif self._effort_kind == "state":
            eff = x[rows, self._eff[rows]]
        else:
            eff = None
        return pos, vel, eff
