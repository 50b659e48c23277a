"""An arm's rigid-body dynamics from its URDF (ROS-free): the facade the estimators, the
simulator and the node use, on the compiled dynamics of :mod:`.dynamics`.

    M(q) a + C(q, v) v + g(q) + tau_f(v) = tau + tau_ext,     p = M(q) v,
    p' = tau + C(q, v)^T v - g(q) - tau_f(v) + tau_ext        (Mdot = C + C^T, Christoffel C)

for the joints a user lists (``joints``), in the user's order. tau_f is the friction per
listed joint, viscous and Coulomb with a smooth sign: tau_f = b v + f_c tanh(v / w); by
default b and f_c are the URDF's ``<dynamics damping friction>``. The armature (a motor's
rotor inertia through its gear, added to M's diagonal) is ``<dynamics armature>`` (an
attribute of ours) or given per listed joint.

Joints (docs/external_torque.md):

- ``joints`` empty (or None): the arm's chain, :func:`.urdf.default_joints` (the movable,
  non-mimic joints on every root-to-leaf path: a gripper's fingers are never chosen);
- every other movable joint that is no ``<mimic>`` is **passive**: its position is given per
  call (``passive``, in the order of :attr:`RigidBodyModel.passive_joints`; None: the
  defaults, 0 or the position ``locked_joints`` gives) and its velocity is zero: a gripper's
  fingers change the arm's inertia as they move;
- a ``<mimic joint=P multiplier=m offset=o>`` joint follows P: q = m q_P + o, v = m v_P
  (its armature counts m^2 times on P; its friction is not modelled). Listing it is refused
  naming P; locking it, unless at the position P's gives it.

A payload (mass, centre of mass, inertia) at a named frame changes one body's inertia at
run time (:meth:`RigidBodyModel.set_payload`). Refusals are one ``ConfigError`` line naming
the parameter.
"""
from __future__ import annotations

import math
import os
from typing import Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError, FtoRosError, short
from . import dynamics as dyn
from .source import read_source
from .tree import ACTIVE, ARMATURE, MULT, Tree
from .urdf import Urdf, default_joints, parse

#: default width w of the Coulomb friction's smooth sign tanh(v / w), rad/s
DEFAULT_FRICTION_WIDTH = 0.02


class ArmInputError(FtoRosError, ValueError):
    """A call with vectors of the wrong size (a caller's error, not a sample's)."""


def _as_vector(values, n: int, name: str, *, nonnegative: bool = False) -> np.ndarray:
    try:
        arr = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError(name, f"must be a list of numbers, got {short(values)}") from None
    if arr.size == 1 and n > 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n:
        raise ConfigError(name, f"needs one value per joint ({n}), got {arr.size}")
    if not np.all(np.isfinite(arr)) or (nonnegative and np.any(arr < 0)):
        raise ConfigError(name, f"must be finite{' and >= 0' if nonnegative else ''}, got "
                                f"{short(arr.tolist())}")
    return arr


