"""Joints as an axis: one observer of a one-joint plant per joint of an arm.

With ``joints: [a1, ..., a7]`` the plant block is the model of ONE joint; every joint gets
its own observer of it, built from the same parameters except the constants written per
joint in ``plant.constants`` as ``"name=[v1, ..., vJ]"`` (one value per joint, in the
order of ``joints``).  The runner runs all of them in one compiled call per message (the
rows of one array per kind of memory), each with its own state, clock, gate, counters and
restarts: one joint's bad sample rejects or restarts that joint only.

What a joint publishes (its position, velocity and effort in a JointState) is read off
the plant: the position is the state the plant measures (``h = [q]``), the velocity the
state its derivative equals (``f[q] = q_dot``), the effort the observer's unknown-input
estimate when it identifies one; ``joint_roles.position_state``, ``joint_roles.velocity_state`` and
``joint_roles.effort`` say otherwise.  ROS-free.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import sympy

from ..core.errors import ConfigError, short

CONSTANTS = "plant.constants"
_LIST = re.compile(r"^\s*\[(.*)\]\s*$", re.S)


def _values(text: str, where: str, count: int) -> list[str] | None:
    """The per-joint values of a constant's text, or None for a plain (shared) value."""
    name, sep, value = text.partition("=")
    match = _LIST.match(value) if sep else None
    if match is None:
        return None
    items = [v.strip() for v in match.group(1).split(",") if v.strip()]
    if len(items) != count:
        raise ConfigError(where, f"{name.strip()} has {len(items)} value(s) for {count} joint(s): "
                          "give one per joint, in the order of 'joints'")
    for v in items:
        try:
            ok = math.isfinite(float(v))
        except ValueError:
            ok = False
        if not ok:
            raise ConfigError(where, f"{name.strip()}: {short(v)} is not a finite number")
    return [f"{name.strip()}={v}" for v in items]


def per_joint(flat: Mapping[str, Any], joints: Sequence[str]) -> list[dict[str, Any]]:
    """The flat parameters of each joint's observer: the same, with each per-joint constant
    replaced by that joint's value, and each ``joint_overrides`` entry's value for that
    joint.  ConfigError for a malformed per-joint constant or override."""
    if len(set(joints)) != len(joints):
        dup = next(j for j in joints if list(joints).count(j) > 1)
        raise ConfigError("joints", f"joint {short(dup)} is listed twice")
    texts = flat.get(CONSTANTS) or []
    columns = [(_values(t, f"{CONSTANTS}[{i}]", len(joints)) if isinstance(t, str) else None)
               for i, t in enumerate(texts)]
    overrides = overrides_by_joint(flat.get(OVERRIDES) or [], len(joints))
    out = []
    for j in range(len(joints)):
        f = dict(flat)
        if texts:
            f[CONSTANTS] = [t if col is None else col[j] for t, col in zip(texts, columns)]
        f.update({name: values[j] for name, values in overrides.items()})
        out.append(f)
    return out


OVERRIDES = "joint_overrides"
#: longest joint_overrides entry (characters)
MAX_OVERRIDE = 100_000


def _override_value(v: Any) -> bool:
    """A number, a bool, or a flat list of numbers: what a parameter of one joint may be."""
    def scalar(x):
        return isinstance(x, (bool, int, float))
    return scalar(v) or (isinstance(v, list) and all(scalar(x) and not isinstance(x, bool)
                                                       for x in v))


def overrides_by_joint(texts: Sequence[Any], count: int) -> dict[str, list[Any]]:
    """{'section.name': [the value of each joint]} of ``joint_overrides`` entries
    ``'section.name=[v_1, ..., v_J]'`` (JSON values: a number, or a list for an array
    parameter); ConfigError naming the entry when one is malformed, names no observer
    parameter, or does not give one value per joint."""
    import json

    from ..observers import REGISTRY
    out: dict[str, list[Any]] = {}
    if not isinstance(texts, (list, tuple)):
        raise ConfigError(OVERRIDES, f"expected a list of 'section.name=[...]' texts, got "
                          f"{short(texts)}")
    for i, text in enumerate(texts):
        where = f"{OVERRIDES}[{i}]"
        if not isinstance(text, str) or len(text) > MAX_OVERRIDE:
            raise ConfigError(where, f"expected a text 'section.name=[v_1, ..., v_J]' of at most "
                              f"{MAX_OVERRIDE} characters, got {short(text)}")
        name, sep, value = text.partition("=")
        name = name.strip()
        section, dot, short_name = name.partition(".")
        cls = REGISTRY.get(section)
        if not sep or not dot or cls is None or \
                short_name not in {p.name for p in cls.PARAMS}:
            raise ConfigError(where, f"{short(name)} is not an observer parameter ('section.name="
                              "[value per joint]', e.g. 'joint_kalman.bandwidth=[20, 30]')")
        try:
            values = json.loads(value)
        except ValueError:
            values = None
        if not isinstance(values, list) or len(values) != count or \
                not all(_override_value(v) for v in values):
            raise ConfigError(where, f"{name}: expected a list of {count} values (one per joint, "
                              f"in the order of 'joints'; a value a number or a list of "
                              f"numbers), got {short(value.strip())}")
        if name in out:
            raise ConfigError(where, f"{name} is overridden twice")
        kind = next(p.kind for p in cls.PARAMS if p.name == short_name)
        if kind.endswith("_array"):             # one number stands for a one-element array
            values = [v if isinstance(v, list) else [v] for v in values]
        out[name] = values
    return out


@dataclass(frozen=True)
class Roles:
    """Which state is a joint's position and velocity (index or -1), and where its effort
    comes from: ('state', index), ('unknown_input', 0) or ('none', -1)."""
    position: int
    velocity: int
    effort: tuple[str, int]


def roles(settings: Mapping[str, Any], plant, state_names: Sequence[str],
          has_unknown_input: bool) -> Roles:
    """The published roles of the states (see the module doc); ConfigError naming the
    setting when a name is not a state or the plant does not say."""
    names = list(state_names)

    def index(key: str, name: str) -> int:
        if name not in names:
            raise ConfigError(key, f"{short(name)} is not a state (states: {', '.join(names)})")
        return names.index(name)

    pos_name = settings["joint_roles.position_state"]
    if pos_name:
        pos = index("joint_roles.position_state", pos_name)
    else:
        pos = -1
        if plant is not None and len(plant.h) >= 1 and plant.h[0] in plant.x:
            pos = plant.x.index(plant.h[0])
        if pos < 0:
            raise ConfigError("joint_roles.position_state", "the plant's first output is not a state: "
                              "name the state published as the joint's position")
    vel_name = settings["joint_roles.velocity_state"]
    if vel_name:
        vel = index("joint_roles.velocity_state", vel_name)
    else:
        vel = -1
        if plant is not None:
            deriv = sympy.sympify(plant.f[pos])
            if deriv in plant.x:
                vel = plant.x.index(deriv)
    effort = settings["joint_roles.effort"]
    if effort == "" or effort == "unknown_input":
        if has_unknown_input:
            eff = ("unknown_input", 0)
        elif effort == "unknown_input":
            raise ConfigError("joint_roles.effort", "this observer does not estimate an unknown input")
        else:
            eff = ("none", -1)
    elif effort == "none":
        eff = ("none", -1)
    else:
        eff = ("state", index("joint_roles.effort", effort))
    return Roles(pos, vel, eff)
