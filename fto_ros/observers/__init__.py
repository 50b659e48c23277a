"""Observer families, one module each, and the registry ``observer.type`` -> class with
:func:`make`, which builds every observer (registry.py).

ROS-free: nothing here imports rclpy.
"""
from __future__ import annotations

from .base import ConfigError, Observer, Param
from .registry import REGISTRY, make, observer_class

__all__ = ["REGISTRY", "ConfigError", "Observer", "Param", "make", "observer_class"]