def _roles(robot: Urdf, joints, locked: Mapping[str, float], joints_param: str):
    """(listed joints, passive joints, their default positions), validated."""
    movable = robot.movable
    mimic = {j.name: j.mimic[0] for j in robot.joints if j.mimic is not None}
    fixed = {j.name for j in robot.joints if not j.movable}
    locked = dict(locked or {})
    if joints is None or (not isinstance(joints, str) and len(joints) == 0):
        joints = [j for j in default_joints(robot) if j not in locked]
    joints = [joints] if isinstance(joints, str) else list(joints)
    if not joints:
        raise ConfigError(joints_param, "the URDF has no movable joint left to use")
    if not all(isinstance(j, str) and j for j in joints):
        raise ConfigError(joints_param, f"must be a list of joint names, got {short(joints)}")
    twice = sorted({j for j in joints if joints.count(j) > 1})
    if twice:
        raise ConfigError(joints_param, f"joints listed twice: {', '.join(twice)}")
    missing = [j for j in joints if j not in movable]
    if missing:
        what = [f"{j} (a fixed joint)" if j in fixed else j for j in missing]
        raise ConfigError(joints_param, f"the URDF has no movable joint(s) {', '.join(what)} "
                                        f"(its movable joints: {short(movable)})")
    follows = [f"{j} follows {mimic[j]}" for j in joints if j in mimic]
    if follows:
        raise ConfigError(joints_param, f"<mimic> joint(s) cannot be listed: "
                                        f"{'; '.join(follows)} (list the joint it follows)")
    unknown = [str(j) for j in locked if j not in movable]
    if unknown:
        raise ConfigError("plant.locked_joints", f"the URDF has no joint(s) {', '.join(unknown)}"
                                                 f" that move")
    both = [j for j in locked if j in joints]
    if both:
        raise ConfigError("plant.locked_joints", f"joint(s) {', '.join(both)} are also in "
                                                 f"{joints_param}: a joint moves or is locked")
    passive = [j for j in movable if j not in joints and j not in mimic]
    default = []
    for name in passive:
        value = locked.get(name, 0.0)
        try:
            x = float(value)
        except (TypeError, ValueError):
            x = math.nan
        if not math.isfinite(x):
            raise ConfigError("plant.locked_joints", f"{name}: the position must be a finite "
                                                     f"number, got {short(value)}")
        default.append(x)
    for name in (j for j in locked if j in mimic):    # it follows: only where it is anyway
        src, m, o = robot.mimic_source(name)
        there = m * (default[passive.index(src)] if src in passive else math.nan) + o
        if not abs(float(locked[name]) - there) <= 1e-9 * (1 + abs(there)):
            raise ConfigError("plant.locked_joints", f"{name} follows {src} (<mimic>): it can "
                                                     f"be locked only where {src} puts it ("
                              + (f"{there:.9g})" if src in passive else f"{src} moves)"))
    return joints, passive, np.array(default, dtype=float)


