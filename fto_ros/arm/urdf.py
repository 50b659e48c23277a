"""A URDF read as an arm's physics (ROS-free): the XML checks, every link's inertia and
every joint's placement, axis, dynamics and ``<mimic>``, validated before anything uses
them; the tree order; the default joint list.

Refusals are one ``ConfigError`` line naming the source's parameter (``plant.urdf`` or
``robot_description``) and, in the message, the link or joint:

- the text: a NUL character, not UTF-8, XML that does not parse (Python's expat refuses
  entity-expansion bombs), a root that is not ``<robot>``, more than :data:`MAX_JOINTS`
  joints;
- the structure: names twice, a joint whose parent or child link does not exist, a link
  that is the child of two joints, not exactly one root, a cycle;
- the physics (issue 28 item 4): a mass that is not a finite number > 0 (urdfdom and so
  Pinocchio drop a NaN or inf mass silently: the XML is read here) -- a mass of 0 with an
  inertia tensor of zeros is a massless frame (a link with no ``<inertial>``), a mass of 0
  with any other tensor is refused --, every mass zero, an
  inertia tensor that is not finite, not positive definite, or breaks the triangle
  inequality (each principal moment at most the sum of the other two, within
  :data:`TRIANGLE_TOLERANCE` of the largest); a zero or non-finite joint axis; damping,
  friction or armature that is not a finite number >= 0; an origin or limit that is not
  numbers;
- joints: an unknown type, a ``<mimic>`` of a joint that does not exist or does not move,
  of itself, or a cycle of mimics. A floating or planar joint (a mobile base under the arm)
  is read as fixed at its neutral pose (its origin), and :attr:`Urdf.notes` says so.

The ``armature`` attribute of ``<dynamics>`` (a motor's rotor inertia through its gear) is
ours: urdfdom ignores it.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from ..core.errors import ConfigError, short

#: most joints a URDF may declare: with the external-torque node's window estimator
#: (T = 60 ms at 1 kHz) a chain of 256 configures in 1.0-1.4 s and 190 MB above the imports
#: (benchmarks/bench_urdf_size.py, docs/external_torque.md)
MAX_JOINTS = 256
#: a principal moment may exceed the sum of the other two by this fraction of the largest
#: (the rounding of published inertias), no more
TRIANGLE_TOLERANCE = 1e-4
MOVABLE = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class Inertial:
    """A link's mass, centre of mass (link axes) and inertia about it (link axes, 3 x 3)."""
    mass: float
    com: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class Joint:
    name: str
    kind: str                     # revolute, continuous, prismatic, fixed
    parent: str
    child: str
    xyz: np.ndarray               # origin of the child frame in the parent link's frame
    rotation: np.ndarray          # the child frame's axes in the parent's (from rpy)
    axis: np.ndarray              # unit, in the child frame
    damping: float = 0.0
    friction: float = 0.0
    armature: float = 0.0
    effort: float = math.inf
    mimic: tuple | None = None    # (joint, multiplier, offset) as written

    @property
    def movable(self) -> bool:
        return self.kind in MOVABLE


@dataclass(frozen=True)
class Urdf:
    """The robot: its root link, links (name -> Inertial or None) and joints in tree order
    (depth first from the root, siblings in the document's order: parents first)."""
    name: str
    root: str
    links: dict
    joints: tuple
    #: what was read otherwise than written (a floating or planar joint taken as fixed)
    notes: tuple = ()

    def joint(self, name: str) -> Joint | None:
        return next((j for j in self.joints if j.name == name), None)

    @property
    def movable(self) -> list[str]:
        return [j.name for j in self.joints if j.movable]

    def mimic_source(self, name: str) -> tuple[str, float, float]:
        """(the non-mimic joint a joint follows, multiplier, offset), composed along a chain
        of mimics: q = m q_source + o; (name, 1, 0) for a joint that is no mimic."""
        m, o = 1.0, 0.0
        j = self.joint(name)
        while j.mimic is not None:
            src, mj, oj = j.mimic
            m, o = m * mj, m * oj + o
            j = self.joint(src)
        return j.name, m, o


def rotation_rpy(r: float, p: float, y: float) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw: Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), \
        math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


