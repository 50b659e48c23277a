"""What the arm simulator reads from a URDF's text itself (ROS-free): the joints' tree,
limits and ``<mimic>`` elements, the arm's trunk, and a simulated arm that differs from the
URDF (the model error of ``fto-simulate --urdf --model-error``).

The dynamics come from :func:`fto_ros.arm.load_model`; this module only decides which
joints move how and rewrites inertials. ``<mimic>`` elements are removed from the text the
simulator loads (:func:`without_mimic`): the simulator moves a mimic joint itself, as a
coordinate of its own that follows its parent exactly (q = multiplier q_parent + offset).
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from ..core.errors import ConfigError, short

MOVABLE = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class UrdfJoint:
    """A joint as the URDF writes it (lower/upper: -inf/inf when it has no finite limit;
    mimic: (parent joint, multiplier, offset) or None)."""
    name: str
    kind: str
    parent: str
    child: str
    lower: float
    upper: float
    mimic: tuple[str, float, float] | None


def _number(text, default: float, what: str) -> float:
    if text is None:
        return default
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not math.isfinite(x):
        raise ConfigError("urdf", f"{what}: not a finite number: {short(text)}")
    return x


def urdf_joints(text: str) -> dict[str, UrdfJoint]:
    """Every joint of the URDF text, in the file's order (ConfigError when the XML does not
    parse or a mimic joint names a joint the URDF does not have)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise ConfigError("urdf", f"the XML does not parse ({err})") from None
    out = {}
    for j in root.findall("joint"):
        name, kind = j.get("name", ""), j.get("type", "")
        parent, child = j.find("parent"), j.find("child")
        lim, mim = j.find("limit"), j.find("mimic")
        lower = upper = math.nan
        if kind in ("revolute", "prismatic") and lim is not None:
            lower = _number(lim.get("lower"), 0.0, f"joint {name} lower limit")
            upper = _number(lim.get("upper"), 0.0, f"joint {name} upper limit")
        if not (lower < upper):
            lower, upper = -math.inf, math.inf
        mimic = None
        if mim is not None:
            mimic = (mim.get("joint", ""), _number(mim.get("multiplier"), 1.0, f"joint {name} "
                     f"mimic multiplier"), _number(mim.get("offset"), 0.0, f"joint {name} "
                                                                          f"mimic offset"))
        out[name] = UrdfJoint(name, kind, "" if parent is None else parent.get("link", ""),
                              "" if child is None else child.get("link", ""), lower, upper, mimic)
    for j in out.values():
        if j.mimic and (j.mimic[0] not in out or out[j.mimic[0]].kind not in MOVABLE):
            raise ConfigError("urdf", f"joint {j.name} mimics {short(j.mimic[0])}, which is "
                                      f"not a movable joint of the URDF")
    return out


def trunk(joints: dict[str, UrdfJoint]) -> list[str]:
    """The arm's chain: the movable joints on every root-to-leaf path of movable joints (a
    parallel gripper's fingers branch off it); when that is empty, every movable joint.
    Mimic joints are never in it."""
    by_child = {j.child: j for j in joints.values()}
    movable = [j for j in joints.values() if j.kind in MOVABLE]

    def chain(j: UrdfJoint) -> list[str]:            # movable joints from the root to j
        out, link, seen = [], j.child, set()
        while link in by_child and link not in seen:
            seen.add(link)
            above = by_child[link]
            if above.kind in MOVABLE:
                out.append(above.name)
            link = above.parent
        return out[::-1]

    chains = {j.name: chain(j) for j in movable}
    leaves = [n for n in chains if not any(n in c[:-1] for c in chains.values())]
    common = set(chains[leaves[0]]) if leaves else set()
    for n in leaves[1:]:
        common &= set(chains[n])
    order = [j.name for j in movable if j.name in common and not j.mimic]
    return order or [j.name for j in movable if not j.mimic]


def without_mimic(text: str) -> str:
    """The URDF text without its ``<mimic>`` elements (each mimic joint an ordinary joint)."""
    root = ET.fromstring(text)
    for j in root.findall("joint"):
        for m in j.findall("mimic"):
            j.remove(m)
    return ET.tostring(root, encoding="unicode")


#: a centre of mass moves by up to error x this length (m) per coordinate
COM_LENGTH = 0.1


def perturbed(text: str, error: float, seed: int) -> tuple[str, dict]:
    """The URDF text of an arm whose links differ from ``text``'s: per link with an
    ``<inertial>``, the mass times (1 + e_m), the inertia tensor (about the centre of mass)
    times (1 + e_I), each centre-of-mass coordinate moved by e_c COM_LENGTH, with e_m, e_I,
    e_c independent and uniform in [-error, error] (``seed``: reproducible); and the record
    {link: {mass_scale, inertia_scale, com_shift, mass}}. A scaled tensor stays positive
    definite and keeps the triangle inequality."""
    if not (isinstance(error, (int, float)) and 0.0 <= error < 1.0):
        raise ConfigError("model_error", f"must be in [0, 1), got {short(error)}")
    root = ET.fromstring(text)
    rng = np.random.default_rng([int(seed), 7001])
    record = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        name = link.get("name", "")
        e_m, e_i = rng.uniform(-error, error, 2)
        e_c = rng.uniform(-error, error, 3) * COM_LENGTH
        mass = inertial.find("mass")
        if mass is not None:
            m = _number(mass.get("value"), 0.0, f"link {name} mass") * (1 + e_m)
            mass.set("value", repr(float(m)))
        inertia = inertial.find("inertia")
        if inertia is not None:
            for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                x = _number(inertia.get(key), 0.0, f"link {name} {key}")
                inertia.set(key, repr(float(x * (1 + e_i))))
        origin = inertial.find("origin")
        if origin is None:
            origin = ET.SubElement(inertial, "origin")
        xyz = [_number(x, 0.0, f"link {name} origin") for x in origin.get("xyz", "0 0 0").split()]
        if len(xyz) != 3:
            raise ConfigError("urdf", f"link {name}: the inertial origin needs 3 coordinates")
        origin.set("xyz", " ".join(repr(float(c + d)) for c, d in zip(xyz, e_c)))
        record[name] = {"mass_scale": 1 + float(e_m), "inertia_scale": 1 + float(e_i),
                        "com_shift": [float(d) for d in e_c],
                        "mass": None if mass is None else float(mass.get("value"))}
    return ET.tostring(root, encoding="unicode"), record
