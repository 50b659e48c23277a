"""What the node publishes per message in per-joint mode (``joints``), and /diagnostics.

One message per output per JointState taken, stamped with the measurement's stamp, naming
only the joints whose sample gave an output (runner/joint_outputs.py):

- ``~/estimated_joint_states`` (sensor_msgs/JointState, the default output): name = the
  joints, position / velocity / effort = each joint's estimated position, velocity and
  unknown input (the runner's roles; a field no observer fills is empty);
- ``~/state_estimate_stamped`` / ``~/unknown_input_estimate_stamped`` (JointState): every
  state (unknown input) of every joint, named ``joint/state``, in ``position``;
- ``~/state_estimate`` / ``~/unknown_input_estimate`` / ``~/convergence``
  (Float64MultiArray, one labelled dimension per element ``joint/element``).

The JointStates are published pre-serialised (runner/joint_state_cdr.py: one buffer per
set of joints, reused; docs/benchmarks.md "JointState I/O of the node").  As in
outputs.py, a topic nobody subscribes to is not published (counts refreshed every
REFRESH_S); /diagnostics carries the node's status and one per joint.
"""
from __future__ import annotations

import array

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ..runner.joint_outputs import JointOutputPlan
from ..runner.joint_state_cdr import JointStateEncoder
from .outputs import OUT_QOS, diagnostic_array, labelled_array


class JointOutputs:
    """The per-joint mode's publishers (see the module doc)."""

    def __init__(self, create_publisher, plan: JointOutputPlan, frame_id: str):
        no_events = PublisherEventCallbacks(use_default_callbacks=False)
        overridable = QoSOverridingOptions.with_default_policies()

        def pub(mtype, topic):
            return create_publisher(mtype, topic, OUT_QOS, event_callbacks=no_events,
                                    qos_overriding_options=overridable)
        self.plan = plan
        self.frame_id = frame_id
        self.js = pub(JointState, "~/estimated_joint_states")
        self.est_stamped = pub(JointState, "~/state_estimate_stamped")
        self.est = pub(Float64MultiArray, "~/state_estimate")
        self.conv = pub(Float64MultiArray, "~/convergence")
        self.ui = self.ui_stamped = None
        if plan.unknown_input_names:
            self.ui = pub(Float64MultiArray, "~/unknown_input_estimate")
            self.ui_stamped = pub(JointState, "~/unknown_input_estimate_stamped")
        self.diag = pub(DiagnosticArray, "/diagnostics")
        self.per_sample = [p for p in (self.js, self.est_stamped, self.est, self.conv,
                                       self.ui, self.ui_stamped) if p is not None]
        self.publishers = self.per_sample + [self.diag]
        self._encoders: dict = {}
        self._arrays: dict = {}
        self.wanted: dict = {}
        self.refresh()

    def set_frame(self, frame: str) -> None:
        """header.frame_id of the JointStates from now on."""
        self.frame_id = frame
        self._encoders.clear()

    def refresh(self) -> None:
        """Which per-sample topics have a subscriber (the others are not published)."""
        self.wanted = {p: p.get_subscription_count() > 0 for p in self.per_sample}

    def _encoder(self, what: str, rows: np.ndarray) -> JointStateEncoder:
        key = (what, rows.tobytes())
        enc = self._encoders.get(key)
        if enc is None:
            plan, k = self.plan, len(rows)
            if what == "joints":
                enc = JointStateEncoder(plan.names(rows), (k, k * plan.has_velocity,
                                                           k * plan.has_effort), self.frame_id)
            else:
                labels = plan.labels(rows, what)
                enc = JointStateEncoder(labels, (len(labels), 0, 0), self.frame_id)
            self._encoders[key] = enc
        return enc

    def _array(self, what: str, rows: np.ndarray) -> Float64MultiArray:
        key = (what, rows.tobytes())
        msg = self._arrays.get(key)
        if msg is None:
            msg = self._arrays[key] = labelled_array(self.plan.labels(rows, what))
        return msg

    def _publish_array(self, pub, what: str, rows: np.ndarray, values: np.ndarray) -> None:
        msg = self._array(what, rows)
        msg.data = array.array("d", np.ascontiguousarray(values, dtype=np.float64).tobytes())
        pub.publish(msg)

    def publish(self, rows: np.ndarray, x: np.ndarray, ui: np.ndarray, conv: np.ndarray,
                sec: int, nanosec: int) -> None:
        """One message per wanted output for the joints ``rows`` (their estimates x (J x n),
        unknown inputs ui (J x r), convergence values (J x c)), stamped (sec, nanosec)."""
        wanted = self.wanted
        if wanted[self.js]:
            pos, vel, eff = self.plan.fields(rows, x, ui)
            self.js.publish(self._encoder("joints", rows).encode(sec, nanosec, pos, vel, eff))
        if wanted[self.est_stamped]:
            self.est_stamped.publish(self._encoder("state", rows).encode(
                sec, nanosec, x[rows].ravel()))
        if wanted[self.est]:
            self._publish_array(self.est, "state", rows, x[rows])
        if wanted[self.conv]:
            c = conv[rows]
            if not np.isfinite(c).all():    # guaranteed_time = inf: 'no guarantee' is -1.0
                c = np.where(np.isfinite(c), c, -1.0)
            self._publish_array(self.conv, "convergence", rows, c)
        if self.ui is not None:
            if wanted[self.ui]:
                self._publish_array(self.ui, "unknown_input", rows, ui[rows])
            if wanted[self.ui_stamped]:
                self.ui_stamped.publish(self._encoder("unknown_input", rows).encode(
                    sec, nanosec, ui[rows].ravel()))

    def publish_statuses(self, ns: int | None, statuses) -> None:
        """/diagnostics: (level, name, message, hardware_id, values) per status."""
        self.diag.publish(diagnostic_array(ns, statuses))
