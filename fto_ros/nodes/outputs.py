"""What the observer node publishes for an accepted sample, and /diagnostics.

Every message carries the time of the measurement it is for (never now()):

- ``~/state_estimate`` / ``~/unknown_input_estimate``: Float64MultiArray with one
  ``MultiArrayDimension`` per element, labelled with that element's name (size 1,
  stride 1), so plotting tools show ``q``, ``q_dot`` rather than ``data[0]``;
- ``~/state_estimate_stamped`` / ``~/unknown_input_estimate_stamped``: JointState with
  ``header.stamp`` = the sample's stamp, ``header.frame_id`` = ``output.frame_id``,
  ``name`` = the names, ``position`` = the values (velocity and effort empty), for
  message_filters, TF and every time-aware tool;
- ``~/convergence``: Float64MultiArray labelled with convergence_fields (the common
  fields, then the observer's; non-finite values, i.e. "no guarantee", as -1.0);
- ``~/estimated_joint_states`` when configured.

Publishers are reliable, keep last 10 (overridable per publisher with the read-only
parameters ``qos_overrides.<topic>.publisher.{depth,durability,history,reliability}``, as
rclpy's QoSOverridingOptions declares them), without QoS event handlers (each is rebuilt
into the executor's wait set on every message: ~20 % of the node's CPU at 1 kHz; an
incompatible peer is still told by its own default handler).

A per-sample topic nobody subscribes to is not published: a publish costs 15-25 us even
without a subscriber (serialisation), a check of the subscription count 2 us.  The counts
are refreshed every REFRESH_S (0.1 s) by a timer, so a new subscriber gets data within
0.1 s.  /diagnostics is always published.
"""
from __future__ import annotations

import array

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ..observers.base import Observer
from ..runner.runner import convergence_fields

#: how often the subscription counts of the per-sample topics are refreshed (s)
REFRESH_S = 0.1

OUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)


def labelled_array(labels) -> Float64MultiArray:
    """A Float64MultiArray whose layout names each element."""
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=str(name), size=1, stride=1) for name in labels]
    return msg


def _doubles(values) -> array.array:
    return array.array("d", np.asarray(values, dtype=np.float64).tobytes())


class Outputs:
    """The node's output publishers and reusable messages for one observer."""

    def __init__(self, create_publisher, obs: Observer, settings):
        no_events = PublisherEventCallbacks(use_default_callbacks=False)
        overridable = QoSOverridingOptions.with_default_policies()

        def pub(mtype, topic):
            return create_publisher(mtype, topic, OUT_QOS, event_callbacks=no_events,
                                    qos_overriding_options=overridable)
        frame = settings["output.frame_id"]
        self.est = pub(Float64MultiArray, "~/state_estimate")
        self.est_msg = labelled_array(obs.state_names)
        self.est_stamped = pub(JointState, "~/state_estimate_stamped")
        self.est_stamped_msg = JointState(name=list(obs.state_names))
        self.est_stamped_msg.header.frame_id = frame
        self.conv = pub(Float64MultiArray, "~/convergence")
        self.conv_msg = labelled_array(convergence_fields(obs))
        self.ui = self.ui_stamped = None
        if obs.has_unknown_input:
            names = list(getattr(obs, "unknown_input_names", None) or
                         [f"zeta{j}" for j in range(obs.n_outputs)])
            self.ui = pub(Float64MultiArray, "~/unknown_input_estimate")
            self.ui_msg = labelled_array(names)
            self.ui_stamped = pub(JointState, "~/unknown_input_estimate_stamped")
            self.ui_stamped_msg = JointState(name=names)
            self.ui_stamped_msg.header.frame_id = frame
        self.js = None
        if settings["estimated_joint_states.joint_names"]:
            self.js = pub(JointState, "~/estimated_joint_states")
            self.js_msg = JointState()
            self.js_msg.header.frame_id = frame
        self.diag = pub(DiagnosticArray, "/diagnostics")
        self.per_sample = [p for p in (self.est, self.est_stamped, self.conv, self.ui,
                                       self.ui_stamped, self.js) if p is not None]
        self.publishers = self.per_sample + [self.diag]
        self.wanted: dict = {}
        self.refresh()

    def set_frame(self, frame: str) -> None:
        """header.frame_id of the stamped outputs from now on (output.frame_id changed)."""
        for msg in (self.est_stamped_msg, getattr(self, "ui_stamped_msg", None),
                    getattr(self, "js_msg", None)):
            if msg is not None:
                msg.header.frame_id = frame

    def refresh(self) -> None:
        """Which per-sample topics have a subscriber (the others are not published)."""
        self.wanted = {p: p.get_subscription_count() > 0 for p in self.per_sample}

    def publish(self, out, sec: int, nanosec: int) -> None:
        """Publish one runner Output stamped (sec, nanosec) on the topics someone listens to."""
        wanted = self.wanted
        x = _doubles(out.estimate)
        if wanted[self.est]:
            m = self.est_msg
            m.data = x
            self.est.publish(m)
        if wanted[self.est_stamped]:
            st = self.est_stamped_msg
            st.header.stamp.sec, st.header.stamp.nanosec = sec, nanosec
            st.position = x
            self.est_stamped.publish(st)
        if wanted[self.conv]:
            conv = out.convergence
            if not np.isfinite(conv).all():  # guaranteed_time = inf: 'no guarantee' is -1.0
                conv = np.where(np.isfinite(conv), conv, -1.0)
            c = self.conv_msg
            c.data = _doubles(conv)
            self.conv.publish(c)
        if out.unknown_input is not None and self.ui is not None:
            ui = _doubles(out.unknown_input)
            if wanted[self.ui]:
                self.ui_msg.data = ui
                self.ui.publish(self.ui_msg)
            if wanted[self.ui_stamped]:
                us = self.ui_stamped_msg
                us.header.stamp.sec, us.header.stamp.nanosec = sec, nanosec
                us.position = ui
                self.ui_stamped.publish(us)
        if self.js is not None and out.joint_state is not None and wanted[self.js]:
            js = self.js_msg
            js.header.stamp.sec, js.header.stamp.nanosec = sec, nanosec
            js.name, js.position, js.velocity, js.effort = out.joint_state
            self.js.publish(js)

    def publish_diagnostics(self, ns: int | None, level: int, name: str, message: str,
                            hardware_id: str, values) -> None:
        self.diag.publish(diagnostic_array(ns, [(level, name, message, hardware_id, values)]))


def diagnostic_array(ns: int | None, statuses) -> DiagnosticArray:
    """One DiagnosticArray stamped ``ns`` (None: unstamped) of ``statuses``: (level, name,
    message, hardware_id, [(key, value), ...]) each."""
    diag = DiagnosticArray()
    if ns is not None:
        diag.header.stamp.sec, diag.header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000
    diag.status = [DiagnosticStatus(level=bytes([level]), name=name, message=message,
                                    hardware_id=hardware_id,
                                    values=[KeyValue(key=k, value=v) for k, v in values])
                   for level, name, message, hardware_id, values in statuses]
    return diag
