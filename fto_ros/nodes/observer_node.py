"""The live observer node: ROS topics <-> the ROS-free runner.

``fto-observer --ros-args --params-file config/X.yaml [-p name:=value ...]``
(also ``ros2 run fto_ros observer_node``).

Everything numerical happens in :class:`fto_ros.runner.Runner`, the same code
the offline replay runs; this module only

- declares the parameters (``observer.type`` first, then every runner setting
  and every parameter of the chosen observer, each with a descriptor),
  validates them and refuses bad runtime changes with a reason;
- turns messages into ``(t, y, u)`` samples and outputs into messages stamped
  with the measurement time (never now());
- publishes ``/diagnostics``, offers ``~/reset`` and ``~/enable`` and restarts
  the observer when the ROS clock jumps backwards (bag loop, sim restart).

Time stamps.  A ``JointState`` sample is taken at its header stamp.  A
``Float64MultiArray`` has none: it is stamped with the node clock *at its receipt
by DDS* (the ``received_timestamp`` of its message info), not when the executor
gets round to it, so a node running behind its input still sees the true sample
spacing.  Under ``use_sim_time`` that is the last ``/clock`` received before the
message (see ``_setup_sim_clock``): exact with ``fto-play --clock``, which
publishes ``/clock`` before every sample.

Published values are always finite: on ``~/convergence`` the guaranteed
convergence time is ``-1.0`` when the observer gives no guarantee
(asymptotic observers), and the output residual is ``-1.0`` when unknown.

Speed (benchmarks/bench_live_node.py): one OpenBLAS thread, no QoS event handlers
on the node's own entities, and ``gc.freeze()`` after start-up (no 50 ms full
collections of the ~1e5 objects sympy/scipy leave) keep 1 kHz at about half a core.
"""
from __future__ import annotations

import array
import gc
import os
import sys
import time
from collections import deque
from typing import Any

# One BLAS thread: the updates are tiny matrix products, and OpenBLAS's worker threads
# spin-wait, which cost a whole core at 1 kHz on a 2-core machine (set it before numpy).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import rclpy
import rclpy.logging
import rclpy.utilities
from rclpy.clock import Clock, ClockType, JumpThreshold
from rclpy.duration import Duration
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.qos_overriding_options import QoSOverridingOptions

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rosgraph_msgs.msg import Clock as RosClock
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from std_srvs.srv import SetBool, Trigger

from ..core.errors import ConfigError
from ..observers import REGISTRY, observer_class
from ..observers.base import Observer, Param
from ..plant.block import PLANT_PARAMS, PREFIX as PLANT_PREFIX
from ..runner.messages import joint_state_sample
from ..runner.runner import CONVERGENCE_FIELDS, Runner
from ..runner.params_file import load_params_file
from ..runner.settings import ROS_BUILTIN, SETTINGS

NODE_NAME = "observer_node"

#: Param.kind -> ROS 2 parameter type
_ROS_TYPE = {
    "bool": Parameter.Type.BOOL,
    "int": Parameter.Type.INTEGER,
    "double": Parameter.Type.DOUBLE,
    "string": Parameter.Type.STRING,
    "double_array": Parameter.Type.DOUBLE_ARRAY,
    "int_array": Parameter.Type.INTEGER_ARRAY,
    "string_array": Parameter.Type.STRING_ARRAY,
}
_ARRAY_KINDS = ("double_array", "int_array", "string_array")
_INT64_MIN, _INT64_MAX = -(2 ** 63), 2 ** 63 - 1
_NS = 1_000_000_000
#: how often at most a summary of rejected samples is logged (s)
LOG_THROTTLE_S = 5.0


