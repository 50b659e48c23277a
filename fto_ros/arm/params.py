"""The arm's plant and conventions as parameters, declared once (``core.params.Param``, full
ROS names) for every family that estimates an arm's external torques (external_torque,
momentum_observer), and what they build: the model of the arm (fto_ros/arm), the effort's
meaning, the payload, the collision levels. ROS-free.

The names are fixed (docs/external_torque.md, "Parameters"), so that ``fto-identify``
writes what the node and the replay read. Every refusal is one ``ConfigError`` line naming
the parameter. fto-identify (arm/identify_params.py) reads the same declarations.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from .identify import EFFORT_MEANINGS as MEANINGS
from .model import RigidBodyModel, load_model
from ..core.errors import ConfigError, short
from ..core.params import Param, resolve

#: effort meaning -> its code in the kernels' constants
MEANING_CODE = {m: i for i, m in enumerate(MEANINGS)}
COMMANDED, NO_GRAVITY, MEASURED, CURRENT = range(4)

PLANT: tuple[Param, ...] = (
    Param("plant.urdf", "string", "", "the arm's URDF file (or robot_description; exactly one)"),
    Param("robot_description", "string", "", "the arm's URDF as text, as robot_state_publisher "
          "takes it (or plant.urdf). The node also takes it from the transient-local "
          "robot_description topic (std_msgs/String) when neither is given"),
    Param("plant.locked_joints", "string_array", [], "passive joints' names with a start "
          "position (a passive joint is any movable joint of the URDF not in 'joints' and no "
          "<mimic>; the message's value is used when it carries one)"),
    Param("plant.locked_positions", "double_array", [], "one position per plant.locked_joints"),
    Param("plant.viscous_friction", "double_array", [], "b per joint (Nm s/rad; one value: every "
          "joint; empty: the URDF's <dynamics damping>)", min=0.0),
    Param("plant.coulomb_friction", "double_array", [], "f_c per joint (Nm; one value: every "
          "joint; empty: the URDF's <dynamics friction>)", min=0.0),
    Param("plant.friction_width", "double", 0.02, "w of the Coulomb friction's tanh(v / w), "
          "rad/s", gt=0.0),
    Param("plant.armature", "double_array", [], "rotor inertia through the gear per joint, added "
          "to M's diagonal (one value: every joint; empty: the URDF's <dynamics armature>, "
          "else 0)", min=0.0),
    Param("plant.inertia_scale.links", "string_array", [], "links whose mass, first moment and "
          "inertia are scaled (what fto-identify fits) ..."),
    Param("plant.inertia_scale.factors", "double_array", [], "... by these factors, one per "
          "link", gt=0.0),
    Param("plant.inertia_delta.links", "string_array", [], "links whose inertia parameters get "
          "a correction added (what fto-identify fits in base-parameter form) ..."),
    Param("plant.inertia_delta.values", "double_array", [], "... 10 values per link: m, m c "
          "(3), the inertia about the link's origin xx yy zz yz xz xy, link axes"),
    Param("payload.frame", "string", "", "the link (or frame) a payload is attached to ('' none)",
          read_only=False),
    Param("payload.mass", "double", 0.0, "the payload's mass (kg; run-time changeable: a "
          "grasped object is not read as a contact)", min=0.0, read_only=False),
    Param("payload.com", "double_array", [0.0, 0.0, 0.0], "its centre of mass in payload.frame "
          "(m, 3 values)", read_only=False),
    Param("payload.inertia", "double_array", [0.0] * 6, "its inertia about the centre of mass "
          "in the frame's axes: ixx ixy ixz iyy iyz izz (kg m^2; zeros: a point mass)",
          read_only=False),
    Param("effort.meaning", "string", "commanded", "what JointState.effort is: the commanded "
          "torque (gravity included), commanded_no_gravity (the drive adds g(q): franka_ros2), "
          "measured (a link-side joint torque tau_J: friction drops out), current (motor "
          "current: torque = current * effort.torque_constant * effort.gear_ratio)",
          choices=MEANINGS),
    Param("effort.torque_constant", "double_array", [], "Nm/A per joint (effort.meaning: "
          "current; one value: every joint)", gt=0.0),
    Param("effort.gear_ratio", "double_array", [], "gear ratio per joint (effort.meaning: "
          "current; one value: every joint)", gt=0.0),
)

COLLISION: tuple[Param, ...] = (
    Param("collision.false_alarms_per_hour", "double", 1e-2, "the false-alarm bound that sets "
          "each joint's lower (contact) level: z sigma_i, z from the union bound", gt=0.0),
    Param("collision.sigma", "double_array", [], "the residual's level in radians of encoder "
          "noise (one value: every joint; empty: measured over collision.calibration)", gt=0.0),
    Param("collision.calibration", "double", 2.0, "the calibration (s of estimates from the "
          "first one, contact-free): the residual's level and its comparison with the "
          "encoder's noise (the model-mismatch check)", gt=0.0, max=3600.0),
    Param("collision.upper_threshold", "double_array", [], "the upper (collision) level in Nm "
          "per joint (one value: every joint; empty: collision.upper_factor times the lower)",
          gt=0.0),
    Param("collision.upper_factor", "double", 3.0, "the upper level as a multiple of the lower "
          "(when collision.upper_threshold is empty)", min=1.0),
    Param("collision.release", "double", 0.5, "a joint in contact is re-armed once its residual "
          "stayed below this fraction of its lower level for collision.hold", gt=0.0,
          max=0.999),
    Param("collision.hold", "double", 0.05, "see collision.release (s)", min=0.0),
    Param("collision.mismatch_factor", "double", 3.0, "the calibrated residual above this many "
          "times the encoder's noise (through the estimator) is a model mismatch: WARN in "
          "/diagnostics naming the joints (fto-identify fits the model)", gt=1.0),
    Param("collision.contact_size", "double", 10.0, "the external-torque step (Nm) for which "
          "/diagnostics states the guaranteed detection time per joint", gt=0.0),
    Param("collision.miss", "double", 1e-3, "the miss probability of that guaranteed time",
          gt=0.0, max=0.5),
    Param("wrench.frame", "string", "", "a link or frame of the URDF: the node publishes the "
          "external wrench there (~/wrench in base axes, ~/wrench_frame in the frame's axes; "
          "empty: not published)"),
    Param("wrench.damping", "double", 0.01, "the damping of the wrench's least squares "
          "(J J^T + damping^2 I)^-1 J tau_ext", min=0.0),
)

#: every arm parameter (full names), as the runner and the node take them
ARM_PARAMS: tuple[Param, ...] = PLANT + COLLISION
ARM_NAMES = frozenset(p.name for p in ARM_PARAMS)
#: the arm parameters the node changes at run time without rebuilding (the payload's)
PAYLOAD_NAMES = ("payload.frame", "payload.mass", "payload.com", "payload.inertia")


def resolve_arm(flat: Mapping[str, Any]) -> dict[str, Any]:
    """The typed arm parameters of ``flat`` (full names), defaults filled in."""
    return resolve(ARM_PARAMS, {k: v for k, v in flat.items() if k in ARM_NAMES})


def per_joint(values, n: int, name: str, default: float | None = None) -> np.ndarray:
    """One value per joint from a parameter's list (one value: every joint)."""
    v = list(values or [])
    if not v:
        if default is None:
            raise ConfigError(name, f"needs one value per joint ({n}) or one for all")
        return np.full(n, float(default))
    if len(v) == 1:
        return np.full(n, float(v[0]))
    if len(v) != n:
        raise ConfigError(name, f"needs one value per joint ({n}) or one for all, got {len(v)}")
    return np.asarray(v, dtype=float)


