"""Observer families, one module each, and the registry ``observer.type`` -> class.

ROS-free: nothing here imports rclpy.
"""
from __future__ import annotations

from ..core.errors import short
from .base import ConfigError, Observer, Param
from .luenberger import LuenbergerObserver
from .prescribed_time import PrescribedTimeObserver
from .single_delay import SingleDelayObserver
from .global_norm import GlobalNormObserver
from .high_gain import HighGainObserver
from .hosm import HosmObserver
from .newton_inversion import NewtonInversionObserver
from .ekf import ExtendedKalmanFilter
from .track import TrackObserver
from .external_torque import ExternalTorqueObserver
from .momentum_observer import MomentumObserverFamily

REGISTRY: dict[str, type[Observer]] = {
    cls.TYPE: cls for cls in (NewtonInversionObserver, SingleDelayObserver, PrescribedTimeObserver, LuenbergerObserver, HosmObserver)
}
REGISTRY.update({cls.TYPE: cls for cls in (GlobalNormObserver, HighGainObserver)})
REGISTRY[ExtendedKalmanFilter.TYPE] = ExtendedKalmanFilter
REGISTRY[TrackObserver.TYPE] = TrackObserver
REGISTRY[ExternalTorqueObserver.TYPE] = ExternalTorqueObserver
REGISTRY[MomentumObserverFamily.TYPE] = MomentumObserverFamily


def observer_class(type_name: str) -> type[Observer]:
    """The class registered as ``type_name``, or ConfigError listing the known ones."""
    if not isinstance(type_name, str):
        raise ConfigError("observer.type", f"expected the name of an observer (one of "
                          f"{', '.join(sorted(REGISTRY))}), got {short(type_name)}")
    try:
        return REGISTRY[type_name]
    except KeyError:
        raise ConfigError("observer.type", f"unknown observer {short(type_name)}; known: "
                          + ", ".join(sorted(REGISTRY))) from None


__all__ = ["REGISTRY", "ConfigError", "Observer", "Param", "observer_class"]