def _descriptor(p: Param, full_name: str) -> ParameterDescriptor:
    """A ParameterDescriptor for ``p`` (description, range, read_only, choices)."""
    d = ParameterDescriptor(description=p.description, read_only=bool(p.read_only))
    constraints = []
    if p.choices:
        constraints.append("one of: " + ", ".join(p.choices))
    if p.min is not None or p.max is not None:
        if p.kind == "double":
            lo = -sys.float_info.max if p.min is None else float(p.min)
            hi = sys.float_info.max if p.max is None else float(p.max)
            d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
        elif p.kind == "int":
            lo = _INT64_MIN if p.min is None else int(p.min)
            hi = _INT64_MAX if p.max is None else int(p.max)
            d.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=0)]
        else:  # ROS ranges apply to scalars only: state the element range in words
            parts = ([f">= {p.min}"] if p.min is not None else []) + \
                    ([f"<= {p.max}"] if p.max is not None else [])
            constraints.append("every element " + " and ".join(parts))
    if p.default is None:
        constraints.append("required")
    d.additional_constraints = "; ".join(constraints)
    return d


def _typed_override(p: Param, full_name: str, param: Parameter) -> Any:
    """The override ``param`` converted to ``p``'s type (ConfigError naming it otherwise).

    ``None`` for an unset value (an empty YAML list reaches rclpy as NOT_SET).
    """
    if param.type_ == Parameter.Type.NOT_SET or param.value is None:
        return [] if p.kind in _ARRAY_KINDS else None
    return p.coerce(param.value, full_name)