def _pairs(a: Mapping[str, Any], links_name: str, values_name: str, per: int) -> dict:
    """{link: its value (per 1) or its ``per`` values} from two parallel list parameters."""
    links, values = a[links_name], a[values_name]
    if len(values) != per * len(links):
        raise ConfigError(values_name, f"{per} value(s) per entry of {links_name} "
                                       f"({len(links)}), got {len(values)}")
    return {name: (values[i] if per == 1 else values[per * i:per * i + per])
            for i, name in enumerate(links)}


def build_model(a: Mapping[str, Any], joints) -> RigidBodyModel:
    """The arm's model from the typed arm parameters ``a`` and the joint list (empty: the
    trunk), its inertial corrections and payload applied."""
    urdf, text = a["plant.urdf"], a["robot_description"]
    if bool(urdf) == bool(text):
        raise ConfigError("plant.urdf", "give the URDF file (plant.urdf) or its text "
                          "(robot_description), exactly one of them")
    model = load_model(list(joints) or None, urdf=urdf or None, robot_description=text or None,
                       locked_joints=_pairs(a, "plant.locked_joints", "plant.locked_positions", 1),
                       viscous_friction=a["plant.viscous_friction"] or None,
                       coulomb_friction=a["plant.coulomb_friction"] or None,
                       friction_width=a["plant.friction_width"],
                       armature=a["plant.armature"] or None,
                       inertia_scale=_pairs(a, "plant.inertia_scale.links",
                                            "plant.inertia_scale.factors", 1),
                       inertia_delta=_pairs(a, "plant.inertia_delta.links",
                                            "plant.inertia_delta.values", 10))
    set_payload(model, a)
    return model


