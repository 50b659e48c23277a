"""The node in per-joint mode (``joints: [names]``): one JointState in, every joint's
observer run in one runner call, one JointState out.  Mixed into ObserverCore.

Per message (a raw subscription: the payload decoded with numpy, runner/joint_state_cdr.py,
rclpy's deserialiser for what that does not take):

- the topic's owner and losses as in the single-observer mode (sources.py), then the
  stamp's checks against the wall clock (runner/messages.py ``stamp_check``: a refused
  stamp refuses every joint's sample) and the old timeline after a clock jump;
- each configured joint's y and u by name (runner/intake.py: missing, duplicated, short
  field arrays refuse that joint only, counted with the reason);
- ``Runner.process_joints_arrays``: each joint's checks, gate, observer and restarts on
  its own row;
- the joints with an output published (joints_outputs.py); every other joint's reason
  counted in its own /diagnostics status.

Services: ``~/reset`` and ``~/enable`` act on every joint; ``~/set_state`` restarts the
joints it names (the service: one double_array parameter per joint, named by the joint,
with every state of that joint; the topic: a JointState named ``joint/state`` for every
state of each joint it sets, values in ``position``, as ``~/state_estimate_stamped``
publishes them).
"""
from __future__ import annotations

import math
import time

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from ..runner import loop as L
from ..runner.intake import JointIntake
from ..runner.joint_outputs import JointOutputPlan
from ..runner.joint_state_cdr import JointStateDecoder
from ..runner.messages import stamp_check
from ..runner.runner import reason
from .fast_io import decode_payload, message_info_callback
from .joints_outputs import JointOutputs

_NS = 1_000_000_000


