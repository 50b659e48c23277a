"""The external-torque node: an arm's JointState -> tau_ext per joint and collisions, with a
guaranteed time (docs/external_torque.md), as a lifecycle node.

``fto-external-torque --ros-args -p plant.urdf:=urdf/arm7.urdf`` (also ``ros2 run fto_ros
external_torque_node``, ``ros2 launch fto_ros arm7_external_torque.launch.py``).

Subscribes   joint_states (sensor_msgs/JointState: position = encoders, effort = the
             commanded torque, header stamp; topics.joint_states)
Publishes    external_torque (JointState, effort = tau_ext in Nm by joint name, the
             measurement's stamp), ~/external_torque_momentum (the same from the
             generalized-momentum observer, when external_torque.momentum_gain > 0),
             ~/collision (JointState at each detection: name = the joints that fired, effort =
             their tau_ext estimate, the measurement's stamp), ~/wrench (WrenchStamped, when
             wrench.link is set: the wrench at that link's origin, world axes, frame_id
             "world", through the Jacobian), /diagnostics (per joint:
             state, threshold, residual, guaranteed detection time, refusals).

Lifecycle: configure declares and checks the parameters and builds the model (a bad one
fails the transition with one log line naming it); activate opens the topics; deactivate
closes them, keeping the estimators; cleanup drops them.  ``autostart`` (default true)
configures and activates at start-up; a bad parameter then exits with status 2 after one
line.  ``-p autostart:=false`` leaves the transitions to a lifecycle manager.
"""
from __future__ import annotations

import sys

from .entry import run
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from ..core.errors import ConfigError  # noqa: E402
from ..runner.torque_loop import TorqueLoop  # noqa: E402
from ..runner.torque_settings import TORQUE_SETTINGS, build  # noqa: E402
from .parameters import _declare, typed_override  # noqa: E402

NAME = "external_torque_node"
PROG, EXE = "fto-external-torque", "external_torque_node"
IN_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                    reliability=ReliabilityPolicy.BEST_EFFORT)
OUT_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE)


