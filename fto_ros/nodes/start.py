"""The console scripts of the nodes: Ctrl-C while a node is still importing exits quietly.

Importing a node (rclpy, scipy, sympy, numba's cached kernels) takes seconds, minutes on a
loaded machine with a cold compile cache; a Ctrl-C then would print a KeyboardInterrupt
traceback from deep inside an import.  These entry points exit with 130 instead, then
import the node and hand SIGINT back to Python before rclpy takes it over (entry.run).
"""
from __future__ import annotations

import os
import signal


def _quiet(_signum, _frame):
    os._exit(130)


def _start(module: str) -> int:
    signal.signal(signal.SIGINT, _quiet)
    import importlib
    main = importlib.import_module(module).main
    signal.signal(signal.SIGINT, signal.default_int_handler)
    return main()


def observer() -> int:
    return _start("fto_ros.nodes.observer_node")


def managed() -> int:
    return _start("fto_ros.nodes.managed_node")


def external_torque() -> int:
    """``fto-external-torque``: the observer node with the arm's defaults: node name
    external_torque_node (unless remapped) and observer.type external_torque (unless a
    params file or -p gives one); docs/external_torque.md, "The node"."""
    import sys
    signal.signal(signal.SIGINT, _quiet)
    from .arm_start import arm_arguments
    from .observer_node import main
    signal.signal(signal.SIGINT, signal.default_int_handler)
    return main(arm_arguments(sys.argv[1:]))


def player() -> int:
    return _start("fto_ros.nodes.player")
