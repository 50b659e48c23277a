"""The observer as a managed (lifecycle) node: ``fto-observer-managed`` (also ``ros2 run
fto_ros managed_observer_node``), driven through the ``lifecycle_msgs`` services.

- configure: declare and validate the parameters and build the observer (a bad
  parameter fails the transition, logged with the parameter's name; the node stays
  unconfigured and can be configured again after the parameter is fixed);
- activate: subscriptions, outputs, services and /diagnostics on;
- deactivate: all of them off, the observer's state kept (activate goes on from it);
- cleanup: the observer dropped (back to unconfigured);
- shutdown: everything off.

``autostart: true`` (a parameter) configures and activates at start-up, as a launch
file's lifecycle manager would.  The plain node (``observer_node.py``) stays the default.
"""
from __future__ import annotations

import sys

from .entry import NODE_NAME, run
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from ..core.errors import ConfigError  # noqa: E402
from .observer_core import ObserverCore  # noqa: E402


class ManagedObserverNode(ObserverCore, LifecycleNode):
    """The observer node under lifecycle management (see the module docstring)."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs):
        kwargs.setdefault("allow_undeclared_parameters", False)
        kwargs.setdefault("automatically_declare_parameters_from_overrides", False)
        super().__init__(node_name, **kwargs)
        # rclpy (7.1.6, ros2/rclpy#1209) raises "Transition is not registered" out of the
        # ~/change_state service for a transition id the current state does not have, and the
        # exception ends the node: such requests are refused here, with a log line
        self._rclpy_change_state = self._service_change_state.callback
        self._service_change_state.callback = self._on_change_state
        raw = self._parameter_overrides.get("autostart")
        autostart = raw is not None and raw.type_ == Parameter.Type.BOOL and bool(raw.value)
        if autostart:
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ConfigError("autostart", "the configure transition failed (the log names "
                                  "the parameter)")
            self.trigger_activate()

    def _on_change_state(self, request, response):
        """~/change_state: a transition the current state has goes to rclpy; any other is
        refused (success false) with a log line naming the ones it has."""
        transition = request.transition
        _, state = self._state_machine.current_state
        have = [(t[0], t[1]) for t in self._state_machine.available_transitions]
        if not any((transition.label == label) if transition.label else (transition.id == tid)
                   for tid, label in have):
            asked = f"'{transition.label}'" if transition.label else f"id {transition.id}"
            self.get_logger().warning(
                f"lifecycle: transition {asked} refused in state '{state}'; it has "
                + (", ".join(f"'{label}' (id {tid})" for tid, label in have) or "none"))
            response.success = False
            return response
        return self._rclpy_change_state(request, response)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.configure()
        except ConfigError as exc:
            self._runner = None
            self.get_logger().error(f"fto_ros: bad parameter: {exc}")
            return TransitionCallbackReturn.FAILURE
        except Exception as exc:  # noqa: BLE001  an observer that cannot be built: stay unconfigured
            self._runner = None
            self.get_logger().error(f"fto_ros: cannot build the observer: {type(exc).__name__}: "
                                    + " ".join(str(exc).split())[:300])
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.open()
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.close()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._entities is not None:
            self.close()
        self._runner = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._entities is not None:
            self.close()
        self._runner = None
        return TransitionCallbackReturn.SUCCESS


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``fto-observer-managed`` / ``managed_observer_node``."""
    return run(ManagedObserverNode, "fto-observer-managed", "managed_observer_node", managed=True,
               argv=argv)


if __name__ == "__main__":
    sys.exit(main())
