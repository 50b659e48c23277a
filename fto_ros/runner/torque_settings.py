"""The external-torque node's parameters (schema) and what they build: the arm's model, the
windowed momentum estimator, the optional momentum observer and the collision detector.

The schema is the runner's (``observers.base.Param``): the node declares each with a
descriptor, the refusals are one ``ConfigError`` line naming the parameter, and the same
flat dictionary builds the same objects offline (tests, benchmarks).  ROS-free.

URDF source: ``plant.urdf`` (a file) or ``robot_description`` (the string
robot_state_publisher publishes), exactly one non-empty.  The commanded torque is the
effort field of the same JointState as the positions (what a drive reports and what
``fto-simulate --urdf`` records: the torque commanded at the sample, held until the next).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..core.errors import ConfigError, short
from ..core.params import Param
from ..arm import RigidBodyModel, load_model
from ..arm.collision import CollisionDetector
from ..arm.external_torque import MomentumObserver, WindowEstimator

TORQUE_SETTINGS: tuple[Param, ...] = (
    Param("plant.urdf", "string", "", "the arm's URDF file (or robot_description; exactly one)"),
    Param("robot_description", "string", "", "the arm's URDF as a string, as robot_state_publisher "
          "takes it (or plant.urdf; exactly one)"),
    Param("plant.joints", "string_array", [], "the joints the estimator uses, by name, in the "
          "order of every output (empty: every movable joint of the URDF, in its tree order)"),
    Param("plant.locked_joints", "string_array", [], "the URDF's other movable joints, locked at "
          "plant.locked_positions"),
    Param("plant.locked_positions", "double_array", [], "one position per plant.locked_joints entry"),
    Param("plant.viscous_friction", "double_array", [], "b per joint (Nm s/rad; one value: every "
          "joint; empty: the URDF's <dynamics damping>)", min=0.0),
    Param("plant.coulomb_friction", "double_array", [], "f_c per joint (Nm; one value: every "
          "joint; empty: the URDF's <dynamics friction>)", min=0.0),
    Param("plant.friction_width", "double", 0.02, "w of the Coulomb friction's tanh(v / w), rad/s",
          gt=0.0),
    Param("plant.armature", "double_array", [], "rotor inertia through the gear per joint, added "
          "to M's diagonal (empty: the URDF's <dynamics armature>, else 0)", min=0.0),
    Param("topics.joint_states", "string", "joint_states", "JointState input: position = the "
          "encoders, effort = the commanded torque (held until the next sample); header stamp"),
    Param("topics.external_torque", "string", "external_torque", "JointState output: effort = "
          "tau_ext (Nm) by joint name, stamped with the measurement's stamp"),
    Param("sample_period", "double", 1e-3, "the stream's nominal period (s); a step that is not "
          "it within 0.1 % restarts the estimator (a gap or a lost message)", gt=0.0, max=0.1),
    Param("external_torque.window", "double", 0.06, "T (s): the kernel's length; the estimate is "
          "exact T after any change of tau_ext (a whole number of sample periods, >= 8)", gt=0.0),
    Param("external_torque.velocity_L", "double", 300.0, "the velocity differentiator's bound on "
          "the third derivative of the positions", gt=0.0),
    Param("external_torque.momentum_gain", "double", 0.0, "K_O (1/s) of the generalized-momentum "
          "observer published on ~/external_torque_momentum as a baseline (0: not run)", min=0.0),
    Param("wrench.link", "string", "", "a link (or frame) of the URDF: publish ~/wrench, the "
          "wrench (f; m) at its origin, world axes, whose joint torques J^T (f; m) best match "
          "tau_ext (least squares; empty: not published)"),
    Param("wrench.force_only", "bool", False, "~/wrench: a pure force at the link (m = 0)"),
    Param("collision.false_alarms_per_hour", "double", 1e-2, "the false-alarm bound that sets "
          "the per-joint threshold", gt=0.0),
    Param("collision.sigma", "double_array", [], "the residual's noise level in radians of encoder "
          "noise (one value: every joint; empty: measured over collision.calibration at start)",
          gt=0.0),
    Param("collision.calibration", "double", 2.0, "the calibration window (s) after the first "
          "estimate, without contact", gt=0.0),
    Param("collision.release", "double", 0.5, "a joint in contact is re-armed once its residual "
          "stayed below this fraction of its threshold for collision.hold", gt=0.0, max=0.999),
    Param("collision.hold", "double", 0.05, "see collision.release (s)", min=0.0),
    Param("collision.contact_size", "double", 10.0, "the external-torque step (Nm) for which "
          "/diagnostics states the guaranteed detection time per joint", gt=0.0),
    Param("collision.miss", "double", 1e-3, "the miss probability of that guaranteed time",
          gt=0.0, max=0.5),
    Param("diagnostics.period", "double", 1.0, "seconds between /diagnostics messages", gt=0.0),
)

#: parameters ROS itself declares on every node
ROS_OWN = ("use_sim_time", "start_type_description_service", "autostart")


@dataclass
class TorqueSetup:
    model: RigidBodyModel
    estimator: WindowEstimator
    momentum: MomentumObserver | None
    detector: CollisionDetector
    flat: dict[str, Any]


def settings_values(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Every setting's typed value (defaults filled in); ConfigError for a value the schema
    refuses or a name it does not have."""
    specs = {p.name: p for p in TORQUE_SETTINGS}
    unknown = sorted(k for k in flat if k not in specs and k not in ROS_OWN
                     and not k.startswith("qos_overrides."))
    if unknown:
        raise ConfigError(unknown[0], "unknown parameter of the external-torque node (its "
                          "parameters: docs/ros_interface.md)")
    return {name: (p.default if flat.get(name) is None else p.coerce(flat[name], name))
            for name, p in specs.items()}


