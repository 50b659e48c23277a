"""Every parameter that is not an observer's own, and reading a ROS 2 params file.

Shared by the live node (which declares these as ROS parameters) and the
replay harness (which reads the same YAML file), so one params file drives
both and a typo is refused the same way by both.  ROS-free.
"""
from __future__ import annotations

from typing import Any, Mapping

from ..core.errors import ConfigError
from ..observers import REGISTRY, observer_class
from ..core.params import Param, check_size, resolve
from ..plant import expand as expand_plant
from .params_file import flatten, load_params_file, load_params_files  # noqa: F401  (re-exported)

FIELDS = ("position", "velocity", "effort")

#: runner and I/O parameters (full ROS names); node-only ones say so
SETTINGS: tuple[Param, ...] = (
    Param("observer.type", "string", None, "observer family: " + ", ".join(sorted(REGISTRY)),
          choices=tuple(sorted(REGISTRY))),
    Param("observer.initial_estimate", "double_array", [],
          "x_hat at start-up and after every reset, plant coordinates (empty: the observer's default)"),
    Param("source", "string", "topics", "where y and u come from: 'topics' (measured_output + input "
          "Float64MultiArray) or 'joint_states' (sensor_msgs/JointState)", choices=("topics", "joint_states")),
    Param("topics.measured_output", "string", "measured_output", "Float64MultiArray y topic"),
    Param("topics.input", "string", "input", "Float64MultiArray u topic (unused when the observer has no input)"),
    Param("topics.joint_states", "string", "joint_states", "JointState source topic (source: joint_states)"),
    Param("topics.true_state", "string", "true_state", "ground-truth Float64MultiArray topic "
          "(replay only: compared with the estimate)"),
    Param("topics.true_unknown_input", "string", "true_unknown_input", "ground-truth unknown-input "
          "Float64MultiArray topic (replay only: compared with unknown_input_estimate when the bag "
          "has it)"),
    Param("joints", "string_array", [], "the joints of an arm, by name: one observer of the "
          "plant (the model of ONE joint) per joint, all run in one call per message; y and u "
          "of each come from its entry in the JointState (joint_states.output_fields, "
          "input_fields), a constant may differ per joint ('name=[v1, ..., vJ]' in "
          "plant.constants). Empty: one observer over the plant (y and u as the other "
          "joint_states.* settings say). For the arm's external-torque families "
          "(external_torque, momentum_observer): the joints ONE observer estimates, in the "
          "order of every output (empty: the arm's chain from its URDF)"),
    Param("joint_overrides", "string_array", [], "per-joint mode (joints): observer parameters "
          "that differ per joint, each 'section.name=[v_1, ..., v_J]' (one value per joint, "
          "in the order of joints; a value is a number, or a list for an array parameter: "
          "'joint_kalman.bandwidth=[30, 40, ...]', 'hosm.poles=[[-60, -70], ...]'); "
          "fto-tune writes them", read_only=False),
    Param("joint_states.output_fields", "string_array", ["position"], "per-joint mode "
          "(joints): the JointState fields that give each joint's y, in the plant's output "
          "order", choices=FIELDS),
    Param("joint_states.input_fields", "string_array", ["effort"], "per-joint mode (joints): "
          "the JointState fields that give each joint's u, in the plant's input order (only "
          "the first m are used)", choices=FIELDS),
    Param("joint_roles.position_state", "string", "", "per-joint mode: the state published as each "
          "joint's position (empty: the state the plant's h measures)"),
    Param("joint_roles.velocity_state", "string", "", "per-joint mode: the state published as each "
          "joint's velocity (empty: the state the position's derivative f equals; none if no "
          "state does)"),
    Param("joint_roles.effort", "string", "", "per-joint mode: what each joint's effort is: "
          "'unknown_input' (the observer's unknown-input estimate), a state name, 'none', or "
          "empty (the unknown input when the observer identifies one, else none)"),
    Param("joint_states.output_joints", "string_array", [], "joints whose field gives y, in order"),
    Param("joint_states.output_field", "string", "position", "JointState field giving y", choices=FIELDS),
    Param("joint_states.input_joints", "string_array", [], "joints whose field gives u, in order"),
    Param("joint_states.input_field", "string", "effort", "JointState field giving u", choices=FIELDS),
    Param("estimated_joint_states.joint_names", "string_array", [],
          "joints of the published estimated_joint_states (empty: not published)"),
    Param("estimated_joint_states.position_states", "int_array", [],
          "per joint, the state index giving its position (-1: none)", min=-1),
    Param("estimated_joint_states.velocity_states", "int_array", [],
          "per joint, the state index giving its velocity (-1: none)", min=-1),
    Param("estimated_joint_states.effort_states", "int_array", [],
          "per joint, the state index giving its effort (-1: none)", min=-1),
    Param("input.timeout", "double", 0.5, "a sample whose latest input is older than this (s) is "
          "rejected as 'stale_input'", gt=0.0, read_only=False),
    Param("time.max_gap", "double", 0.5, "a gap between samples longer than this (s), or longer "
          "than the observer bridges, restarts the observer at the new sample (once the next "
          "sample confirms it)", gt=0.0, max=1e6, read_only=False),
    Param("time.reset_on_jump", "bool", True, "restart the observer when time jumps backwards by more "
          "than time.jump_threshold (bag looping, sim time reset; confirmed by the next sample); "
          "else such samples are rejected", read_only=False),
    Param("time.jump_threshold", "double", 0.5, "backward jump (s) treated as a time reset",
          min=0.0, max=1e6, read_only=False),
    Param("time.future_tolerance", "double", 0.5, "JointState stamps further than this (s) ahead "
          "of the wall clock (node without sim time) or the log time (replay) are rejected as "
          "'future_stamp'", min=0.0, read_only=False),
    Param("limits.measurement", "double_array", [1e12], "plausibility: a measurement with |y_i| "
          "above this is rejected as 'measurement_implausible' (one value for every output, or "
          "one per output)", gt=0.0, read_only=False),
    Param("limits.input", "double_array", [1e12], "plausibility: an input with |u_i| above this is "
          "rejected as 'input_implausible' (one value, or one per input)", gt=0.0, read_only=False),
    Param("limits.estimate", "double", 1e15, "an estimate with an element beyond +-this restarts the "
          "observer ('estimate_implausible') and is not published", gt=0.0, read_only=False),
    Param("outlier.threshold", "double", 20.0, "outlier gate: once converged, reject a measurement "
          "whose innovation (against the extrapolation of the last two accepted ones) exceeds this "
          "many times its recent RMS, as 'outlier' (0: gate off)", min=0.0, read_only=False),
    Param("outlier.window", "int", 200, "outlier gate: samples over which the innovation RMS is "
          "averaged (exponentially); the gate acts after a quarter of it", min=4, max=1000000,
          read_only=False),
    Param("outlier.confirm", "int", 3, "outlier gate: this many consecutive rejected samples that "
          "continue each other are a real change of the signal: accepted, the gate re-bases",
          min=3, max=1000, read_only=False),
    Param("outlier.max_consecutive", "int", 100, "outlier gate: after this many rejections in a row "
          "the gate re-bases anyway (never locks the observer out)", min=3, max=1000000,
          read_only=False),
    Param("outlier.min_scale", "double_array", [0.0], "outlier gate: floor of the innovation RMS "
          "(units of y; one value, or one per output), e.g. the sensor resolution", min=0.0,
          read_only=False),
    Param("convergence.residual_threshold", "double", 0.1, "after the guaranteed time, an output "
          "residual above this (units of y) reports 'diverging'", min=0.0, read_only=False),
    Param("diagnostics.period", "double", 1.0, "node only: /diagnostics period (s)", min=0.01,
          max=3600.0),
    Param("diagnostics.window", "double", 10.0, "the /diagnostics level describes the last this "
          "many seconds: an ERROR (observer failure) or WARN (rejections) clears once that long "
          "has passed cleanly; ~/reset clears it at once", gt=0.0, read_only=False),
    Param("diagnostics.stale_after", "double", 1.0, "WARN when no measurement was accepted for this "
          "long (s) (a stalled publisher)", gt=0.0, read_only=False),
    Param("diagnostics.expected_rate", "double", 0.0, "expected measurement rate (Hz) for the rate "
          "check; 0 disables it", min=0.0, read_only=False),
    Param("diagnostics.hardware_id", "string", "", "node only: hardware_id in /diagnostics"),
    Param("output.frame_id", "string", "", "header.frame_id of the stamped outputs "
          "(state_estimate_stamped, unknown_input_estimate_stamped, estimated_joint_states)",
          read_only=False),
    Param("autostart", "bool", False, "managed node only: configure and activate at start-up "
          "(else it waits in 'unconfigured' for the lifecycle services)"),
    Param("metrics.settle_time", "double", 0.0, "replay only: errors are summarised from this "
          "long (s) after each (re)start (0: the guaranteed time + 10 ms, or 0.11 s without "
          "one; fto-replay --after overrides it)", min=0.0),
    Param("qos.depth", "int", 100, "node only: subscription queue depth (best effort, keep last)",
          min=1, max=100000),
    Param("node.executor", "string", "auto", "node only (plain node; the managed node always "
          "runs the single-threaded one): the executor, 'events' (rclpy.experimental."
          "EventsExecutor: about half the CPU per message, docs/benchmarks.md), 'single' "
          "(SingleThreadedExecutor) or 'auto' (events in per-joint mode, single otherwise)",
          choices=("auto", "events", "single")),
)

