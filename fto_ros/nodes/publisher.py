"""The node's one output publisher: what the source's output plan says, as raw CDR, and
/diagnostics.

Per accepted sample one message per output of the plan (runner/sources/plan.py), each
stamped with the measurement's time (never now()): the bytes come from the plan's
encoders (core/cdr.py, one reused buffer per layout) and are published as they are, so
rclpy serialises nothing; they are the bytes the replay writes for the same sample.

Publishers are reliable, keep last 10 (overridable per publisher with the read-only
parameters ``qos_overrides.<topic>.publisher.{depth,durability,history,reliability}``, as
rclpy's QoSOverridingOptions declares them), without QoS event handlers (each is rebuilt
into the executor's wait set on every message: ~20 % of the node's CPU at 1 kHz; an
incompatible peer is still told by its own default handler).

A per-sample topic nobody subscribes to is not published (a check of the subscription
count costs 2 us; the counts are refreshed every REFRESH_S by a timer, so a new
subscriber gets data within 0.1 s).  /diagnostics is always published.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ..core.cdr import F64_ARRAY, JOINT_STATE
from ..runner.sources.plan import OutputPlan

#: how often the subscription counts of the per-sample topics are refreshed (s)
REFRESH_S = 0.1

OUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
#: the rclpy class of each message type a plan publishes
MESSAGE_CLASS = {F64_ARRAY: Float64MultiArray, JOINT_STATE: JointState}


class Publisher:
    """The node's publishers of one output plan (see the module doc)."""

    def __init__(self, create_publisher, plan: OutputPlan):
        no_events = PublisherEventCallbacks(use_default_callbacks=False)
        overridable = QoSOverridingOptions.with_default_policies()

        def pub(mtype, topic):
            return create_publisher(mtype, topic, OUT_QOS, event_callbacks=no_events,
                                    qos_overriding_options=overridable)
        self.create = pub
        self.plan = plan
        self.per_sample = [pub(MESSAGE_CLASS[s.msgtype], f"~/{s.topic}") for s in plan.specs]
        self.diag = pub(DiagnosticArray, "/diagnostics")
        self.publishers = self.per_sample + [self.diag]
        self.extra = None
        self.wanted: list = []
        self.refresh()

    def add(self, extra) -> list:
        """Outputs of a family beyond the plan's (nodes/arm_outputs.py: built with
        ``self.create``, so on the same QoS), refreshed and published with the plan's;
        their publishers."""
        self.extra = extra
        return extra.publishers

    def set_frame(self, frame: str) -> None:
        """header.frame_id of the JointStates from now on (output.frame_id changed)."""
        self.plan.set_frame(frame)

    def refresh(self) -> None:
        """Which per-sample topics have a subscriber (the others are not published)."""
        self.wanted = [(i, p) for i, p in enumerate(self.per_sample)
                       if p.get_subscription_count() > 0]
        if self.extra is not None:
            self.extra.refresh()

    def publish(self, ok, x, w, c, sec: int, nanosec: int) -> None:
        """One sample's outputs: x (J, n), w (J, r), c (J, ncf), ok (J,) the joints with one."""
        encode = self.plan.encode_one
        for i, pub in self.wanted:
            payload = encode(i, sec, nanosec, x, w, c, ok)
            if payload is not None:
                pub.publish(payload)
        if self.extra is not None:
            self.extra.publish(ok, x, w, c, sec, nanosec)

    def publish_statuses(self, ns: int | None, statuses) -> None:
        """/diagnostics: (level, name, message, hardware_id, values) per status."""
        self.diag.publish(diagnostic_array(ns, statuses))


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
