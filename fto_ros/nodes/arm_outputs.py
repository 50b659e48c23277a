"""What the observer node publishes for an arm's external-torque family, beside the outputs
every observer has (the source's plan, nodes/publisher.py, which publishes these with it
on its QoS), each stamped with the measurement's stamp:

- ``~/external_torque`` (sensor_msgs/JointState): name = the joints, position and velocity
  = the estimate x = [q, v], effort = tau_ext (Nm), once the estimator has one;
- ``~/contact`` (JointState) at each contact onset: name = the joints whose residual crossed
  their lower level at that sample, effort = their tau_ext;
- ``~/collision`` (JointState) when a joint's collision latches (its upper level crossed):
  the joints that latched now; cleared by ``~/reset_collision``;
- ``~/wrench`` and ``~/wrench_frame`` (geometry_msgs/WrenchStamped) when ``wrench.frame``
  names a frame: the external wrench at its origin whose joint torques J^T w match tau_ext
  (damped least squares), in the base's axes (frame_id = the URDF's root link) and in the
  frame's own axes (frame_id = the frame), as franka_robot_state_broadcaster publishes them;
- ``~/joint_extras`` (control_msgs/DynamicJointState) where control_msgs is importable (a
  ROS install has it, no pip wheel does): per joint the interfaces external_torque,
  contact, collision, lower_level, upper_level.

Per-sample topics nobody subscribes to are not published (the counts refreshed with the
node's other outputs).
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState

from ..arm import detect as DT

try:                                   # a ROS install has it; no pip wheel does
    from control_msgs.msg import DynamicJointState, InterfaceValue
except ImportError:                    # pragma: no cover - depends on the install
    DynamicJointState = InterfaceValue = None

INTERFACES = ("external_torque", "contact", "collision", "lower_level", "upper_level")


class ArmOutputs:
    """The arm topics of one runner (module doc)."""

    def __init__(self, create, runner, log):
        """``create(message class, topic)``: nodes/publisher.py's ``Publisher.create``."""
        obs = runner.observer
        self.obs, self.n = obs, obs.n_joints
        self.joints = list(obs.joints)
        self.base = runner.convergence_fields.index("tau_ext_valid")
        self.torque = create(JointState, "~/external_torque")
        self.contact = create(JointState, "~/contact")
        self.collision = create(JointState, "~/collision")
        self.frame = obs.arm["wrench.frame"]
        self.wrench = self.wrench_frame = None
        if self.frame:
            self.wrench = create(WrenchStamped, "~/wrench")
            self.wrench_frame = create(WrenchStamped, "~/wrench_frame")
        self.extras = None
        if DynamicJointState is not None:
            self.extras = create(DynamicJointState, "~/joint_extras")
        else:
            log("control_msgs is not importable (no pip wheel has it; a ROS install does): "
                "~/joint_extras (DynamicJointState) is not published, the per-joint values "
                "are on ~/external_torque and ~/convergence")
        self.publishers = [p for p in (self.torque, self.contact, self.collision, self.wrench,
                                       self.wrench_frame, self.extras) if p is not None]
        self._flags = np.zeros(self.n)
        self._latched = np.zeros(self.n)
        self.wanted: dict = {}
        self.refresh()

    def refresh(self) -> None:
        self.wanted = {p: p.get_subscription_count() > 0 for p in self.publishers}

    def _joint_state(self, sec, nanosec, names, position=(), velocity=(), effort=()):
        msg = JointState(name=list(names), position=list(position), velocity=list(velocity),
                         effort=list(effort))
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        return msg

    def publish(self, ok, x, tau, conv, sec: int, nanosec: int) -> None:
        """The arm topics of one sample: the plan's rows (one joint row: the arm is one
        observer) of the estimate x, the external torque tau and the convergence values."""
        if not ok[0]:
            return
        x, tau, conv = x[0], tau[0], conv[0]
        n, b = self.n, self.base
        valid = conv[b + DT.X_VALID] > 0.5
        flags = conv[b + DT.X_HEAD:b + DT.X_HEAD + n]
        latched = conv[b + DT.X_HEAD + n:b + DT.X_HEAD + 2 * n]
        rose = np.flatnonzero((flags > 0.5) & (self._flags < 0.5))
        new = np.flatnonzero((latched > 0.5) & (self._latched < 0.5))
        self._flags, self._latched = flags.copy(), latched.copy()
        if not valid:
            return
        if self.wanted.get(self.torque):
            self.torque.publish(self._joint_state(sec, nanosec, self.joints, x[:n], x[n:], tau))
        if rose.size:
            self.contact.publish(self._joint_state(sec, nanosec, [self.joints[i] for i in rose],
                                                   effort=tau[rose]))
        if new.size:
            self.collision.publish(self._joint_state(sec, nanosec, [self.joints[i] for i in new],
                                                     effort=tau[new]))
        if self.frame and (self.wanted.get(self.wrench) or self.wanted.get(self.wrench_frame)):
            self._wrenches(sec, nanosec, x[:n], tau)
        if self.extras is not None and self.wanted.get(self.extras):
            self._extras(sec, nanosec, conv, tau)

    def _wrenches(self, sec, nanosec, q, tau) -> None:
        model = self.obs.model
        w = model.wrench(self.frame, q, tau, self.obs.arm["wrench.damping"])
        R, _ = model.frame_pose(self.frame, q)
        for pub, frame_id, f, m in ((self.wrench, model.robot.root, w[:3], w[3:]),
                                    (self.wrench_frame, self.frame, R.T @ w[:3], R.T @ w[3:])):
            msg = WrenchStamped()
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            msg.header.frame_id = frame_id
            msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = (float(v) for v in f)
            msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = (float(v) for v in m)
            pub.publish(msg)

    def _extras(self, sec, nanosec, conv, tau) -> None:
        n, b = self.n, self.base + DT.X_HEAD
        msg = DynamicJointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.joint_names = list(self.joints)
        msg.interface_values = [
            InterfaceValue(interface_names=list(INTERFACES),
                           values=[float(tau[i]), float(conv[b + i]), float(conv[b + n + i]),
                                   float(conv[b + 2 * n + i]), float(conv[b + 3 * n + i])])
            for i in range(n)]
        self.extras.publish(msg)

    def forget_latched(self) -> None:
        """The collisions were cleared (~/reset_collision): a new latch is published again."""
        self._latched[:] = 0.0