class RigidBodyModel:
    """The dynamics of the listed joints of an arm (see the module doc).

    Every method takes and returns float64 arrays in the order of ``joints``; ``passive``
    (optional everywhere) gives the positions of :attr:`passive_joints`. Call
    :func:`load_model` to build one from parameters."""

    def __init__(self, robot: Urdf, joints: Sequence[str] | None,
                 locked: Mapping[str, float] | None = None, viscous=None, coulomb=None,
                 friction_width: float = DEFAULT_FRICTION_WIDTH, armature=None,
                 joints_param: str = "joints", source_param: str = "robot_description"):
        joints, passive, default = _roles(robot, joints, locked, joints_param)
        self.robot = robot
        self.tree = tree = Tree(robot, joints, passive)
        self.joints, self.n = tuple(joints), len(joints)
        #: the passive joints (the order of every ``passive`` argument) and their defaults
        self.passive_joints, self.passive_default = tuple(passive), default
        #: joint -> (the joint it follows, multiplier, offset)
        self.mimic = {j.name: robot.mimic_source(j.name) for j in robot.joints
                      if j.mimic is not None}
        own = [tree.row_of(j) for j in joints]
        urdf_joint = [robot.joint(j) for j in joints]
        if armature is not None:
            tree.rows[own, ARMATURE] = _as_vector(armature, self.n, "plant.armature",
                                                  nonnegative=True)
        self.armature = tree.rows[own, ARMATURE].copy()
        self.viscous = (np.array([j.damping for j in urdf_joint]) if viscous is None else
                        _as_vector(viscous, self.n, "plant.viscous_friction", nonnegative=True))
        self.coulomb = (np.array([j.friction for j in urdf_joint]) if coulomb is None else
                        _as_vector(coulomb, self.n, "plant.coulomb_friction", nonnegative=True))
        w = float(friction_width) if isinstance(friction_width, (int, float)) else math.nan
        if not (math.isfinite(w) and w > 0):
            raise ConfigError("plant.friction_width", f"must be a finite number > 0, got "
                                                      f"{short(friction_width)}")
        self.friction_width = w
        self.effort_limit = np.array([j.effort for j in urdf_joint])
        diag = np.diag(self.mass_matrix(np.zeros(self.n)))
        dead = [j for j, d in zip(joints, diag) if not d > 0]
        if dead:
            raise ConfigError(source_param, f"joint(s) {', '.join(dead)} move no mass (no "
                                            f"<inertial> below them) and have no armature")

    # -- coordinates ------------------------------------------------------------------------
    def _vec(self, x, what: str) -> np.ndarray:
        a = np.ascontiguousarray(x, dtype=float)
        if a.shape != (self.n,):
            raise ArmInputError(f"{what}: need {self.n} values, got shape {a.shape}")
        return a

    def _passive(self, passive) -> np.ndarray:
        if passive is None:
            return self.passive_default
        a = np.ascontiguousarray(passive, dtype=float)
        if a.shape != self.passive_default.shape:
            raise ArmInputError(f"passive positions: need {self.passive_default.size} values "
                                f"({', '.join(self.passive_joints)}), got shape {a.shape}")
        return a

    @property
    def moving_joints(self) -> tuple[str, ...]:
        """Every movable joint of the URDF (listed, passive, mimic), in tree order."""
        return self.tree.names

    def full_state(self, q, v=None, passive=None) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) of :attr:`moving_joints` at the listed joints' (q, v)."""
        v = np.zeros(self.n) if v is None else self._vec(v, "velocities")
        return dyn.full_coordinates(self.tree.rows, self._vec(q, "positions"),
                                    self._passive(passive), v)

    @property
    def velocity_map(self) -> np.ndarray:
        """G (moving joints x listed joints): the moving joints' velocities are G v."""
        rows = self.tree.rows
        G = np.zeros((rows.shape[0], self.n))
        for i, r in enumerate(rows):
            if r[ACTIVE] >= 0:
                G[i, int(r[ACTIVE])] = r[MULT]
        return G

    # -- dynamics ---------------------------------------------------------------------------
    def mass_matrix(self, q, passive=None) -> np.ndarray:
        """M(q), armature included."""
        return dyn.mass_matrix(self.tree.rows, self.n, self._vec(q, "positions"),
                               self._passive(passive))

    def coriolis_matrix(self, q, v, passive=None) -> np.ndarray:
        """The Christoffel C(q, v): Mdot = C + C^T."""
        return dyn.coriolis_matrix(self.tree.rows, self.n, self._vec(q, "positions"),
                                   self._passive(passive), self._vec(v, "velocities"))

    def coriolis(self, q, v, passive=None) -> np.ndarray:
        """C(q, v) v."""
        return dyn.inverse_dynamics(self.tree.rows, self.n, self._vec(q, "positions"),
                                    self._passive(passive), self._vec(v, "velocities"),
                                    np.zeros(self.n), False)

    def gravity(self, q, passive=None) -> np.ndarray:
        return dyn.gravity(self.tree.rows, self.n, self._vec(q, "positions"),
                           self._passive(passive))

    def bias(self, q, v, passive=None) -> np.ndarray:
        """C(q, v) v + g(q)."""
        return dyn.inverse_dynamics(self.tree.rows, self.n, self._vec(q, "positions"),
                                    self._passive(passive), self._vec(v, "velocities"),
                                    np.zeros(self.n), True)

    def friction(self, v) -> np.ndarray:
        """tau_f(v) = b v + f_c tanh(v / w)."""
        v = np.asarray(v, dtype=float)
        return self.viscous * v + self.coulomb * np.tanh(v / self.friction_width)

    def inverse_dynamics(self, q, v, a, passive=None) -> np.ndarray:
        """tau = M a + C v + g + tau_f (no external torque)."""
        tau = dyn.inverse_dynamics(self.tree.rows, self.n, self._vec(q, "positions"),
                                   self._passive(passive), self._vec(v, "velocities"),
                                   self._vec(a, "accelerations"), True)
        return tau + self.friction(v)

    def forward_dynamics(self, q, v, tau, passive=None) -> np.ndarray:
        """a = M^-1 (tau - C v - g - tau_f); tau includes any external torque."""
        rhs = self._vec(tau, "torques") - self.bias(q, v, passive) - self.friction(v)
        return np.linalg.solve(self.mass_matrix(q, passive), rhs)

    def momentum(self, q, v, passive=None) -> np.ndarray:
        """p = M(q) v."""
        return self.mass_matrix(q, passive) @ self._vec(v, "velocities")

    def mass_derivative(self, q, v, passive=None) -> np.ndarray:
        """Mdot = dM/dt along v."""
        return self.momentum_terms(q, v, False, passive)[1]

    def momentum_terms(self, q, v, mass: bool = True, passive=None):
        """(M, Mdot, C^T v, g) at (q, v), from one kinematic pass: what the estimators' steps
        take from the model (called twice per sample); M is None without ``mass``."""
        n = self.n
        out = dyn.momentum_terms(self.tree.rows, n, self._vec(q, "positions"),
                                 self._passive(passive), self._vec(v, "velocities"), bool(mass))
        return (out[:n * n].reshape(n, n) if mass else None), \
            out[n * n:2 * n * n].reshape(n, n), out[2 * n * n:2 * n * n + n], out[2 * n * n + n:]

    def _frame(self, link: str, param: str = "contact.link"):
        if not isinstance(link, str) or link not in self.tree.frames:
            raise ConfigError(param, f"the URDF has no link or frame {short(link)}")
        return self.tree.frames[link]

    def jacobian(self, link: str, q, passive=None) -> np.ndarray:
        """6 x n Jacobian of the origin of ``link``'s frame (a link or a joint), (linear;
        angular) in world-aligned axes: the joint torques of a wrench (f; m) there are
        J^T (f; m)."""
        body, _, origin = self._frame(link)
        return dyn.jacobian(self.tree.rows, self.n, self._vec(q, "positions"),
                            self._passive(passive), body, origin)

    def frame_pose(self, link: str, q, passive=None) -> tuple[np.ndarray, np.ndarray]:
        """(R, p): ``link``'s frame axes (columns, world axes) and origin (world) at q."""
        body, axes, origin = self._frame(link, "wrench.frame")
        return dyn.frame_pose(self.tree.rows, self.n, self._vec(q, "positions"),
                              self._passive(passive), body, np.ascontiguousarray(axes), origin)

    def wrench(self, link: str, q, tau_ext, damping: float = 0.0, passive=None) -> np.ndarray:
        """The wrench (f; m) at the origin of ``link``'s frame, world axes, whose joint torques
        J^T (f; m) match ``tau_ext`` best: damped least squares, w = (J J^T + damping^2 I)^-1
        J tau_ext (damping 0: the minimum-norm least-squares solution): the contact wrench a
        tau_ext estimate implies, if the contact is on that link."""
        J = self.jacobian(link, q, passive)
        tau = np.asarray(tau_ext, dtype=float)
        if damping > 0:
            return np.linalg.solve(J @ J.T + damping ** 2 * np.eye(6), J @ tau)
        return np.linalg.lstsq(J.T, tau, rcond=1e-9)[0]

    def set_payload(self, frame: str, mass: float, com=(0.0, 0.0, 0.0),
                    inertia=((0.0, 0.0, 0.0),) * 3) -> None:
        """A payload at ``frame`` (see :meth:`.tree.Tree.set_payload`; mass 0 removes it),
        used from the next call on; nothing else is rebuilt."""
        self.tree.set_payload(frame, mass, com, inertia)

    def correct_inertia(self, scale=None, delta=None) -> None:
        """Identified inertial corrections (``plant.inertia_scale``: {link: factor},
        ``plant.inertia_delta``: {link: 10 values}; :meth:`.tree.Tree.correct_inertia`)."""
        self.tree.correct_inertia(scale, delta)


def load_model(joints: Sequence[str] | None, *, urdf: str | os.PathLike | None = None,
               robot_description: str | None = None,
               locked_joints: Mapping[str, float] | None = None,
               viscous_friction=None, coulomb_friction=None,
               friction_width: float = DEFAULT_FRICTION_WIDTH, armature=None,
               inertia_scale=None, inertia_delta=None) -> RigidBodyModel:
    """A :class:`RigidBodyModel` from a URDF file (``plant.urdf``) or string
    (``robot_description``), the joints to use (``joints``; None or empty: the arm's
    chain) and the default positions of passive joints (``plant.locked_joints``); friction
    and armature per listed joint (None: the URDF's); identified inertial corrections
    (:meth:`RigidBodyModel.correct_inertia`)."""
    text, param = read_source(urdf, robot_description)
    robot = parse(text, param)
    model = RigidBodyModel(robot, joints, locked_joints or {}, viscous_friction,
                           coulomb_friction, friction_width, armature, source_param=param)
    if inertia_scale or inertia_delta:
        model.correct_inertia(inertia_scale, inertia_delta)
    return model
