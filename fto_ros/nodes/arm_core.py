"""The observer node running an arm's external-torque family (external_torque,
momentum_observer): mixed into ObserverCore.

- **The URDF**: ``plant.urdf`` (a file) or ``robot_description`` (a string parameter), or,
  when neither is given, the transient-local ``robot_description`` topic (std_msgs/String,
  as robot_state_publisher latches it): the node logs that it waits, and configures when
  the text arrives (a text the arm's checks refuse is logged, and the node waits for
  another); a later, different text is logged and not used (restart the node).
- **The arm's outputs** (nodes/arm_outputs.py) beside the plan's, on the one publisher, and the service
  ``~/reset_collision`` (std_srvs/Trigger) that clears the latched collisions.
- **The payload at run time**: a change of ``payload.*`` alone goes into the running
  estimator (the tree's rows in its kernel's constants; the window's history is evaluated
  again with the new model), without a restart: a grasped object is not a contact.
- **/diagnostics**: per joint a status ``<node>: <joint>`` (armed, contact, collision or
  calibrating; the levels in Nm; the residual's level against the encoder's noise; the
  guaranteed detection time), WARN in contact, ERROR on a latched collision.
"""
from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.errors import ConfigError
from ..arm.params import PAYLOAD_NAMES
from ..runner.runner import Runner
from ..runner.settings import is_arm
from .arm_outputs import ArmOutputs

#: the latched URDF, as robot_state_publisher offers it
DESCRIPTION_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
_STATE_LEVEL = {"armed": 0, "calibrating": 0, "contact": 1, "collision": 2}


class ArmCore:
    """The arm families' part of ObserverCore (``self`` is the node)."""

    _arm: ArmOutputs | None = None
    _waiting: dict | None = None
    _description: str | None = None

    # -- the URDF from the topic ---------------------------------------------------------
    def _arm_waits(self, flat: dict) -> bool:
        """True (and the node waits for the robot_description topic) for an arm family
        without plant.urdf and robot_description."""
        if not is_arm(flat) or flat.get("plant.urdf") or flat.get("robot_description"):
            self._waiting = None
            return False
        self._waiting = dict(flat)
        self._runner = None
        topic = self.resolve_topic_name("robot_description")
        self.get_logger().info(f"{flat.get('observer.type')}: no plant.urdf or "
                               f"robot_description parameter: waiting for the URDF on {topic} "
                               f"(std_msgs/String, transient local)")
        return True

    def _open_description(self) -> list:
        return [self.create_subscription(String, "robot_description", self._on_description,
                                         DESCRIPTION_QOS)]

    def _on_description(self, msg: String) -> None:
        if self._runner is not None:
            if msg.data != self._description:
                self.get_logger().warning("a new robot_description arrived: not used (the "
                                          "estimator runs on the first; restart the node)")
            return
        flat = dict(self._waiting)
        flat["robot_description"] = msg.data
        try:
            runner = Runner(flat)
        except ConfigError as exc:
            self.get_logger().error(f"robot_description refused: {exc}; waiting for another")
            return
        self._description = msg.data
        self._params.flat["robot_description"] = msg.data
        self._configured(runner)
        self.get_logger().info(f"robot_description received ({len(msg.data)} characters): "
                               "configured")
        if self._entities is not None:             # open already: the topics now
            self._entities += self._open_observer()

    # -- outputs and services ----------------------------------------------------------------
    def _open_arm(self) -> list:
        """The arm's outputs and ~/reset_collision (nothing for the other families)."""
        runner = self._runner
        if runner.intake is None:
            self._arm = None
            return []
        log = self.get_logger()
        for note in runner.observer.notes:
            log.info("URDF note: " + note)
        self._arm = ArmOutputs(self._out.create, runner, log.info)
        srv = self.create_service(Trigger, "~/reset_collision", self._on_reset_collision)
        return self._out.add(self._arm) + [srv]

    def _on_reset_collision(self, request, response):
        cleared = self._runner.observer.reset_collision()
        if self._arm is not None:
            self._arm.forget_latched()
        response.success = True
        response.message = f"collisions cleared ({cleared} joint(s) were latched)"
        self.get_logger().info("reset_collision: " + response.message)
        return response

    # -- the payload at run time -------------------------------------------------------------
    def _arm_takes(self, diff) -> bool:
        return self._runner is not None and self._runner.intake is not None and \
            bool(diff) and set(diff) <= set(PAYLOAD_NAMES)

    def _arm_payload(self, new: dict, params) -> SetParametersResult:
        try:
            self._runner.observer.set_payload(new)
        except ConfigError as exc:
            return self._refuse_change(params, str(exc))
        self._params.flat = new
        self._runner._flat = dict(new)
        self.get_logger().info("payload changed: " + ", ".join(f"{p.name}={p.value}"
                                                               for p in params)
                               + "; the estimator runs on with it")
        return SetParametersResult(successful=True)

    # -- diagnostics ---------------------------------------------------------------------
    def _arm_statuses(self, hardware_id: str) -> list:
        """Per joint (level, name, message, hardware_id, values)."""
        if self._arm is None:
            return []
        out = []
        for entry in self._runner.observer.joint_diagnostics():
            joint = entry.pop("joint")
            state = entry["state"]
            out.append((_STATE_LEVEL[state], f"{self.get_name()}: {joint}", state, hardware_id,
                        list(entry.items())))
        return out
