"""The observer node's services: ``~/reset``, ``~/enable`` and ``~/set_state`` (a service
and a topic), mixed into ObserverCore (observer_core.py; ``self`` is the node).  In
per-joint mode ``~/set_state`` is joints_core.py's.
"""
from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState


class ObserverServices:
    """The services of ObserverCore (see the module doc)."""

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

    def _set_state(self, x) -> str | None:
        """Validate and take x; None or why it was refused (logged either way)."""
        reason = self._runner.set_state(x)
        names = self._runner.observer.state_names
        if reason is None:
            self.get_logger().info("set_state: the observer restarts from "
                                   + ", ".join(f"{n}={v:.6g}" for n, v in zip(names, x))
                                   + " at the next sample")
        else:
            self.get_logger().warning(f"set_state refused: {reason}")
        return reason

    def _on_set_state(self, request, response):
        """rcl_interfaces/SetParameters: one double_array parameter 'state' with every state
        in order, or one double parameter per state, named by the state's name.  Per-joint
        mode: joints_core.py."""
        if self._runner.joints:
            return self._on_set_state_joints(request, response)
        names = list(self._runner.observer.state_names)
        params = [Parameter.from_parameter_msg(p) for p in request.parameters]
        given = {p.name: p.value for p in params}
        state = given.get("state")
        if set(given) == {"state"} and hasattr(state, "__len__") and not isinstance(state, str):
            x, reason = list(state), None
        elif set(given) == set(names) and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                              for v in given.values()):
            x, reason = [float(given[n]) for n in names], None
        else:
            x, reason = None, (f"give one double_array parameter 'state' with {len(names)} values, "
                               f"or one double per state named {', '.join(names)}")
        if reason is None:
            reason = self._set_state(x)
        response.results = [SetParametersResult(successful=reason is None, reason=reason or "")
                            for _ in params or [None]]
        return response

    def _on_set_state_topic(self, msg: JointState) -> None:
        if self._runner.joints:
            self._on_set_state_topic_joints(msg)
            return
        names = list(self._runner.observer.state_names)
        if list(msg.name) != names or len(msg.position) != len(names):
            self.get_logger().warning(f"set_state refused: name must be {names} with one "
                                      f"position each, got {list(msg.name)}")
            return
        self._set_state(list(msg.position))
