"""Offline replay of recorded bags through the runner (no rclpy, no DDS).

``replay(bag, params, out)`` runs a bag through the same runner code path as
the live node and writes the outputs as a bag plus ``metrics.json`` and
``replay.png``; ``fto-replay`` is its command line (:mod:`fto_ros.replay.cli`).
"""
from __future__ import annotations

from .replay import DEFAULT_NODE_NAME, DEFAULT_TOLERANCE, ReplayError, replay

__all__ = ["DEFAULT_NODE_NAME", "DEFAULT_TOLERANCE", "ReplayError", "replay"]