#: ROS's own parameters that may appear in a params file
ROS_BUILTIN = ("use_sim_time", "start_type_description_service")


def is_arm(flat: Mapping[str, Any]) -> bool:
    """Whether ``flat`` chooses a family that estimates an arm's external torques (one
    observer over ``joints``, its plant the URDF: observers/arm_base.py)."""
    cls = REGISTRY.get(flat.get("observer.type")) if isinstance(flat.get("observer.type"), str) \
        else None
    return bool(getattr(cls, "ARM", False))


def _arm_observer(flat: Mapping[str, Any], cls) -> tuple[type, dict[str, Any], dict[str, Any]]:
    """An arm family's (class, config, flat): its section, the arm parameters (``cfg['arm']``,
    arm/params.py) and the joint list (``joints``)."""
    section = cls.TYPE + "."
    values = {k[len(section):]: v for k, v in flat.items() if k.startswith(section)}
    cfg = resolve(cls.PARAMS, values, prefix=section)
    cfg["arm"] = resolve(cls.ARM_PARAMS, {k: v for k, v in flat.items() if k in
                                          {p.name for p in cls.ARM_PARAMS}})
    joints = flat.get("joints") or []
    cfg["joints"] = resolve([p for p in SETTINGS if p.name == "joints"], {"joints": joints})[
        "joints"]
    return cls, cfg, dict(flat)


