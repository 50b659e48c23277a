"""The parameters fto-identify reads from the params files and writes back (ROS-free): the
arm room's names (docs/identify.md), the prior model they build, and the params file's text.

Read: the URDF (``plant.urdf`` or ``robot_description``, exactly one), ``joints``, the
passive joints' start positions, friction, armature, earlier corrections
(``plant.inertia_scale.*``, ``plant.inertia_delta.*``), the payload (``payload.*``), the
effort's meaning (``effort.*``) and the stream's topic; every other parameter of the files
(an estimator's tuning) is not fto-identify's and is left alone. Written: the friction, the
inertial corrections and the payload fitted, under ``/**: ros__parameters:``, with the fit's
figures as comments, so that the node and the replay merge the file after the plant file.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import yaml

from ..core.errors import ConfigError
from ..core.params import Param
from .identify import EFFORT_MEANINGS
from .model import RigidBodyModel, load_model

READS: tuple[Param, ...] = (
    Param("plant.urdf", "string", "", "the arm's URDF file (or robot_description)"),
    Param("robot_description", "string", "", "the arm's URDF text (or plant.urdf)"),
    Param("joints", "string_array", [], "the estimator's joints (empty: the arm's chain)"),
    Param("plant.locked_joints", "string_array", [], "passive joints with a start position"),
    Param("plant.locked_positions", "double_array", [], "their positions"),
    Param("plant.viscous_friction", "double_array", [], "b per joint", min=0.0),
    Param("plant.coulomb_friction", "double_array", [], "f_c per joint", min=0.0),
    Param("plant.friction_width", "double", 0.02, "w of tanh(v / w), rad/s", gt=0.0),
    Param("plant.armature", "double_array", [], "rotor inertia per joint", min=0.0),
    Param("plant.inertia_scale.links", "string_array", [], "links scaled"),
    Param("plant.inertia_scale.factors", "double_array", [], "their factors", gt=0.0),
    Param("plant.inertia_delta.links", "string_array", [], "links corrected"),
    Param("plant.inertia_delta.values", "double_array", [], "10 per link"),
    Param("payload.frame", "string", "", "the payload's frame ('' none)"),
    Param("payload.mass", "double", 0.0, "kg", min=0.0),
    Param("payload.com", "double_array", [0.0, 0.0, 0.0], "m, frame axes"),
    Param("payload.inertia", "double_array", [0.0] * 6, "ixx ixy ixz iyy iyz izz about the com"),
    Param("effort.meaning", "string", "commanded", "what JointState.effort carries",
          choices=EFFORT_MEANINGS),
    Param("effort.torque_constant", "double_array", [], "Nm/A per joint (current)", gt=0.0),
    Param("effort.gear_ratio", "double_array", [], "per joint (current)", gt=0.0),
    Param("topics.joint_states", "string", "joint_states", "the JointState stream"),
)

#: the first line of every params file fto-identify writes (what --overwrite may replace)
MARKER = "# written by fto-identify (fto_ros); --overwrite may replace this file"


def read(flat: Mapping[str, Any]) -> dict[str, Any]:
    """The typed values of :data:`READS` in the merged params ``flat`` (defaults filled)."""
    if "plant.joints" in flat and "joints" not in flat:
        raise ConfigError("plant.joints", "the arm's joint list is the parameter 'joints'")
    return {p.name: (p.default if flat.get(p.name) is None else p.coerce(flat[p.name], p.name))
            for p in READS}


def _pairs(links, values, per: int, links_name: str, values_name: str) -> dict:
    if len(values) != per * len(links):
        raise ConfigError(values_name, f"{per} value(s) per entry of {links_name} "
                                       f"({len(links)}), got {len(values)}")
    return {name: (values[i] if per == 1 else values[per * i:per * i + per])
            for i, name in enumerate(links)}


def prior_model(s: Mapping[str, Any]) -> RigidBodyModel:
    """The model the params ``s`` (:func:`read`) describe: the prior of an identification."""
    urdf, text = s["plant.urdf"], s["robot_description"]
    if bool(urdf) == bool(text):
        raise ConfigError("plant.urdf", "give the URDF file (plant.urdf) or the "
                                        "robot_description string, exactly one of them")
    locked = _pairs(s["plant.locked_joints"], s["plant.locked_positions"], 1,
                    "plant.locked_joints", "plant.locked_positions")
    model = load_model(list(s["joints"]) or None, urdf=urdf or None,
                       robot_description=text or None, locked_joints=locked,
                       viscous_friction=s["plant.viscous_friction"] or None,
                       coulomb_friction=s["plant.coulomb_friction"] or None,
                       friction_width=s["plant.friction_width"],
                       armature=s["plant.armature"] or None,
                       inertia_scale=_pairs(s["plant.inertia_scale.links"],
                                            s["plant.inertia_scale.factors"], 1,
                                            "plant.inertia_scale.links",
                                            "plant.inertia_scale.factors"),
                       inertia_delta=_pairs(s["plant.inertia_delta.links"],
                                            s["plant.inertia_delta.values"], 10,
                                            "plant.inertia_delta.links",
                                            "plant.inertia_delta.values"))
    frame = s["payload.frame"]
    if frame and s["payload.mass"] > 0:
        com, inertia = s["payload.com"], s["payload.inertia"]
        if len(com) != 3 or len(inertia) != 6:
            raise ConfigError("payload.com", f"payload.com needs 3 values and payload.inertia 6 "
                                             f"(ixx ixy ixz iyy iyz izz), got {len(com)}, "
                                             f"{len(inertia)}")
        xx, xy, xz, yy, yz, zz = inertia
        model.set_payload(frame, s["payload.mass"], com,
                          [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return model


def _plain(value):
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(x) for x in value]
    if isinstance(value, (float, np.floating)):
        return float(value)
    return value


def _nested(flat: Mapping[str, Any]) -> dict:
    out: dict = {}
    for key, value in flat.items():
        node = out
        *parents, leaf = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = _plain(value)
    return out


def params_text(values: Mapping[str, Any], comments: list[str]) -> str:
    """The params file: :data:`MARKER`, ``comments`` (one line each), the values under
    ``/**: ros__parameters:`` (an empty list is left out: in a params file it is a parameter
    not set)."""
    values = {k: v for k, v in values.items() if not (isinstance(v, (list, tuple)) and not v)}
    body = yaml.safe_dump({"/**": {"ros__parameters": _nested(values)}}, sort_keys=False,
                          default_flow_style=None, width=100)
    lines = [MARKER] + ["# " + " ".join(str(c).split()) for c in comments]
    return "\n".join(lines) + "\n" + body
