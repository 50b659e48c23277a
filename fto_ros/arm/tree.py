"""An arm's kinematic tree as packed float64 arrays for the compiled dynamics
(:mod:`.dynamics`), and the payloads that change its inertias at run time (ROS-free).

One row per moving body, that is per movable joint of the URDF (fixed joints merged: a
link fixed to another is part of its body), parents before children. Columns (:data:`COL`):

- ``TYPE`` 0 revolute or continuous, 1 prismatic; ``PARENT`` the parent body's row (-1:
  the root, fixed to the world);
- ``AXIS`` (3) the joint axis, unit, in the body's frame (= the joint's child frame);
- ``ROT`` (9, row-major) and ``POS`` (3): the joint frame at q = 0 in the parent body's
  frame (axes and origin);
- ``INERTIA`` (10): the body's mass m, first moment h = m c (3) and rotational inertia about
  the body's origin (Ixx, Iyy, Izz, Iyz, Ixz, Ixy), body axes; the URDF's links merged
  into it plus the payloads attached to it;
- ``ARMATURE``: rotor inertia through the gear, on this joint's coordinate;
- the coordinate map: q_body = ``MULT`` x + ``OFFSET`` and v_body = ``MULT`` v_x, where x is
  the listed joint ``ACTIVE`` (its index in ``joints``) or the passive joint ``PASSIVE`` (its
  index in the passive vector; then v_body = 0). A listed or passive joint maps to itself
  (MULT 1, OFFSET 0); a ``<mimic>`` joint to the joint it follows.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.errors import ConfigError, short
from .urdf import Urdf, check_inertia

TYPE, PARENT, AXIS, ROT, POS, INERTIA, ARMATURE, MULT, OFFSET, ACTIVE, PASSIVE = \
    0, 1, 2, 5, 14, 17, 27, 28, 29, 30, 31
#: columns of a row
COL = 32


def inertia_params(mass: float, com, inertia_com, R=np.eye(3), p=np.zeros(3)) -> np.ndarray:
    """The 10 inertia parameters about a frame's origin, in its axes, of a body of ``mass``,
    centre of mass ``com`` and rotational inertia ``inertia_com`` (about the centre of mass),
    both given in a frame placed at (R, p) in it."""
    c = R @ np.asarray(com, dtype=float) + p
    I = R @ np.asarray(inertia_com, dtype=float) @ R.T + mass * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([mass, *(mass * c), I[0, 0], I[1, 1], I[2, 2], I[1, 2], I[0, 2], I[0, 1]])


def shift_params(params, R=np.eye(3), p=np.zeros(3)) -> np.ndarray:
    """The 10 inertia parameters (m, h, I about the origin, :func:`inertia_params`' order)
    of a frame, re-expressed about the origin and in the axes of a frame in which it sits at
    (R, p); linear in ``params`` (so a correction, even with a negative mass, maps too)."""
    m, h = params[0], R @ np.asarray(params[1:4], dtype=float)
    xx, yy, zz, yz, xz, xy = params[4:10]
    I = R @ np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]) @ R.T + \
        m * (p @ p * np.eye(3) - np.outer(p, p)) + 2 * (p @ h) * np.eye(3) - np.outer(p, h) - \
        np.outer(h, p)
    return np.array([m, *(h + m * p), I[0, 0], I[1, 1], I[2, 2], I[1, 2], I[0, 2], I[0, 1]])


def _refuse(param: str):
    def fail(message: str):
        raise ConfigError(param, message)
    return fail


class Tree:
    """The packed tree of a validated :class:`~.urdf.Urdf`, for the joints ``active`` (in
    that order) and ``passive`` (in that order); every other movable joint is a mimic.

    Attributes: ``rows`` (nb x :data:`COL`), ``names`` (the joint of each row), ``n`` (listed
    joints), ``frames`` (link or joint name -> (row or -1, axes, origin in that body))."""

    def __init__(self, robot: Urdf, active: list[str], passive: list[str]):
        self.robot = robot
        moving = [j for j in robot.joints if j.movable]
        self.names = tuple(j.name for j in moving)
        row = {name: i for i, name in enumerate(self.names)}
        self.n, self.n_passive = len(active), len(passive)
        rows = np.zeros((len(moving), COL))
        # where each link is: (body row, axes, origin) in that body; the root's row is -1
        place = {robot.root: (-1, np.eye(3), np.zeros(3))}
        for j in robot.joints:
            b, R, p = place[j.parent]
            R_j, p_j = R @ j.rotation, p + R @ j.xyz
            if not j.movable:
                place[j.child] = (b, R_j, p_j)
                continue
            i = row[j.name]
            place[j.child] = (i, np.eye(3), np.zeros(3))
            r = rows[i]
            r[TYPE] = 1.0 if j.kind == "prismatic" else 0.0
            r[PARENT] = b
            r[AXIS:AXIS + 3] = j.axis
            r[ROT:ROT + 9] = R_j.ravel()
            r[POS:POS + 3] = p_j
            r[ARMATURE] = j.armature
            src, m, o = robot.mimic_source(j.name)
            r[MULT], r[OFFSET] = m, o
            r[ACTIVE] = active.index(src) if src in active else -1
            r[PASSIVE] = passive.index(src) if src in passive else -1
        self.frames = dict(place)
        for j in robot.joints:               # a joint's frame is its child link's
            self.frames.setdefault(j.name, place[j.child])
        self.base = np.zeros((len(moving), 10))
        for link, inertial in robot.links.items():
            b, R, p = place[link]
            if inertial is not None and b >= 0:
                self.base[b] += inertia_params(inertial.mass, inertial.com, inertial.inertia, R, p)
        rows[:, INERTIA:INERTIA + 10] = self.base
        self.rows = rows
        self.payloads: dict[str, np.ndarray] = {}
        #: the URDF's inertias per body, before any correction (:meth:`correct_inertia`)
        self.urdf_base = self.base.copy()
        self.inertia_scale: dict[str, float] = {}
        self.inertia_delta: dict[str, np.ndarray] = {}

    def row_of(self, joint: str) -> int:
        return self.names.index(joint)

    def subtree_mass(self) -> np.ndarray:
        """The mass each row's joint moves (its body and every body below it)."""
        m = self.rows[:, INERTIA].copy()
        for i in range(len(m) - 1, -1, -1):
            p = int(self.rows[i, PARENT])
            if p >= 0:
                m[p] += m[i]
        return m

    def link_params(self, link: str) -> tuple[int, np.ndarray]:
        """(body row, the link's own 10 inertia parameters in that body) of a link with an
        ``<inertial>`` that moves (row -1 and zeros otherwise)."""
        inertial = self.robot.links.get(link)
        b, R, p = self.frames.get(link, (-1, None, None))
        if inertial is None or b < 0:
            return -1, np.zeros(10)
        return b, inertia_params(inertial.mass, inertial.com, inertial.inertia, R, p)

    def correct_inertia(self, scale=None, delta=None) -> None:
        """The identified corrections (fto-identify): ``scale`` {link: factor} multiplies a
        link's mass, first moment and inertia (``plant.inertia_scale``); ``delta`` {link: 10
        values} adds to a link's parameters (m, m c, inertia about its origin: xx, yy, zz, yz,
        xz, xy, link axes; ``plant.inertia_delta``). Replaces earlier corrections; payloads
        stay."""
        base = self.urdf_base.copy()
        for link, factor in (scale or {}).items():
            b, params = self.link_params(link)
            if b < 0:
                raise ConfigError("plant.inertia_scale.links", f"{short(link)} is no link with "
                                                              f"an <inertial> that moves")
            f = float(factor)
            if not (math.isfinite(f) and f > 0):
                raise ConfigError("plant.inertia_scale.factors", f"{link}: must be a finite "
                                                                f"number > 0, got {short(factor)}")
            base[b] += (f - 1.0) * params
        for link, values in (delta or {}).items():
            b, R, p = self.frames.get(link, (-1, None, None)) if isinstance(link, str) else \
                (-1, None, None)
            d = np.asarray(values, dtype=float).reshape(-1)
            if b < 0:
                raise ConfigError("plant.inertia_delta.links", f"{short(link)} is no link that "
                                                              f"moves")
            if d.size != 10 or not np.all(np.isfinite(d)):
                raise ConfigError("plant.inertia_delta.values", f"{link}: 10 finite values")
            base[b] += shift_params(d, R, p)
        if np.any(base[:, 0] < 0):
            raise ConfigError("plant.inertia_scale.factors", "the corrections make a body's "
                                                            "mass negative")
        self.base = base
        #: the corrections applied (the prior of a new identification)
        self.inertia_scale = {str(k): float(v) for k, v in (scale or {}).items()}
        self.inertia_delta = {str(k): np.asarray(v, dtype=float).reshape(10).copy()
                              for k, v in (delta or {}).items()}
        self._refresh()

    # -- payloads ----------------------------------------------------------------------------
    def set_payload(self, frame: str, mass: float, com=(0.0, 0.0, 0.0),
                    inertia=((0.0, 0.0, 0.0),) * 3, param: str = "payload") -> None:
        """Attach (or replace, or with mass 0 remove) the payload at ``frame``: ``mass`` (kg),
        centre of mass ``com`` and rotational inertia about it ``inertia`` (3 x 3, or the six
        values ixx, iyy, izz, iyz, ixz, ixy), both in the frame's axes. Only that body's
        inertia row changes."""
        if not isinstance(frame, str) or frame not in self.frames:
            raise ConfigError(param, f"the URDF has no link or frame {short(frame)}")
        try:
            m = float(mass)
            c = np.asarray(com, dtype=float).reshape(3)
            I = np.asarray(inertia, dtype=float)
            if I.size == 6:
                xx, yy, zz, yz, xz, xy = I.ravel()
                I = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
            I = I.reshape(3, 3)
        except (TypeError, ValueError):
            raise ConfigError(param, f"mass, com (3) and inertia (3 x 3 or 6) as numbers, got "
                                     f"{short(mass)}, {short(com)}, {short(inertia)}") from None
        if not (math.isfinite(m) and m >= 0 and np.all(np.isfinite(c))):
            raise ConfigError(param, f"the mass must be a finite number >= 0 and the centre of "
                                     f"mass finite, got {short(mass)}, {short(com)}")
        if not np.allclose(I, I.T, rtol=1e-12, atol=0):
            raise ConfigError(param, "the inertia must be symmetric")
        if np.any(I != 0):        # a point mass has none; else a rigid body's
            check_inertia(I, _refuse(param))
        b, R, p = self.frames[frame]
        self.payloads.pop(frame, None)
        if m > 0:
            self.payloads[frame] = inertia_params(m, c, I, R, p)
        self._refresh()

    def _refresh(self) -> None:
        total = self.base.copy()
        for name, params in self.payloads.items():
            if self.frames[name][0] >= 0:
                total[self.frames[name][0]] += params
        self.rows[:, INERTIA:INERTIA + 10] = total