class _Reader:
    """Attribute parsing with refusals naming the source's parameter and the element."""

    def __init__(self, param: str):
        self.param = param
        self.notes: list[str] = []

    def fail(self, message: str):
        raise ConfigError(self.param, message)

    def name(self, el, seen) -> str:
        """The name of a <link> or <joint>, new among ``seen``."""
        name = el.get("name")
        if not name:
            self.fail(f"a <{el.tag}> without a name")
        if name in seen:
            self.fail(f"{el.tag} {short(name)} is defined twice")
        return name

    def numbers(self, el, attr: str, count: int, where: str, default=None) -> list[float]:
        text = None if el is None else el.get(attr)
        if text is None:
            if default is None:
                self.fail(f"{where}: <{'?' if el is None else el.tag}> needs {attr}=")
            return list(default)
        try:
            values = [float(x) for x in text.split()]
        except ValueError:
            values = []
        if len(values) != count or not all(math.isfinite(x) for x in values):
            self.fail(f"{where}: {attr} must be {count} finite number"
                      f"{'s' if count > 1 else ''}, got {short(text)}")
        return values

    def number(self, el, attr: str, where: str, default: float, minimum: float | None = 0.0,
               finite: bool = True) -> float:
        text = el.get(attr) if el is not None else None
        if text is None:
            return default
        try:
            x = float(text)
        except ValueError:
            x = math.nan
        if math.isnan(x) or (finite and not math.isfinite(x)) or \
                (minimum is not None and x < minimum):
            need = "a finite number" if finite else "a number"
            self.fail(f"{where}: {attr} must be {need}"
                      f"{f' >= {minimum:g}' if minimum is not None else ''}, got {short(text)}")
        return x

    def origin(self, el, where: str) -> tuple[np.ndarray, np.ndarray]:
        o = el.find("origin")
        xyz = self.numbers(o, "xyz", 3, f"{where} <origin>", (0.0, 0.0, 0.0))
        rpy = self.numbers(o, "rpy", 3, f"{where} <origin>", (0.0, 0.0, 0.0))
        return np.array(xyz), rotation_rpy(*rpy)

    def inertial(self, link) -> Inertial | None:
        name = link.get("name")
        el = link.find("inertial")
        if el is None:
            return None
        where = f"link {short(name)}"
        com, R = self.origin(el, where)
        mass_el = el.find("mass")
        if mass_el is None or mass_el.get("value") is None:
            self.fail(f"{where}: <inertial> needs <mass value=...>")
        try:
            mass = float(mass_el.get("value"))
        except ValueError:
            mass = math.nan
        if not (math.isfinite(mass) and mass >= 0):
            self.fail(f"{where}: the mass must be a finite number > 0, got "
                      f"{short(mass_el.get('value'))}")
        tensor = el.find("inertia")
        if tensor is None:
            self.fail(f"{where}: <inertial> needs <inertia>")
        v = {}
        for a in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
            text = tensor.get(a)
            try:
                v[a] = float(text)
            except (TypeError, ValueError):
                self.fail(f"{where}: <inertia> needs {a} as a number, got {short(text)}")
            if not math.isfinite(v[a]):
                self.fail(f"{where}: the inertia {a} must be finite, got {short(text)}")
        I = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]],
                      [v["ixz"], v["iyz"], v["izz"]]])
        if mass == 0:                    # a massless frame, or refused
            if np.any(I != 0):
                self.fail(f"{where}: the mass must be a finite number > 0, got 0 with a "
                          f"non-zero inertia tensor (a massless frame has every ixx..izz 0)")
            return None
        check_inertia(I, lambda msg: self.fail(f"{where}: {msg}"))
        return Inertial(mass, com, R @ I @ R.T)

    def joint(self, el) -> Joint:
        name = el.get("name")
        where = f"joint {short(name)}"
        kind = el.get("type")
        if kind in ("floating", "planar"):
            self.notes.append(f"{where} is {kind}: read as fixed at its neutral pose (a mobile "
                              f"base under the arm does not move in this model)")
            kind = "fixed"
        if kind not in MOVABLE + ("fixed",):
            self.fail(f"{where}: unknown type {short(kind)}")
        links = []
        for tag in ("parent", "child"):
            e = el.find(tag)
            if e is None or not e.get("link"):
                self.fail(f"{where}: needs <{tag} link=...>")
            links.append(e.get("link"))
        xyz, R = self.origin(el, where)
        axis = np.array(self.numbers(el.find("axis"), "xyz", 3, f"{where} <axis>",
                                     (1.0, 0.0, 0.0)))
        norm = float(np.linalg.norm(axis))
        if kind != "fixed" and not (math.isfinite(norm) and norm > 0):
            self.fail(f"{where}: the axis is zero")
        dyn, limit, mimic = el.find("dynamics"), el.find("limit"), el.find("mimic")
        values = {a: self.number(dyn, a, where, 0.0) for a in ("damping", "friction", "armature")}
        effort = self.number(limit, "effort", where, math.inf, finite=False)
        for a in ("lower", "upper", "velocity"):
            self.number(limit, a, where, 0.0, minimum=None, finite=False)
        if mimic is not None:
            if kind == "fixed":
                self.fail(f"{where}: a <mimic> needs a movable joint, this one is fixed")
            if not mimic.get("joint"):
                self.fail(f"{where}: <mimic> needs joint=")
            mimic = (mimic.get("joint"), self.number(mimic, "multiplier", where, 1.0, None),
                     self.number(mimic, "offset", where, 0.0, None))
        return Joint(name, kind, links[0], links[1], xyz, R,
                     axis / norm if kind != "fixed" else axis, effort=effort, mimic=mimic,
                     **values)


