"""What makes an rclpy node an fto_ros observer: mixed into the plain node and the
managed (lifecycle) node, so both behave the same on their topics.

Everything numerical happens in :class:`fto_ros.runner.Runner`, the same code the
offline replay runs; this mixin only

- declares the parameters (``parameters.py``), builds the runner and chooses the source
  once (``configure``; runner/sources/: the input mode's topics, intake and output plan);
- opens and closes the node's entities (``open``/``close``): a raw subscription per topic
  of the source, the publisher of its plan (``publisher.py``), services, the /diagnostics
  timer and the clock jump callback;
- per message (``_on_payload``, the same for every mode): the topic's owner
  (topic_owner.py), the source's rows of the payload (its decoding and intake checks; a
  Float64MultiArray stamped with the node clock at its receipt, ``receipt_clock.py``, a
  JointState with its header stamp, checked against the wall clock), the old timeline
  after a clock jump, ``Runner.process_rows``, and the plan's outputs of the joints with
  one, stamped with the measurement time;
- offers ``~/reset``, ``~/enable`` and ``~/set_state`` (service and topic;
  observer_services.py) and restarts the observer when the ROS clock jumps back (bag
  loop, sim restart).
"""
from __future__ import annotations

import time

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.clock import Clock, ClockType, JumpThreshold
from rclpy.duration import Duration
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from ..core.errors import ConfigError, DecodeError
from ..runner import loop as L
from ..runner.runner import HELD, Runner, reason
from ..runner.sources import make_source
from .arm_core import ArmCore
from .fast_io import message_info_callback
from .publisher import MESSAGE_CLASS, REFRESH_S, Publisher
from .parameters import NodeParameters, check_declared
from .receipt_clock import ReceiptClock
from .observer_services import ObserverServices
from .topic_owner import SECOND_SOURCE, SOURCE_CHANGE, TopicOwner

_NS = 1_000_000_000
#: how often at most a summary of rejected samples is logged (s)
LOG_THROTTLE_S = 5.0
#: parameters only the outputs use: changed at run time without restarting the observer
OUTPUT_ONLY = frozenset({"output.frame_id"})
#: the node's own services keep every request and every response (ROS's default for services
#: keeps the last 10 of each: of a burst of 1000 ~/reset calls, 20 were answered)
SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)


def rclpy_fallback(payload: bytes, msgtype: str, key: str):
    """The node's reference deserialiser for what the numpy codec does not take (big endian,
    XCDR2); DecodeError naming rclpy's error for what it refuses too."""
    try:
        return deserialize_message(payload, MESSAGE_CLASS[msgtype])
    except Exception as exc:  # rclpy raises RuntimeError / its own types; never into the executor
        raise DecodeError(f"{type(exc).__name__}") from None