def _observer(flat: Mapping[str, Any], type_name: Any) -> tuple[type, dict[str, Any], dict[str, Any]]:
    """(registered class, typed config, flat parameters after the plant expansion) of
    observer ``type_name`` as configured by ``flat`` (its section, the plant block); a
    composition's config holds each child's (type name, typed config) under
    ``<role>_observer`` (observers/registry.py ``make``)."""
    cls = observer_class(type_name)
    sub = dict(flat)
    sub["observer.type"] = type_name
    if is_arm(sub):
        return _arm_observer(sub, cls)
    if cls.CHILD_ROLES:                            # a composition: its children expand
        sub = {k: v for k, v in sub.items() if not k.startswith("plant.")}
    else:
        sub = expand_plant(sub)
    section = cls.TYPE + "."
    values = {k[len(section):]: v for k, v in sub.items() if k.startswith(section)}
    cfg = resolve(cls.PARAMS, values, prefix=section)
    for role in cls.CHILD_ROLES:
        _, child_cfg, _ = _observer(flat, cfg[role])
        cfg[role + "_observer"] = (cfg[role], child_cfg)
    return cls, cfg, sub


def split(flat: Mapping[str, Any]) -> tuple[dict[str, Any], type, dict[str, Any]]:
    """(typed settings, observer class, typed observer config) from flat parameters.

    Sections of other registered observers are ignored (one file may carry
    several); any other unknown name is refused.  A plant block (``plant.*``) is
    expanded first into the chosen observer's explicit parameters (fto_ros.plant); a
    composition (``track``) gets its children's type names and configs in its config.
    """
    for k, v in flat.items():                  # sizes first: nothing is parsed before
        check_size(k, v)
    known = {p.name for p in SETTINGS}
    type_name = flat.get("observer.type")
    if type_name is None:
        raise ConfigError("observer.type", "missing: say which observer to run (one of "
                          + ", ".join(sorted(REGISTRY)) + ")")
    cls, obs_cfg, flat = _observer(flat, type_name)
    section = cls.TYPE + "."
    arm = {p.name for p in getattr(cls, "ARM_PARAMS", ())}
    for k in flat:
        if k in known or k in arm or k.startswith(section) or k in ROS_BUILTIN:
            continue
        if k.split(".", 1)[0] in REGISTRY:
            continue
        raise ConfigError(k, "unknown parameter (a typo? see docs/ros_interface.md)")
    settings = resolve(SETTINGS, {k: v for k, v in flat.items() if k in known})
    return settings, cls, obs_cfg