def check_inertia(I: np.ndarray, fail) -> None:
    """Refuse (``fail(message)``) a rotational inertia that is not finite, not positive
    definite, or breaks the triangle inequality."""
    if not np.all(np.isfinite(I)):
        fail("the inertia tensor is not finite")
    moments = np.linalg.eigvalsh(I)
    if not moments[0] > 0:
        fail(f"the inertia tensor is not positive definite (principal moments "
             f"{', '.join(f'{x:.6g}' for x in moments)})")
    if moments[2] > moments[0] + moments[1] + TRIANGLE_TOLERANCE * moments[2]:
        fail(f"the inertia tensor breaks the triangle inequality (principal moment "
             f"{moments[2]:.6g} > {moments[0]:.6g} + {moments[1]:.6g}): no rigid body has it")


def check_xml(text: str, param: str) -> ET.Element:
    """The parsed <robot> element, its size bounded."""
    if "\x00" in text:
        raise ConfigError(param, "not a URDF: the text holds a NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as err:
        raise ConfigError(param, f"not a URDF: not encodable as UTF-8 ({err.reason} at "
                                 f"character {err.start})") from None
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise ConfigError(param, f"not a URDF: the XML does not parse ({err})") from None
    if root.tag != "robot":
        raise ConfigError(param, f"not a URDF: the root element is <{short(root.tag)}>, "
                                 f"not <robot>")
    joints = root.findall("joint")
    if len(joints) > MAX_JOINTS:
        raise ConfigError(param, f"{len(joints)} joints: more than the {MAX_JOINTS} accepted "
                                 f"(docs/external_torque.md)")
    return root


def parse(text: str, param: str) -> Urdf:
    """The validated robot of a URDF text (see the module doc)."""
    root = check_xml(text, param)
    read = _Reader(param)
    links = {}
    for el in root.findall("link"):
        links[read.name(el, links)] = read.inertial(el)
    if not links:
        read.fail("not a URDF: no <link>")
    joints, parent_of = {}, {}
    for el in root.findall("joint"):
        name = read.name(el, joints)
        j = read.joint(el)
        for link in (j.parent, j.child):
            if link not in links:
                read.fail(f"joint {short(name)}: there is no link {short(link)}")
        if j.child in parent_of:
            read.fail(f"link {short(j.child)} is the child of two joints, "
                      f"{short(parent_of[j.child])} and {short(name)}")
        parent_of[j.child] = name
        joints[name] = j
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        read.fail(f"not a tree: {len(roots)} root links ({short(roots)}), one expected"
                  if roots else "not a tree: every link is a child (a cycle)")
    children = {}
    for j in joints.values():
        children.setdefault(j.parent, []).append(j)
    order = _depth_first(roots[0], children)
    if len(order) != len(joints):
        lost = sorted(set(joints) - {j.name for j in order})
        read.fail(f"not a tree: joint(s) {short(lost)} are on a cycle")
    if all(i is None for i in links.values()):
        read.fail("every link's mass is zero (no <inertial>): the arm has no dynamics")
    robot = Urdf(root.get("name") or "", roots[0], links, tuple(order), tuple(read.notes))
    _check_mimics(robot, read)
    return robot


def _depth_first(root: str, children: dict) -> list[Joint]:
    out, stack = [], [(root, 0)]
    while stack:
        link, k = stack.pop()
        kids = children.get(link, [])
        if k < len(kids):
            stack.append((link, k + 1))
            out.append(kids[k])
            stack.append((kids[k].child, 0))
    return out


def _check_mimics(robot: Urdf, read: _Reader) -> None:
    for j in robot.joints:
        seen = [j.name]
        k = j
        while k.mimic is not None:
            src = robot.joint(k.mimic[0])
            if src is None or not src.movable:
                read.fail(f"joint {short(k.name)}: <mimic joint={short(k.mimic[0])}> is not a "
                          f"movable joint of the URDF")
            if src.name in seen:
                read.fail(f"joint {short(j.name)}: its <mimic> chain is a cycle "
                          f"({' -> '.join(seen + [src.name])})")
            seen.append(src.name)
            k = src


def default_joints(robot: Urdf) -> list[str]:
    """The arm's chain: the movable, non-mimic joints on every root-to-leaf path that has
    any (a parallel gripper's fingers branch off it and are never chosen); if none, every
    movable non-mimic joint. Tree order."""
    own = [j for j in robot.joints if j.movable and j.mimic is None]
    by_child = {j.child: j for j in robot.joints}
    parents = {j.parent for j in robot.joints}
    leaves = [link for link in robot.links if link not in parents]
    common = None
    for leaf in leaves:
        on_path, link = set(), leaf
        while link in by_child:
            j = by_child[link]
            if j.movable and j.mimic is None:
                on_path.add(j.name)
            link = j.parent
        if on_path:
            common = on_path if common is None else common & on_path
    trunk = [j.name for j in own if common and j.name in common]
    return trunk or [j.name for j in own]
