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
from .model import RigidBodyModel
from .params import PLANT, build_model

#: the arm's plant and effort parameters as the estimators declare them (arm/params.py),
#: the joint list and the stream's topic
READS: tuple[Param, ...] = PLANT + (
    Param("joints", "string_array", [], "the estimator's joints (empty: the arm's chain)"),
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


def prior_model(s: Mapping[str, Any]) -> RigidBodyModel:
    """The model the params ``s`` (:func:`read`) describe: the prior of an identification."""
    return build_model(s, s["joints"])


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
