"""The Luenberger / steady-state Kalman baseline: the adapter (design) and its kernel."""
from .adapter import LuenbergerObserver

__all__ = ["LuenbergerObserver"]
