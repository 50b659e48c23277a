"""The observer node's services: ``~/reset``, ``~/enable`` and ``~/set_state`` (a service
and a topic), mixed into ObserverCore (observer_core.py; ``self`` is the node).
``~/set_state`` sets the rows the source's output plan names (its ``targets``: the whole
plant, or each joint), as ``~/state_estimate_stamped`` names their states.
"""
from __future__ import annotations

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from ..core.params import check_vector


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

    def _set_states(self, given: dict) -> str | None:
        """Restart the rows named in ``given`` (the plan's target key -> that row's states)
        from them; None or why not (nothing is taken then; logged either way)."""
        runner = self._runner
        keys = [key for key, _ in self._source.plan.targets]
        n = runner.observer.n_states
        unknown = [k for k in given if k not in keys]
        why = (f"unknown name(s) {unknown}; set one of {keys}" if unknown else
               "name at least one of " + ", ".join(keys) if not given else None)
        limit = runner.settings["limits.estimate"]
        for key, x in given.items():       # every row checked before any is taken
            bad = None if why is not None else check_vector(x, n, "state")
            if bad is not None:            # the runner's reasons (Runner.set_state)
                why = f"{key}: {bad} ({len(x)} value(s) for {n} state(s), finite)"
            elif why is None and not all(abs(v) <= limit for v in x):
                why = f"{key}: state_implausible (beyond limits.estimate {limit:g})"
        if why is None:
            for key, x in given.items():
                runner.set_state(x, keys.index(key))
            self.get_logger().info("set_state: the observer restarts from " + "; ".join(
                f"{key}: " + ", ".join(f"{v:.6g}" for v in x) for key, x in given.items())
                + " at the next sample")
        else:
            self.get_logger().warning(f"set_state refused: {why}")
        return why

    def _on_set_state(self, request, response):
        """rcl_interfaces/SetParameters: per row of the plan's targets, one double_array
        parameter named by its key (the whole plant: 'state'; a joint: its name) with every
        state in order, or one double per state named by its label (the whole plant: the
        state's name; a joint: 'joint/state')."""
        params = [Parameter.from_parameter_msg(p) for p in request.parameters]
        given, why = _targets(self._source.plan.targets,
                              {p.name: p.value for p in params}), None
        if isinstance(given, str):
            given, why = None, given
        else:
            why = self._set_states(given)
        response.results = [SetParametersResult(successful=why is None, reason=why or "")
                            for _ in params or [None]]
        return response

    def _on_set_state_topic(self, msg: JointState) -> None:
        """A JointState named as ~/state_estimate_stamped publishes the states (values in
        ``position``): every state of each row it sets."""
        if len(msg.position) != len(msg.name):
            self.get_logger().warning("set_state refused: position must have one value per name")
            return
        given = _targets(self._source.plan.targets, dict(zip(msg.name, msg.position)),
                         arrays=False)
        if isinstance(given, str):
            self.get_logger().warning(f"set_state refused: {given}")
        else:
            self._set_states(given)


def _targets(targets, values: dict, arrays: bool = True) -> dict | str:
    """{row key: its states} of the named ``values`` (a row key -> every state of it, when
    ``arrays``; a state label -> that state's value), or why they do not name whole rows."""
    given, used = {}, set()
    for key, labels in targets:
        v = values.get(key) if arrays else None
        if v is not None:
            if not hasattr(v, "__len__") or isinstance(v, str):
                return f"{key}: give a double_array with its {len(labels)} states"
            given[key] = [float(a) for a in v]
            used.add(key)
        elif any(lb in values for lb in labels):
            if not all(lb in values for lb in labels):
                return f"{key}: name every state as {', '.join(labels)}"
            if not all(isinstance(values[lb], (int, float)) and not isinstance(values[lb], bool)
                       for lb in labels):
                return f"{key}: give one double per state"
            given[key] = [float(values[lb]) for lb in labels]
            used.update(labels)
    extra = [k for k in values if k not in used]
    if extra:
        keys = [key for key, _ in targets]
        return f"names other than the states of {', '.join(keys)}: {extra}"
    return given