class ExternalTorqueNode(LifecycleNode):
    """See the module docstring."""

    def __init__(self, node_name: str = NAME, **kwargs):
        kwargs.setdefault("allow_undeclared_parameters", False)
        kwargs.setdefault("automatically_declare_parameters_from_overrides", False)
        super().__init__(node_name, **kwargs)
        self.loop: TorqueLoop | None = None
        self._io: list = []
        self._failure: ConfigError | None = None
        raw = self._parameter_overrides.get("autostart")
        self._autostart = raw is None or (raw.type_ == Parameter.Type.BOOL and bool(raw.value))
        if self._autostart:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise self._failure or ConfigError("autostart", "the configure transition failed")
            self.trigger_activate()

    # -- parameters -----------------------------------------------------------------------
    def _declared_values(self) -> dict:
        """Declare every setting with its descriptor; the typed values plus every override
        nobody declared (refused by name in ``build``)."""
        overrides = dict(self._parameter_overrides)
        flat = {}
        for p in TORQUE_SETTINGS:
            if self.has_parameter(p.name):
                value = typed_override(p, p.name, self.get_parameter(p.name))
            else:
                value = typed_override(p, p.name, overrides[p.name]) if p.name in overrides \
                    else p.default
                _declare(self, p.name, p, value)
            flat[p.name] = value
        for name, param in overrides.items():
            flat.setdefault(name, param.value)
        return flat

    # -- lifecycle --------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.loop = TorqueLoop(build(self._declared_values()))
            self.loop.warm_up()
        except ConfigError as exc:
            self.loop, self._failure = None, exc
        except Exception as exc:  # noqa: BLE001  a model that cannot be built: unconfigured
            self.loop, self._failure = None, ConfigError(
                "plant.urdf", f"cannot build the model: {type(exc).__name__}: "
                + " ".join(str(exc).split())[:300])
        if self.loop is None:
            if not self._autostart:       # at start-up the entry point prints it, once
                self.get_logger().error(f"fto_ros: bad parameter: {self._failure}")
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        s = self.loop.setup.flat
        self._pub_torque = self.create_publisher(JointState, s["topics.external_torque"], OUT_QOS)
        self._pub_collision = self.create_publisher(JointState, "~/collision", OUT_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", OUT_QOS)
        self._io = [self._pub_torque, self._pub_collision, self._pub_diag]
        self._pub_momentum = None
        if self.loop.gmo is not None:
            self._pub_momentum = self.create_publisher(JointState, "~/external_torque_momentum",
                                                       OUT_QOS)
            self._io.append(self._pub_momentum)
        self._pub_wrench = None
        if s["wrench.link"]:
            self._pub_wrench = self.create_publisher(WrenchStamped, "~/wrench", OUT_QOS)
            self._io.append(self._pub_wrench)
        self._io.append(self.create_subscription(JointState, s["topics.joint_states"],
                                                       self._on_joint_states, IN_QOS))
        self._diag_timer = self.create_timer(s["diagnostics.period"], self._publish_diagnostics)
        return super().on_activate(state)

    def _close(self) -> None:
        for ent in self._io:
            if hasattr(ent, "topic_name") and hasattr(ent, "publish"):
                self.destroy_publisher(ent)
            else:
                self.destroy_subscription(ent)
        if self._io:
            self.destroy_timer(self._diag_timer)
        self._io = []

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close()
        self.loop = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self.on_cleanup(state)

    # -- data -------------------------------------------------------------------------------
    def _joint_state(self, header, names, efforts) -> JointState:
        out = JointState()
        out.header = header
        out.name = names
        out.effort = efforts
        return out

    def _on_joint_states(self, msg: JointState) -> None:
        stamp = msg.header.stamp
        res = self.loop.process(stamp.sec * 1_000_000_000 + stamp.nanosec, msg.name,
                                msg.position, msg.effort)
        if res is None:
            return
        joints = self.loop.joints
        if res.tau_ext is not None:
            self._pub_torque.publish(self._joint_state(msg.header, joints, res.tau_ext.tolist()))
        if res.momentum is not None and self._pub_momentum is not None:
            self._pub_momentum.publish(self._joint_state(msg.header, joints,
                                                         res.momentum.tolist()))
        if res.wrench is not None and self._pub_wrench is not None:
            w = WrenchStamped()
            w.header.stamp, w.header.frame_id = msg.header.stamp, "world"
            f, m = w.wrench.force, w.wrench.torque
            f.x, f.y, f.z, m.x, m.y, m.z = (float(x) for x in res.wrench)
            self._pub_wrench.publish(w)
        if res.collision is not None:
            fired = res.collision.joints
            self._pub_collision.publish(self._joint_state(
                msg.header, [joints[i] for i in fired], [float(res.tau_ext[i]) for i in fired]))

    def _publish_diagnostics(self) -> None:
        loop, s = self.loop, self.loop.setup.flat
        name = self.get_fully_qualified_name().lstrip("/")
        summary = loop.summary()
        level = 0 if summary["calibrated"] == "true" else 1
        statuses = [DiagnosticStatus(
            level=bytes([level]), name=f"{name}: external torque", hardware_id=name,
            message="calibrated" if level == 0 else "calibrating or waiting for samples",
            values=[KeyValue(key=k, value=v) for k, v in summary.items()])]
        for entry in loop.joint_status(s["collision.contact_size"], s["collision.miss"]):
            joint = entry.pop("joint")
            statuses.append(DiagnosticStatus(
                level=bytes([1 if entry["state"] == "contact" else 0]),
                name=f"{name}: {joint}", hardware_id=name, message=entry["state"],
                values=[KeyValue(key=k, value=v) for k, v in entry.items()]))
        diag = DiagnosticArray()
        diag.header.stamp = self.get_clock().now().to_msg()
        diag.status = statuses
        self._pub_diag.publish(diag)


USAGE = __doc__.split("\n\n", 1)[1]


def _with_default_name(args: list[str]) -> list[str]:
    """The entry point's params-file and ``-p`` handling address the node by the name a
    ``-r __node:=`` remap gives: this node's default name, unless the user chose one."""
    if any(a.startswith("__node:=") for a in args):
        return args
    return ["--ros-args", "-r", f"__node:={NAME}", "--", *args]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``fto-external-torque`` / ``external_torque_node``."""
    args = list(sys.argv[1:] if argv is None else argv)
    head = args[:args.index("--ros-args")] if "--ros-args" in args else args
    if "-h" in head or "--help" in head:
        print(f"usage: {PROG} [-h] [--ros-args -p NAME:=VALUE ... --params-file FILE]\n\n"
              + USAGE + "\nparameters:\n" + "\n".join(
                  f"  {p.name} ({p.kind}, default {p.default!r}): {p.description}"
                  for p in TORQUE_SETTINGS))
        return 0
    return run(ExternalTorqueNode, PROG, EXE, managed=True, argv=_with_default_name(args))


if __name__ == "__main__":
    sys.exit(main())