class ObserverNode(Node):
    """A guaranteed-time state observer on live topics (see the module docstring)."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs):
        kwargs.setdefault("allow_undeclared_parameters", False)
        kwargs.setdefault("automatically_declare_parameters_from_overrides", False)
        super().__init__(node_name, **kwargs)
        try:
            self._setup()
        except BaseException:
            self.destroy_node()
            raise

    # ------------------------------------------------------------------ setup
    def _setup(self) -> None:
        self._clock = self.get_clock()
        self._specs: dict[str, Param] = {}     # full name -> Param, for runtime changes
        self._flat: dict[str, Any] = {}        # full name -> typed value (the runner's input)
        self._declare_parameters()
        self._runner = Runner(self._flat_with_unknown_overrides())
        runner = self._runner
        obs = runner.observer
        # node-side counters (the runner counts samples and rejections)
        self._received = {"measured_output": 0, "input": 0, "joint_states": 0}
        self._published = 0
        self._dropped_disabled = 0
        self._enabled = True
        self._last_stamp: float | None = None
        self._rejected_since_log = 0
        self._last_reject_log = 0.0
        self._win_steady = time.monotonic()
        self._win_published = 0
        self._win_received = 0
        self._apply_settings()

        # publishers: reliable, keep last 10.  No QoS event handlers on our high-rate
        # entities: each one is rebuilt into the executor's wait set on every message
        # (~20 % of the node's CPU at 1 kHz), and an incompatible-QoS peer is still
        # reported by the peer's own default handler.
        out_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
        no_events = PublisherEventCallbacks(use_default_callbacks=False)

        def publisher(mtype, topic):
            return self.create_publisher(mtype, topic, out_qos, event_callbacks=no_events)
        self._pub_est = publisher(Float64MultiArray, "~/state_estimate")
        self._est_msg = self._array_msg(obs.state_names, obs.n_states)
        self._pub_conv = publisher(Float64MultiArray, "~/convergence")
        self._conv_msg = self._array_msg(CONVERGENCE_FIELDS, len(CONVERGENCE_FIELDS))
        self._pub_ui = None
        if type(obs).unknown_input is not Observer.unknown_input:  # the class identifies one
            self._pub_ui = publisher(Float64MultiArray, "~/unknown_input_estimate")
        self._ui_msg = Float64MultiArray()
        self._pub_js = None
        self._js_msg = JointState()
        if runner.settings["estimated_joint_states.joint_names"]:
            self._pub_js = publisher(JointState, "~/estimated_joint_states")
        self._pub_diag = publisher(DiagnosticArray, "/diagnostics")

        # subscriptions: sensor-data QoS (best effort, keep last qos.depth, volatile), overridable
        in_qos = QoSProfile(depth=runner.settings["qos.depth"], history=HistoryPolicy.KEEP_LAST,
                            reliability=ReliabilityPolicy.BEST_EFFORT,
                            durability=DurabilityPolicy.VOLATILE)
        s = runner.settings

        def subscription(mtype, topic, callback):
            return self.create_subscription(
                mtype, topic, callback, in_qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
                event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        self._subs = []
        self._setup_sim_clock()   # before the data subscriptions: first in an executor round
        if s["source"] == "topics":
            # input first: when u_k and y_k wait in the same executor round, u_k must be
            # stored before y_k is processed (u given at t holds from t on)
            if obs.n_inputs > 0:
                self._subs.append(subscription(Float64MultiArray, s["topics.input"], self._on_input))
            self._subs.append(subscription(Float64MultiArray, s["topics.measured_output"],
                                           self._on_measured_output))
        else:
            self._subs.append(subscription(JointState, s["topics.joint_states"], self._on_joint_states))

        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/enable", self._on_enable)

        # /diagnostics on the steady clock: it keeps coming when sim time stops
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._diag_timer = self.create_timer(s["diagnostics.period"], self._publish_diagnostics,
                                             clock=self._steady)
        self._jump_handle = None
        self._arm_jump_callback()

        self.add_pre_set_parameters_callback(self._pre_set_parameters)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.get_logger().info(
            f"{obs.TYPE} observer: {obs.n_states} states, {obs.n_outputs} output(s), "
            f"{obs.n_inputs} input(s); source '{s['source']}'"
            + (", sim time" if self._clock.ros_time_is_active else ""))
        # the start-up checks' figures (single_delay: tau, cond(S), noise gain, ...)
        self.get_logger().info("design: " + "; ".join(f"{k} = {v}" for k, v in obs.diagnostics().items()))

    def _declare_parameters(self) -> None:
        overrides: dict[str, Parameter] = dict(self._parameter_overrides)
        type_param = SETTINGS[0]
        assert type_param.name == "observer.type"
        raw = overrides.get("observer.type")
        type_name = None if raw is None else _typed_override(type_param, "observer.type", raw)
        if type_name is None:
            raise ConfigError("observer.type", "missing: say which observer to run (one of "
                              + ", ".join(sorted(REGISTRY)) + ") in the params file or with "
                              "-p observer.type:=NAME")
        cls = observer_class(type_name)
        specs = [(p.name, p) for p in SETTINGS] + [(f"{cls.TYPE}.{p.name}", p) for p in cls.PARAMS]
        specs += [(PLANT_PREFIX + p.name, p) for p in PLANT_PARAMS]      # the plant block
        for full, p in specs:
            value = p.default
            if full in overrides:
                value = _typed_override(p, full, overrides[full])
            elif value is not None:
                value = p.coerce(value, full)
            desc = _descriptor(p, full)
            if value is None or (p.kind in _ARRAY_KINDS and len(value) == 0):
                # rclpy infers a type from the value, and [] has none: declare the type only
                self.declare_parameter(full, _ROS_TYPE[p.kind], desc, ignore_override=True)
            else:
                self.declare_parameter(full, value, desc, ignore_override=True)
            self._specs[full] = p
            if value is not None:
                self._flat[full] = value

    def _flat_with_unknown_overrides(self) -> dict[str, Any]:
        """The declared values plus every override nobody declared, so the runner refuses typos."""
        flat = dict(self._flat)
        for name, param in self._parameter_overrides.items():
            if name in flat or name in self._specs or name in ROS_BUILTIN:
                continue
            if name.startswith("qos_overrides."):
                continue
            flat[name] = param.value
        return flat

    def _apply_settings(self) -> None:
        """Cache the settings read per message."""
        s = self._runner.settings
        self._future_tolerance = s["time.future_tolerance"]
        self._reset_on_jump = s["time.reset_on_jump"]
        self._jump_threshold = s["time.jump_threshold"]

    @staticmethod
    def _array_msg(labels, n: int) -> Float64MultiArray:
        msg = Float64MultiArray()
        msg.layout.dim = [MultiArrayDimension(label=",".join(labels), size=n, stride=n)]
        return msg

    # ------------------------------------------------------------- parameters
    def _pre_set_parameters(self, params: list[Parameter]) -> list[Parameter]:
        """Runtime ``ros2 param set x 1`` for a double: convert instead of refusing."""
        out = []
        for param in params:
            p = self._specs.get(param.name)
            if p is not None and param.type_ != _ROS_TYPE[p.kind] \
                    and param.type_ != Parameter.Type.NOT_SET:
                try:
                    value = p.coerce(param.value, param.name)
                    if p.kind in _ARRAY_KINDS and len(value) == 0:
                        value = []
                    param = Parameter(param.name, _ROS_TYPE[p.kind], value)
                except (ConfigError, TypeError, ValueError):
                    pass  # ROS refuses it with 'Wrong parameter type', naming both types
            out.append(param)
        return out

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        new = dict(self._flat)
        changed = False
        try:
            for param in params:
                p = self._specs.get(param.name)
                if p is None:
                    continue  # use_sim_time, qos_overrides...: ROS's own
                value = _typed_override(p, param.name, param)
                if value is None:
                    new.pop(param.name, None)
                else:
                    new[param.name] = value
                changed = True
            if changed:
                self._runner.reconfigure(new)
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if changed:
            self._flat = new
            old_threshold = self._jump_threshold
            self._apply_settings()
            if self._jump_threshold != old_threshold:
                self._arm_jump_callback()
            self.get_logger().info("parameters changed: "
                                   + ", ".join(f"{p.name}={p.value}" for p in params)
                                   + "; observer restarted")
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------- time
    def _arm_jump_callback(self) -> None:
        if self._jump_handle is not None:
            self._jump_handle.unregister()
        ns = max(1, int(round(self._jump_threshold * 1e9)))
        self._jump_handle = self._clock.create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(nanoseconds=-ns),
                          on_clock_change=False),
            post_callback=self._on_time_jump)

    def _on_time_jump(self, jump) -> None:
        """The ROS clock went backwards by more than time.jump_threshold."""
        if not self._reset_on_jump:
            return
        # The runner restarts by itself on a backward sample stamp (JointState stamps may
        # jump before /clock does); count one jump once.
        t_last = self._runner.last_sample_time
        now = self._clock.now().nanoseconds * 1e-9
        if t_last is None or t_last <= now + self._jump_threshold:
            return
        self._runner.time_jump(now)
        self.get_logger().warning(
            f"ROS time jumped back by {-jump.delta.nanoseconds * 1e-9:.3f} s: observer restarted",
            throttle_duration_sec=LOG_THROTTLE_S)

    # --------------------------------------------------------------- samples
    def _reject(self, reason: str) -> None:
        """Count a rejection found by the node (not the runner) in the runner's counters."""
        self._runner.reject(reason)
        self._rejected(reason)

    def _rejected(self, reason: str) -> None:
        """Log rejected samples as a throttled summary, never one line per sample."""
        self._rejected_since_log += 1
        mono = time.monotonic()
        if mono - self._last_reject_log >= LOG_THROTTLE_S:
            rej = self._runner.rejected
            self.get_logger().warning(
                f"{self._rejected_since_log} sample(s) rejected (last: {reason}); totals: "
                + ", ".join(f"{k}={v}" for k, v in sorted(rej.items())),
                throttle_duration_sec=LOG_THROTTLE_S)
            self._last_reject_log = mono
            self._rejected_since_log = 0

    def _setup_sim_clock(self) -> None:
        """Under sim time, feed the node clock from a /clock subscription that keeps history.

        A Float64MultiArray is stamped with the node clock *at its receipt by DDS*
        (``received_timestamp`` of its message info), not when the executor gets to
        it: with wall time that is the receipt time itself, with sim time the last
        /clock received before it.  rclpy's own /clock subscription keeps only the
        latest message, so a node lagging a 1 kHz bag would stamp a backlog of samples
        with one (later) time; this subscription replaces it (same callback, deeper
        queue, drained before every stamp).  It also tells 'ROS time 0 = no /clock yet'
        from a bag that starts at t = 0.
        """
        self._clock_hist: deque[tuple[int, int]] = deque(maxlen=4096)  # (received ns, clock ns)
        self._clock_seen = not self._clock.ros_time_is_active
        self._clock_sub = None
        self._time_source_cb = None
        if not self._clock.ros_time_is_active:
            return
        ts = getattr(self, "_time_source", None)
        old = getattr(ts, "_clock_sub", None)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT,
                         history=HistoryPolicy.KEEP_LAST)
        if old is not None and callable(getattr(ts, "clock_callback", None)):
            self.destroy_subscription(old)
            self._time_source_cb = ts.clock_callback
            self._clock_sub = ts._clock_sub = self.create_subscription(
                RosClock, "/clock", self._on_clock, qos)
        else:  # another rclpy: keep its subscription, add ours next to it
            self._clock_sub = self.create_subscription(RosClock, "/clock", self._on_clock, qos)

    def _on_clock(self, msg, info) -> None:
        if self._time_source_cb is not None:
            self._time_source_cb(msg)  # sets the node clock (and fires the jump callbacks)
        self._clock_seen = True
        received = info.get("received_timestamp") or time.time_ns()
        self._clock_hist.append((received, msg.clock.sec * _NS + msg.clock.nanosec))

    def _drain_clock(self) -> None:
        """Take every /clock message already received (the executor may lag behind DDS)."""
        sub = self._clock_sub
        try:
            with sub.handle:
                while True:
                    got = sub.handle.take_message(RosClock, False)
                    if got is None:
                        return
                    self._on_clock(*got)
        except InvalidHandle:  # use_sim_time switched off at run time
            self._clock_sub = None

    def _receipt_ns(self, info) -> int | None:
        """The node clock (ns) when DDS received the message; None: no /clock yet."""
        received = info.get("received_timestamp", 0) if info else 0
        if not self._clock.ros_time_is_active:
            return received if received > 0 else self._clock.now().nanoseconds
        sub = self._clock_sub
        ts = getattr(self, "_time_source", None)
        if sub is None or received <= 0 or (self._time_source_cb is not None
                                            and getattr(ts, "_clock_sub", None) is not sub):
            return self._now_ns()
        self._drain_clock()
        for t_received, clock_ns in reversed(self._clock_hist):
            if t_received <= received:
                return clock_ns
        return None

    def _now_ns(self) -> int | None:
        """Node clock now in ns; None while sim time is on and no /clock has arrived."""
        ns = self._clock.now().nanoseconds
        if ns == 0 and not self._clock_seen and self._clock.ros_time_is_active:
            return None
        return ns

    def _on_measured_output(self, msg: Float64MultiArray, info: dict) -> None:
        self._received["measured_output"] += 1
        self._win_received += 1
        if not self._enabled:
            self._dropped_disabled += 1
            return
        ns = self._receipt_ns(info)
        if ns is None:
            self._reject("waiting_for_clock")
            return
        out = self._runner.process(ns * 1e-9, msg.data)
        if out.__class__ is str:
            self._rejected(out)
            return
        self._publish(out, ns // _NS, ns % _NS)

    def _on_input(self, msg: Float64MultiArray, info: dict) -> None:
        self._received["input"] += 1
        if not self._enabled:
            return
        ns = self._receipt_ns(info)
        if ns is None:
            self._reject("waiting_for_clock")
            return
        reason = self._runner.set_input(ns * 1e-9, msg.data)
        if reason is not None:
            self._rejected(reason)

    def _on_joint_states(self, msg: JointState) -> None:
        self._received["joint_states"] += 1
        self._win_received += 1
        if not self._enabled:
            self._dropped_disabled += 1
            return
        stamp = msg.header.stamp
        sim = self._clock.ros_time_is_active
        if stamp.sec == 0 and stamp.nanosec == 0 and not sim:
            self._reject("zero_stamp")
            return
        sample = joint_state_sample(msg, self._runner.settings)
        if sample.__class__ is str:
            self._reject(sample)
            return
        t, y, u = sample
        ns = self._now_ns()  # None under sim time before the first /clock: no future check
        if ns is not None and t - ns * 1e-9 > self._future_tolerance:
            self._reject("future_stamp")
            return
        self._last_stamp = t
        if u is not None:
            reason = self._runner.set_input(t, u)
            if reason is not None:  # counted by the runner; never pair y with a bad u
                self._rejected(reason)
                return
        out = self._runner.process(t, y)
        if out.__class__ is str:
            self._rejected(out)
            return
        self._publish(out, stamp.sec, stamp.nanosec)

    def _publish(self, out, sec: int, nanosec: int) -> None:
        """Publish one Output; every message carries the measurement time (never now())."""
        m = self._est_msg
        m.data = array.array("d", out.estimate.tobytes())
        self._pub_est.publish(m)
        conv = out.convergence
        if not np.isfinite(conv).all():  # guaranteed_time = inf: 'no guarantee' is -1.0
            conv = np.where(np.isfinite(conv), conv, -1.0)
        c = self._conv_msg
        c.data = array.array("d", conv.tobytes())
        self._pub_conv.publish(c)
        if out.unknown_input is not None:
            if self._pub_ui is None:  # an observer that did not declare it
                self._pub_ui = self.create_publisher(Float64MultiArray, "~/unknown_input_estimate", 10)
            ui = self._ui_msg
            ui.data = array.array("d", np.asarray(out.unknown_input, dtype=float).tobytes())
            self._pub_ui.publish(ui)
        if self._pub_js is not None and out.joint_state is not None:
            js = self._js_msg
            js.header.stamp.sec = sec
            js.header.stamp.nanosec = nanosec
            js.name, js.position, js.velocity, js.effort = out.joint_state
            self._pub_js.publish(js)
        self._published += 1
        self._win_published += 1

    # --------------------------------------------------------------- services
    def _on_reset(self, request, response):
        self._runner.reset("service")
        response.success = True
        response.message = (f"observer restarted at the next sample "
                            f"(restarts so far: {sum(self._runner.resets.values())})")
        self.get_logger().info("reset requested: " + response.message)
        return response

    def _on_enable(self, request, response):
        was = self._enabled
        self._enabled = bool(request.data)
        if self._enabled and not was:
            self._runner.reset("enable")
        response.success = True
        response.message = ("enabled" if self._enabled else
                            "disabled: samples are dropped (counted as 'disabled') until enabled")
        self.get_logger().info(response.message)
        return response

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        runner = self._runner
        ns = self._now_ns()
        now = None if ns is None else ns * 1e-9
        st = runner.status(now)
        mono = time.monotonic()
        span = mono - self._win_steady
        pub_rate = self._win_published / span if span > 0 else 0.0
        in_rate = self._win_received / span if span > 0 else 0.0
        self._win_steady, self._win_published, self._win_received = mono, 0, 0
        level, message = st.level, st.message
        values = list(st.values)
        values += [
            ("enabled", str(self._enabled).lower()),
            ("source", runner.settings["source"]),
            ("messages received: measured_output", str(self._received["measured_output"])),
            ("messages received: input", str(self._received["input"])),
            ("messages received: joint_states", str(self._received["joint_states"])),
            ("estimates published", str(self._published)),
            ("input message rate (Hz, wall clock)", f"{in_rate:.1f}"),
            ("publish rate (Hz, wall clock)", f"{pub_rate:.1f}"),
            ("dropped: disabled", str(self._dropped_disabled)),
            ("sim time", str(self._clock.ros_time_is_active).lower()),
        ]
        if self._last_stamp is not None and now is not None:
            values.append(("last stamp age (s)", f"{now - self._last_stamp:.4f}"))
        if not self._enabled:
            level = max(level, 1)
            message = "disabled via ~/enable; samples dropped: " + message
        diag = DiagnosticArray()
        if ns is not None:
            diag.header.stamp.sec, diag.header.stamp.nanosec = ns // _NS, ns % _NS
        status = DiagnosticStatus(
            level=bytes([level]), name=f"{self.get_name()}: observer", message=message,
            hardware_id=runner.settings["diagnostics.hardware_id"] or runner.observer_type,
            values=[KeyValue(key=k, value=v) for k, v in values])
        diag.status = [status]
        self._pub_diag.publish(diag)

    # ------------------------------------------------------------- accessors
    @property
    def runner(self) -> Runner:
        """The runner (for tests and embedding)."""
        return self._runner

    def destroy_node(self) -> None:
        handle = getattr(self, "_jump_handle", None)
        if handle is not None:
            handle.unregister()
            self._jump_handle = None
        super().destroy_node()


# ------------------------------------------------------------------------ main
USAGE = """\
usage: fto-observer [-h] --ros-args --params-file PARAMS.yaml [-p NAME:=VALUE ...]
       ros2 run fto_ros observer_node --ros-args --params-file PARAMS.yaml

The fto_ros live observer node (default name: observer_node).  observer.type
chooses the observer; its parameters live under '<type>.' (see the README and
config/*.yaml).  Add -p use_sim_time:=true to run on a bag's /clock.

Subscribes   measured_output, input (Float64MultiArray; stamped on receipt)
             or joint_states (JointState; header stamp), per 'source'.
Publishes    ~/state_estimate, ~/convergence [{fields}]
             (-1 = no guarantee / unknown), ~/estimated_joint_states,
             ~/unknown_input_estimate, /diagnostics.
Services     ~/reset (std_srvs/Trigger), ~/enable (std_srvs/SetBool).
Exit status  0 on shutdown, 2 on a bad parameter (one log line names it).

observer types: {types}

runner parameters:
{params}
"""


def _usage() -> str:
    lines = []
    for p in SETTINGS:
        default = "required" if p.default is None else f"default {p.default!r}"
        lines.append(f"  {p.name} ({p.kind}, {default}): {p.description}")
    types = "; ".join(f"{name} ({cls.DESCRIPTION or cls.__doc__.splitlines()[0]})"
                      for name, cls in sorted(REGISTRY.items()))
    return USAGE.format(fields=", ".join(CONVERGENCE_FIELDS), types=types, params="\n".join(lines))


def _node_fqn(args: list[str]) -> str:
    """The node's fully qualified name after ``-r __node:=N`` / ``-r __ns:=NS`` remaps."""
    name, ns = NODE_NAME, ""
    for i, a in enumerate(args[:-1]):
        if a in ("-r", "--remap"):
            key, _, value = args[i + 1].partition(":=")
            if key == "__node" and value:
                name = value
            elif key == "__ns" and value:
                ns = value.strip("/")
    return f"{ns}/{name}" if ns else name


def _precheck_params_files(args: list[str]) -> None:
    """Check --params-file arguments before rcl parses them (its errors are opaque), with the
    reader of the replay tools: both refuse the same files with the same line."""
    in_ros = False
    for i, a in enumerate(args):
        if a == "--ros-args":
            in_ros = True
        elif a == "--":
            in_ros = False
        elif in_ros and a == "--params-file" and i + 1 < len(args):
            load_params_file(args[i + 1], _node_fqn(args))


def _error_line(node_name: str, text: str) -> None:
    rclpy.logging.get_logger(node_name).error(text)


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``fto-observer`` / ``observer_node``; ``argv`` without the program name.

    Returns the exit status (0, or 2 for a bad parameter / argument).
    """
    args = ["fto-observer"] + list(sys.argv[1:] if argv is None else argv)
    head = args[1:args.index("--ros-args")] if "--ros-args" in args else args[1:]
    if "-h" in head or "--help" in head:
        print(_usage())
        return 0
    try:
        _precheck_params_files(args)
    except ConfigError as exc:
        _error_line(NODE_NAME, f"fto_ros: bad parameter: {exc}")
        return 2
    try:
        user_args = rclpy.utilities.remove_ros_args(args)[1:]
    except Exception as exc:  # rcl's own argument errors
        _error_line(NODE_NAME, "fto_ros: bad arguments: " + " ".join(str(exc).split()))
        return 2
    if user_args:
        print(f"fto-observer: unexpected argument(s) {user_args}; parameters go after "
              "--ros-args (see --help)", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=args)
    except Exception as exc:  # rcl's argument / params-file errors
        _error_line(NODE_NAME, "fto_ros: cannot start: " + " ".join(str(exc).split()))
        return 2
    node = None
    code = 0
    try:
        node = ObserverNode()
        # the imports (sympy, scipy) leave ~1e5 long-lived objects: a full collection of
        # them takes ~50 ms, a latency spike at 1 kHz; nothing created so far is garbage
        gc.freeze()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except ConfigError as exc:
        _error_line(NODE_NAME, f"fto_ros: bad parameter: {exc}")
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