def build(flat: Mapping[str, Any]) -> TorqueSetup:
    """The model, estimators and detector of the settings ``flat`` (module doc)."""
    s = settings_values(flat)
    urdf, text = s["plant.urdf"], s["robot_description"]
    if bool(urdf) == bool(text):
        raise ConfigError("plant.urdf", "give the URDF file (plant.urdf) or the robot_description "
                          "string, exactly one of them")
    locked, positions = s["plant.locked_joints"], s["plant.locked_positions"]
    if len(locked) != len(positions):
        raise ConfigError("plant.locked_positions", f"one position per locked joint "
                          f"({len(locked)}), got {len(positions)}")
    model = load_model(list(s["plant.joints"]) or None, urdf=urdf or None,
                       robot_description=text or None,
                       locked_joints=dict(zip(locked, positions)),
                       viscous_friction=s["plant.viscous_friction"] or None,
                       coulomb_friction=s["plant.coulomb_friction"] or None,
                       friction_width=s["plant.friction_width"],
                       armature=s["plant.armature"] or None)
    h = s["sample_period"]
    try:
        estimator = WindowEstimator(model, sample_period=h, window=s["external_torque.window"],
                                    velocity_L=s["external_torque.velocity_L"])
    except ValueError as err:
        raise ConfigError("external_torque.window", f"{short(str(err))} (sample_period {h} s)") \
            from None
    gain = s["external_torque.momentum_gain"]
    momentum = MomentumObserver(model, sample_period=h, gain=gain) if gain > 0 else None
    sigma = s["collision.sigma"]
    if sigma and len(sigma) not in (1, model.n):
        raise ConfigError("collision.sigma", f"one value or one per joint ({model.n}), got "
                          f"{len(sigma)}")
    try:
        detector = CollisionDetector(model.n, rate=1.0 / h,
                                     false_alarms_per_hour=s["collision.false_alarms_per_hour"],
                                     sigma=sigma or None, calibration=s["collision.calibration"],
                                     release=s["collision.release"], hold=s["collision.hold"])
    except ValueError as err:
        raise ConfigError("collision.false_alarms_per_hour", short(str(err))) from None
    link = s["wrench.link"]
    if link:
        try:
            model.jacobian(link, np.zeros(model.n))
        except ConfigError as err:
            raise ConfigError("wrench.link", err.problem) from None
    return TorqueSetup(model, estimator, momentum, detector, s)
