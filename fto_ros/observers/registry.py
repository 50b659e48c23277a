"""The registry ``observer.type`` -> observer class, and :func:`make`, the one place an
observer is built.

Every registered class is the class that runs (no constructor picks another): a family
whose forms differ (single_delay's continuous and sampled measurement) decides inside its
constructor, a plant whose observability form is reached through a map gives the map as a
parameter (observers/chain_map.py), and a composition (``track``) is handed :func:`make` to
build its children from their (type name, typed config).  ROS-free.
"""
from __future__ import annotations

from typing import Any, Mapping

from ..core.errors import ConfigError, short
from .base import Observer
from .ekf import ExtendedKalmanFilter
from .external_torque import ExternalTorqueObserver
from .global_norm import GlobalNormObserver
from .high_gain import HighGainObserver
from .hosm import HosmObserver
from .joint_kalman import JointKalmanFilter
from .luenberger import LuenbergerObserver
from .momentum_observer import MomentumObserverFamily
from .newton_inversion import NewtonInversionObserver
from .prescribed_time import PrescribedTimeObserver
from .single_delay import SingleDelayObserver
from .track import TrackObserver

REGISTRY: dict[str, type[Observer]] = {cls.TYPE: cls for cls in (
    NewtonInversionObserver, SingleDelayObserver, PrescribedTimeObserver, LuenbergerObserver,
    HosmObserver, GlobalNormObserver, HighGainObserver, ExtendedKalmanFilter, JointKalmanFilter,
    TrackObserver, ExternalTorqueObserver, MomentumObserverFamily)}


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


def make(type_name: str, cfg: Mapping[str, Any]) -> Observer:
    """The observer ``type_name`` built from its typed config (``core.params.resolve`` of its
    PARAMS; a composition's config also holds, per child role, the child's
    ``(type name, typed config)`` under ``<role>_observer``, and the composition builds its
    children with this function).  ConfigError for a configuration the family refuses."""
    cls = observer_class(type_name)
    if cls.CHILD_ROLES:
        return cls(cfg, make)
    return cls(cfg)