class JointsCore:
    """The per-joint mode of ObserverCore (``self`` is the node)."""

    def _open_joints(self, subscription) -> list:
        """The per-joint outputs and the raw JointState subscription; the entities made."""
        runner, s = self._runner, self._runner.settings
        obs = runner.observer
        r = runner._mem.r
        ui_names = list(getattr(obs, "unknown_input_names", None) or
                        [f"zeta{j}" for j in range(r)])[:r]
        plan = JointOutputPlan(runner.joints, runner.roles, obs.state_names, ui_names,
                               runner.convergence_fields)
        self._out = JointOutputs(self.create_publisher, plan, s["output.frame_id"])
        self._intake = JointIntake(runner.joints, s["joint_states.output_fields"],
                                   s["joint_states.input_fields"], obs.n_inputs)
        self._decoder = JointStateDecoder()
        self._decoded_by_rclpy = 0
        self._every_joint = np.arange(len(runner.joints))
        self._refresh_sim_time()
        ent = list(self._out.publishers)
        ent.append(subscription("joint_states", JointState, s["topics.joint_states"],
                                message_info_callback(self._on_joint_payload), raw=True))
        return ent

    def _refresh_sim_time(self) -> None:
        self._sim_time = self.get_clock().ros_time_is_active

    # --------------------------------------------------------------- samples
    def _on_joint_payload(self, payload: bytes, info: dict) -> None:
        self._received["joint_states"] += 1
        self._win_received += 1
        js, how = decode_payload(self._decoder, payload)
        if js is None:
            self.get_logger().warning(f"JointState refused: {how}", throttle_duration_sec=5.0)
            self._reject("undecodable_joint_state")
            return
        if how == "rclpy":
            self._decoded_by_rclpy += 1
        sec, nanosec = js.sec, js.nanosec
        if not self._from_owner("joint_states", info, sec * _NS + nanosec):
            return
        t = sec + nanosec * 1e-9
        # the wall clock (the ROS clock without sim time), not checked on sim time: as the
        # single-observer mode; whether sim time is on is refreshed with the outputs
        bad = stamp_check(sec, nanosec, t, self._runner.settings,
                          None if self._sim_time else time.time_ns() * 1e-9)
        if bad is not None:
            self._reject(bad)
            return
        if self._from_old_timeline(t):
            return
        self._last_stamp = t
        y, u, refused = self._intake.take_message(js)
        status, x, ui, conv = self._runner.process_joints_arrays(t, y, u, refused)
        last = status[-1]
        if not last.any():                   # every joint an output (L.OUTPUT == 0)
            rows = self._every_joint
        else:
            rows = np.flatnonzero(last == L.OUTPUT)
            for j in np.flatnonzero(last != L.OUTPUT):
                st = int(last[j])
                why = reason(int(status[0, j])) if st == L.SKIPPED else reason(st)
                if why is not None:
                    self._rejected(why)
        if len(rows):
            self._out.publish(rows, x[-1], ui[-1], conv[-1], sec, nanosec)
            self._published += 1
            self._win_published += 1

    # --------------------------------------------------------------- services
    def _set_joint_states(self, given: dict) -> str | None:
        """Restart the joints named in ``given`` (joint -> its states) from them; None or
        why not (nothing is taken then)."""
        runner = self._runner
        n = runner.observer.n_states
        unknown = [j for j in given if j not in runner.joints]
        if unknown or not given:
            return (f"unknown joint(s) {unknown}; joints: {runner.joints}" if unknown else
                    "name at least one joint")
        limit = runner.settings["limits.estimate"]
        for joint, x in given.items():     # every joint checked before any is taken
            if len(x) != n:
                return f"{joint}: {len(x)} value(s) for {n} state(s)"
            if not all(math.isfinite(v) and abs(v) <= limit for v in x):
                return f"{joint}: a value is not finite or beyond limits.estimate"
        for joint, x in given.items():
            runner.set_state(x, runner.joints.index(joint))
        self.get_logger().info("set_state: restarting " + ", ".join(given) + " at the next sample")
        return None

    def _on_set_state_joints(self, request, response):
        params = [Parameter.from_parameter_msg(p) for p in request.parameters]
        given, why = {}, None
        for p in params:
            v = p.value
            if not hasattr(v, "__len__") or isinstance(v, str):
                why = (f"{p.name}: give one double_array parameter per joint (named by the "
                       f"joint) with its {self._runner.observer.n_states} states")
                break
            given[p.name] = [float(a) for a in v]
        if why is None:
            why = self._set_joint_states(given)
        if why is not None:
            self.get_logger().warning(f"set_state refused: {why}")
        response.results = [SetParametersResult(successful=why is None, reason=why or "")
                            for _ in params or [None]]
        return response

    def _on_set_state_topic_joints(self, msg: JointState) -> None:
        names = self._runner.observer.state_names
        if len(msg.position) != len(msg.name):
            why = "position must have one value per name"
        else:
            values = dict(zip(msg.name, msg.position))
            joints = list(dict.fromkeys(nm.split("/", 1)[0] for nm in msg.name))
            given = {}
            why = None
            for joint in joints:
                keys = [f"{joint}/{s}" for s in names]
                if not all(k in values for k in keys):
                    why = f"{joint}: name every state as {', '.join(keys)}"
                    break
                given[joint] = [float(values[k]) for k in keys]
            if why is None and len(values) != len(given) * len(names):
                why = "names other than joint/state of the joints set"
            if why is None:
                why = self._set_joint_states(given)
        if why is not None:
            self.get_logger().warning(f"set_state refused: {why}")

    # ------------------------------------------------------------ diagnostics
    def _joint_statuses(self, now: float | None, node_values: list, level_floor: int,
                        prefix: str) -> tuple:
        """(the node's status: level, message, values; the joints' statuses) for /diagnostics."""
        runner = self._runner
        statuses = runner.statuses(now)
        summary = statuses[0]
        each = statuses[1:] if len(statuses) > 1 else statuses
        hw = runner.settings["diagnostics.hardware_id"] or runner.observer_type
        joints = [(st.level, f"{self.get_name()}: joint {name}", st.message, hw, st.values)
                  for name, st in zip(runner.joints, each)]
        values = list(summary.values) + node_values
        if self._decoded_by_rclpy:
            values.append(("messages decoded by rclpy (not numpy)", str(self._decoded_by_rclpy)))
        level = max(summary.level, level_floor)
        message = prefix + (summary.message if len(statuses) > 1 else
                            f"{runner.joints[0]}: {summary.message}")
        return (level, message, values), hw, joints