class ObserverCore(ArmCore, ObserverServices):
    """The observer behaviour of a node (``self`` is an rclpy Node or LifecycleNode)."""

    _runner: Runner | None = None
    _entities: list | None = None

    # ------------------------------------------------------------- life cycle
    def configure(self) -> None:
        """Declare and validate the parameters and build the observer (no I/O yet; an arm
        family without its URDF waits for the robot_description topic: arm_core.py).
        ConfigError (naming the parameter) for an unusable configuration."""
        self._params = NodeParameters(self)
        self._params.declare()
        flat = self._params.with_unknown_overrides()
        if not self._arm_waits(flat):
            self._configured(Runner(flat))

    def _configured(self, runner: Runner) -> None:
        self._runner = runner
        self._source = make_source(runner, rclpy_fallback)
        self._received = {"measured_output": 0, "input": 0, "joint_states": 0}
        self._published = 0
        self._dropped_disabled = 0
        self._enabled = True
        self._last_stamp: float | None = None
        self._old_timeline: float | None = None
        self._rejected_since_log = 0
        self._last_reject_log = 0.0
        self._win_steady = time.monotonic()
        self._win_published = self._win_received = 0
        self._apply_settings()
        if not getattr(self, "_param_callbacks", False):
            self.add_pre_set_parameters_callback(self._params_convert)
            self.add_on_set_parameters_callback(self._on_set_parameters)
            self._param_callbacks = True
        obs = self._runner.observer
        self.get_logger().info(
            f"{obs.TYPE} observer: {obs.n_states} states, {obs.n_outputs} output(s), "
            f"{obs.n_inputs} input(s); source '{self._runner.settings['source']}'"
            + (", sim time" if self.get_clock().ros_time_is_active else ""))
        # the start-up checks' figures (single_delay: tau, cond(S), noise gain, ...)
        self.get_logger().info("design: " + "; ".join(f"{k} = {v}" for k, v in obs.diagnostics().items()))

    def open(self) -> None:
        """Outputs, subscriptions, services, timers: the observer runs (an arm family
        waiting for its URDF: the robot_description subscription until it comes)."""
        self._entities = self._open_description() if self._waiting is not None else []
        if self._runner is not None:
            self._entities += self._open_observer()

    def _open_observer(self) -> list:
        runner, s = self._runner, self._runner.settings
        obs = runner.observer
        ent = []
        # subscriptions: sensor-data QoS (best effort, keep last qos.depth, volatile), overridable
        in_qos = QoSProfile(depth=s["qos.depth"], history=HistoryPolicy.KEEP_LAST,
                            reliability=ReliabilityPolicy.BEST_EFFORT,
                            durability=DurabilityPolicy.VOLATILE)

        self._owners: dict[str, TopicOwner] = {}
        self._lost_events: dict[str, int] = {}
        self._stamper = ReceiptClock(self)   # before the data subscriptions: first in a round
        self._refresh_sim_time()
        self._out = Publisher(self.create_publisher, self._source.plan)
        ent += self._out.publishers
        # in the source's order (inputs first: when u_k and y_k wait in the same executor
        # round, u_k must be stored before y_k is processed)
        for topic in self._source.topics:
            key = topic.key
            self._lost_events[key] = 0

            def lost(event, key=key):       # the middleware's count (transport losses only)
                self._lost_events[key] = event.total_count
            sub = self.create_subscription(
                MESSAGE_CLASS[topic.msgtype], s[topic.setting],
                message_info_callback(lambda payload, info, key=key: self._on_payload(
                    key, payload, info)), in_qos,
                qos_overriding_options=QoSOverridingOptions.with_default_policies(),
                event_callbacks=SubscriptionEventCallbacks(message_lost=lost,
                                                           use_default_callbacks=False),
                raw=True)
            name = sub.topic_name
            self._owners[key] = TopicOwner(lambda name=name: self.count_publishers(name),
                                           s["time.max_gap"], s["time.jump_threshold"])
            ent.append(sub)
        ent.append(self.create_subscription(JointState, "~/set_state", self._on_set_state_topic, 10))
        ent.append(self.create_service(Trigger, "~/reset", self._on_reset, qos_profile=SERVICE_QOS))
        ent.append(self.create_service(SetBool, "~/enable", self._on_enable, qos_profile=SERVICE_QOS))
        ent.append(self.create_service(SetParameters, "~/set_state", self._on_set_state,
                                       qos_profile=SERVICE_QOS))
        # /diagnostics and the output subscriber check on the steady clock: they keep going
        # when sim time stops
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        ent.append(self.create_timer(s["diagnostics.period"], self._publish_diagnostics,
                                     clock=steady))
        ent.append(self.create_timer(REFRESH_S, self._refresh, clock=steady))
        ent += self._open_arm()
        self._jump_handle = None
        self._arm_jump_callback()
        return ent

    def _refresh(self) -> None:
        """Every REFRESH_S: which outputs have subscribers, and whether sim time is on."""
        self._out.refresh()
        self._refresh_sim_time()

    def _refresh_sim_time(self) -> None:
        self._sim_time = self.get_clock().ros_time_is_active

    def close(self) -> None:
        """Destroy what ``open`` made: no inputs, no outputs; the observer's state is kept."""
        handle = getattr(self, "_jump_handle", None)
        if handle is not None:
            handle.unregister()
            self._jump_handle = None
        for e in self._entities or ():
            destroy = {"Publisher": self.destroy_publisher, "Subscription": self.destroy_subscription,
                       "Service": self.destroy_service, "Timer": self.destroy_timer}.get(type(e).__name__)
            if destroy is not None:
                destroy(e)
        self._entities = None

    # ------------------------------------------------------------- parameters
    def _apply_settings(self) -> None:
        """Cache the settings read per message."""
        s = self._runner.settings
        self._reset_on_jump = s["time.reset_on_jump"]
        self._jump_threshold = s["time.jump_threshold"]
        for tracker in getattr(self, "_owners", {}).values():
            tracker.set_limits(s["time.max_gap"], s["time.jump_threshold"])

    def _params_convert(self, params: list[Parameter]) -> list[Parameter]:
        return self._params.convert(params) if self._runner is not None else params

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        if self._runner is None:        # a managed node not configured: nothing to validate
            return SetParametersResult(successful=True)
        try:
            new = self._params.changed(params)
            if new is not None:
                diff = {k for k in new.keys() | self._params.flat.keys()
                        if new.get(k) != self._params.flat.get(k)}
                if diff and diff <= OUTPUT_ONLY:     # the outputs' business: no restart
                    return self._change_outputs(new, params)
                if self._arm_takes(diff):            # a payload: into the running estimator
                    return self._arm_payload(new, params)
                self._runner.reconfigure(new)
        except ConfigError as exc:
            return self._refuse_change(params, str(exc))
        except Exception as exc:  # noqa: BLE001  a change that cannot be built never kills the node
            return self._refuse_change(params, f"cannot build the observer: {type(exc).__name__}: "
                                               + " ".join(str(exc).split())[:300])
        if new is not None:
            self._params.flat = new
            old_threshold = self._jump_threshold
            self._apply_settings()
            if self._jump_threshold != old_threshold and self._entities is not None:
                self._arm_jump_callback()
            self.get_logger().info("parameters changed: "
                                   + ", ".join(f"{p.name}={p.value}" for p in params)
                                   + "; observer restarted")
        return SetParametersResult(successful=True)

    def _change_outputs(self, new: dict, params: list[Parameter]) -> SetParametersResult:
        """A change of what only the outputs use (output.frame_id): taken at once, the
        observer runs on.  The runner's settings hold it for outputs built later (activate)."""
        self._params.flat = new
        frame = new["output.frame_id"]
        self._runner.settings["output.frame_id"] = frame
        if self._entities is not None:
            self._out.set_frame(frame)
        self.get_logger().info("parameters changed: "
                               + ", ".join(f"{p.name}={p.value}" for p in params))
        return SetParametersResult(successful=True)

    def _refuse_change(self, params: list[Parameter], reason: str) -> SetParametersResult:
        """Refuse a parameter change: the old observer runs on; the reason is logged too."""
        self.get_logger().warning("parameter change refused ("
                                  + ", ".join(f"{p.name}={p.value}" for p in params)
                                  + f"): {reason}; the observer runs on unchanged")
        return SetParametersResult(successful=False, reason=reason)

    def _check_undeclared_parameters(self, parameter_list: list[Parameter]):
        # rclpy's own check, with the names in the message ("undeclared parameter(s): [...]")
        check_declared(self, parameter_list, super()._check_undeclared_parameters)

    # ------------------------------------------------------------------- time
    def _arm_jump_callback(self) -> None:
        if self._jump_handle is not None:
            self._jump_handle.unregister()
        ns = max(1, int(round(self._jump_threshold * 1e9)))
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(nanoseconds=-ns),
                          on_clock_change=False),
            post_callback=self._on_time_jump)

    def _on_time_jump(self, jump) -> None:
        """The ROS clock went backwards by more than time.jump_threshold."""
        if not self._reset_on_jump:
            return
        # The runner restarts by itself on a backward sample stamp (JointState stamps may
        # jump before /clock does); count one jump once.
        t_last = self._runner.last_sample_time()
        now = self.get_clock().now().nanoseconds * 1e-9
        if t_last is None or t_last <= now + self._jump_threshold:
            return
        self._runner.time_jump(now)
        # samples of the old timeline still in flight are stamped at about t_last and later
        self._old_timeline = t_last - self._jump_threshold
        self.get_logger().warning(
            f"ROS time jumped back by {-jump.delta.nanoseconds * 1e-9:.3f} s: observer restarted",
            throttle_duration_sec=LOG_THROTTLE_S)

    # --------------------------------------------------------------- samples
    def _from_old_timeline(self, t: float) -> bool:
        """After the ROS clock jumped back, until a sample of the new timeline arrives, a
        sample stamped on the old one (in flight at the jump) is rejected, counted as
        'stamp_before_time_jump': it must not start the restarted observer.  This, not a
        comparison with /clock (which may lag the data it is played with), is what keeps
        the two timelines apart on sim time."""
        if self._old_timeline is None:
            return False
        if t >= self._old_timeline:
            self._reject("stamp_before_time_jump")
            return True
        self._old_timeline = None
        return False

    def _reject(self, reason: str) -> None:
        """Count a rejection found by the node (not the runner) in the runner's counters."""
        self._runner.reject(reason)
        self._rejected(reason)

    def _rejected(self, reason: str) -> None:
        """Log rejected samples as a throttled summary, never one line per sample."""
        if reason is HELD:
            return
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

    def _from_owner(self, key: str, info: dict, t_ns: int) -> bool:
        """Whether a message on data topic ``key`` is to be used: its publisher owns the
        topic (topic_owner.py); a second source's is rejected and counted.  Disabled: dropped."""
        verdict = self._owners[key].check(info, t_ns)    # always: the losses stay exact
        if not self._enabled:
            if key != "input":
                self._dropped_disabled += 1
            return False
        if verdict is None:
            return True
        if verdict == SOURCE_CHANGE:
            self._runner.reset(SOURCE_CHANGE)
            self.get_logger().warning(
                f"{key}: its publisher was silent for time.max_gap with another one on the topic; "
                "the samples are now taken from the other one (observer restarted)")
            return True
        self._reject(SECOND_SOURCE if key != "input" else "input_" + SECOND_SOURCE)
        return False

    def _on_payload(self, key: str, payload: bytes, info: dict) -> None:
        """One message of the source's topic ``key`` (see the module doc)."""
        self._received[key] += 1
        if key != "input":
            self._win_received += 1
        recv = self._stamper.receipt_ns(info)
        # a header stamp is checked against the wall clock, which cannot lag the data; on sim
        # time not at all (/clock comes from the player of the data): the runner's rules
        clock = None if self._sim_time else np.array([time.time_ns() * 1e-9])
        rows = self._source.rows(key, (payload,), np.array([-1 if recv is None else recv]),
                                 np.array([info.get("source_timestamp", 0)]), clock)
        if not self._from_owner(key, info, int(rows.owner_ns[0])):
            return
        for why in rows.py_reasons.values():        # refused before the runner, by name
            if why.startswith("undecodable"):
                self.get_logger().warning(f"{key}: message refused: {why}: "
                                          f"{self._source.last_undecodable}",
                                          throttle_duration_sec=LOG_THROTTLE_S)
            self._reject(why)
            return
        s = int(rows.srow[0])
        if s >= 0 and not rows.whole[0]:
            t = float(rows.t[s])
            if self._from_old_timeline(t):
                return
            self._last_stamp = t
        status, x, ui, conv = self._runner.process_rows(rows.kind, rows.t, rows.values, rows.pre)
        last = status[s] if s >= 0 else status[0]
        ok = last == L.OUTPUT
        if not ok.all():
            i = int(rows.irow[0])
            for j in np.flatnonzero(~ok):
                st = int(last[j])
                why = reason(int(status[i, j])) if st == L.SKIPPED and i >= 0 else reason(st)
                if why is not None:
                    self._rejected(why)
        if s >= 0 and ok.any():
            ns = int(rows.stamp_ns[0])
            self._out.publish(ok, x[s], ui[s], conv[s], ns // _NS, ns % _NS)
            self._published += 1
            self._win_published += 1

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        runner = self._runner
        ns = self._stamper.now_ns()
        now = None if ns is None else ns * 1e-9
        mono = time.monotonic()
        span = mono - self._win_steady
        pub_rate = self._win_published / span if span > 0 else 0.0
        in_rate = self._win_received / span if span > 0 else 0.0
        self._win_steady, self._win_published, self._win_received = mono, 0, 0
        values = [
            ("enabled", str(self._enabled).lower()),
            ("source", runner.settings["source"]),
            ("messages received: measured_output", str(self._received["measured_output"])),
            ("messages received: input", str(self._received["input"])),
            ("messages received: joint_states", str(self._received["joint_states"])),
            ("estimates published", str(self._published)),
            ("input message rate (Hz, wall clock)", f"{in_rate:.1f}"),
        ]
        # per data topic: its publishers, the owner's messages that never got here (sequence
        # gaps: dropped in transport or overwritten in the queue), and the middleware's own
        # message-lost count (transport losses only)
        for key, tracker in self._owners.items():
            values += [(f"publishers: {key}", str(tracker.publishers())),
                       (f"messages lost: {key}", str(tracker.lost)),
                       (f"messages lost (middleware event): {key}", str(self._lost_events[key]))]
        values += [
            ("publish rate (Hz, wall clock)", f"{pub_rate:.1f}"),
            ("dropped: disabled", str(self._dropped_disabled)),
            ("sim time", str(self.get_clock().ros_time_is_active).lower()),
        ]
        if self._last_stamp is not None and now is not None:
            values.append(("last stamp age (s)", f"{now - self._last_stamp:.4f}"))
        if self._source.by_fallback:
            values.append(("messages decoded by rclpy (not numpy)", str(self._source.by_fallback)))
        disabled = "" if self._enabled else "disabled via ~/enable; samples dropped: "
        statuses = runner.statuses(now)
        summary, each = statuses[0], statuses[1:] or statuses[:len(runner.joints)]
        message = summary.message
        if len(each) == 1:                  # one joint: its name says whose status it is
            message = f"{runner.joints[0]}: {message}"
        hw = runner.settings["diagnostics.hardware_id"] or runner.observer_type
        self._out.publish_statuses(ns, [(
            max(summary.level, 0 if self._enabled else 1), f"{self.get_name()}: observer",
            disabled + message, hw, list(summary.values) + values)] + [
            (st.level, f"{self.get_name()}: joint {name}", st.message, hw, st.values)
            for name, st in zip(runner.joints, each)] + self._arm_statuses(hw))

    # ------------------------------------------------------------- accessors
    def executor_kind(self) -> str:
        """The executor to spin this node with (``node.executor``; 'single' before the
        parameters are declared, i.e. a managed node not configured yet)."""
        if self._runner is None:
            return "single"
        kind = self._runner.settings["node.executor"]
        return self._source.executor if kind == "auto" else kind

    @property
    def runner(self) -> Runner:
        """The runner (for tests and embedding)."""
        return self._runner

    def destroy_node(self) -> None:
        if self._entities is not None:
            self.close()
        super().destroy_node()