def payload_inertia(six) -> np.ndarray:
    """ixx ixy ixz iyy iyz izz -> the 3 x 3 tensor."""
    xx, xy, xz, yy, yz, zz = (float(v) for v in six)
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def set_payload(model: RigidBodyModel, a: Mapping[str, Any]) -> None:
    """The payload.* values into the model (the frame '' or mass 0: none)."""
    frame, mass = a["payload.frame"], a["payload.mass"]
    com, inertia = a["payload.com"], a["payload.inertia"]
    if len(com) != 3:
        raise ConfigError("payload.com", f"needs 3 values (x, y, z), got {len(com)}")
    if len(inertia) != 6:
        raise ConfigError("payload.inertia", f"needs 6 values (ixx ixy ixz iyy iyz izz), got "
                          f"{len(inertia)}")
    for old in list(model.tree.payloads):
        model.tree.set_payload(old, 0.0)
    if not frame:
        if mass > 0:
            raise ConfigError("payload.frame", "a payload mass needs the frame it is attached to")
        return
    try:
        model.tree.set_payload(frame, mass, com, payload_inertia(inertia), param="payload.frame")
    except ConfigError as err:
        name = "payload.frame" if "no link or frame" in err.problem else "payload.inertia"
        raise ConfigError(name, err.problem) from None


def torque_factors(a: Mapping[str, Any], n: int) -> np.ndarray:
    """Per joint, the factor from the effort to the torque (1, or kt * gear for current)."""
    if a["effort.meaning"] != "current":
        return np.ones(n)
    kt = per_joint(a["effort.torque_constant"], n, "effort.torque_constant")
    gear = per_joint(a["effort.gear_ratio"], n, "effort.gear_ratio")
    return kt * gear


def upper_levels(a: Mapping[str, Any], n: int) -> np.ndarray:
    """The given upper levels (Nm) per joint, or zeros (the factor applies)."""
    return per_joint(a["collision.upper_threshold"], n, "collision.upper_threshold", 0.0)


def sigmas(a: Mapping[str, Any], n: int) -> np.ndarray:
    """The given residual levels (rad) per joint, or zeros (calibrated)."""
    return per_joint(a["collision.sigma"], n, "collision.sigma", 0.0)


def row_norm_bound(model: RigidBodyModel, samples: int = 256, seed: int = 0) -> np.ndarray:
    """Per joint, the largest ||M_i,:||_1 over ``samples`` configurations (revolute joints
    over a full turn, prismatic ones over +-0.5 m; the passive joints at their defaults),
    times 1.1: the mass matrix's bound that the gap rule uses (docs/external_torque.md)."""
    rng = np.random.default_rng(seed)
    prismatic = np.array([model.robot.joint(j).kind == "prismatic" for j in model.joints])
    out = np.zeros(model.n)
    for _ in range(samples):
        q = np.where(prismatic, rng.uniform(-0.5, 0.5, model.n),
                     rng.uniform(-math.pi, math.pi, model.n))
        out = np.maximum(out, np.abs(model.mass_matrix(q)).sum(axis=1))
    return 1.1 * out


def gap_step(tolerance: float, kernel_peak: float, row_bound: np.ndarray, L: float,
             period: float) -> float:
    """The longest step whose bridging adds at most ``tolerance`` (Nm) on every joint:
    e_i(G) = 1/2 peak ||M_i,:||_1 L (G - period)^2 (docs/external_torque.md), so
    G = period + sqrt(2 tolerance / (peak max_i ||M_i,:||_1 L))."""
    worst = float(np.max(row_bound)) * kernel_peak * L
    return period + math.sqrt(2.0 * tolerance / worst) if worst > 0 else math.inf


def gap_bound(step: float, kernel_peak: float, row_norm: np.ndarray, L: float,
              period: float) -> np.ndarray:
    """Per joint, the bound on what bridging a step of ``step`` s adds (Nm)."""
    extra = max(step - period, 0.0)
    return 0.5 * kernel_peak * np.asarray(row_norm) * L * extra * extra