def check_settings(settings: Mapping[str, Any], n_states: int, n_outputs: int, n_inputs: int) -> None:
    """Cross-checks of the I/O settings against the observer's dimensions."""
    x0 = settings["observer.initial_estimate"]
    if x0 and len(x0) != n_states:
        raise ConfigError("observer.initial_estimate", f"expected {n_states} values, got {len(x0)}")
    if settings["joint_overrides"] and not settings["joints"]:
        raise ConfigError("joint_overrides", "per-joint values need the per-joint mode: list the "
                          "joints in 'joints' (or set the observer's parameters directly)")
    if settings["joints"]:
        if settings["source"] != "joint_states":
            raise ConfigError("source", "per-joint mode (joints) reads every joint from one "
                              "JointState: set source: joint_states")
        if len(settings["joint_states.output_fields"]) != n_outputs:
            raise ConfigError("joint_states.output_fields", f"expected {n_outputs} field(s), one "
                              f"per output of the joint's plant, got "
                              f"{settings['joint_states.output_fields']}")
        if len(settings["joint_states.input_fields"]) < n_inputs:
            raise ConfigError("joint_states.input_fields", f"expected {n_inputs} field(s), one per "
                              f"input of the joint's plant, got {settings['joint_states.input_fields']}")
    elif settings["source"] == "joint_states":
        if len(settings["joint_states.output_joints"]) != n_outputs:
            raise ConfigError("joint_states.output_joints", f"expected {n_outputs} joint name(s) "
                              f"(one per output), got {settings['joint_states.output_joints']}")
        if len(settings["joint_states.input_joints"]) != n_inputs:
            raise ConfigError("joint_states.input_joints", f"expected {n_inputs} joint name(s) "
                              f"(one per input), got {settings['joint_states.input_joints']}")
    names = settings["estimated_joint_states.joint_names"]
    for field in FIELDS:
        key = f"estimated_joint_states.{field}_states"
        idx = settings[key]
        if idx and len(idx) != len(names):
            raise ConfigError(key, f"expected one index per joint ({len(names)}), got {len(idx)}")
        bad = [i for i in idx if i >= n_states]
        if bad:
            raise ConfigError(key, f"state index {bad[0]} out of range (n = {n_states})")
