"""The live observer node: ROS topics <-> the ROS-free runner.

``fto-observer --ros-args --params-file config/X.yaml [-p name:=value ...]``
(also ``ros2 run fto_ros observer_node``).  The managed (lifecycle) variant is
``managed_node.py``; both get their behaviour from ``observer_core.ObserverCore``.

Speed (benchmarks/bench_live_node.py): one OpenBLAS thread, no QoS event handlers on
the node's own entities, and ``gc.freeze()`` after start-up (no 50 ms full collections
of the ~1e5 objects sympy/scipy leave) keep 1 kHz at about half a core.
"""
from __future__ import annotations

import sys

from .entry import NODE_NAME, run
from rclpy.node import Node  # noqa: E402

from .observer_core import ObserverCore  # noqa: E402


class ObserverNode(ObserverCore, Node):
    """A guaranteed-time state observer on live topics (see observer_core)."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs):
        kwargs.setdefault("allow_undeclared_parameters", False)
        kwargs.setdefault("automatically_declare_parameters_from_overrides", False)
        super().__init__(node_name, **kwargs)
        try:
            self.configure()
            self.open()
        except BaseException:
            self.destroy_node()
            raise


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``fto-observer`` / ``observer_node``; ``argv`` without the program name."""
    return run(ObserverNode, "fto-observer", "observer_node", managed=False, argv=argv)


if __name__ == "__main__":
    sys.exit(main())
