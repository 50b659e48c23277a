"""Acquire, then track: the design (design.py) and the compiled composition that runs it
(adapter.py, kernel.py)."""
from .adapter import TrackObserver
from .design import ACQUIRERS, MODE_NAMES, TRACKERS

__all__ = ["ACQUIRERS", "MODE_NAMES", "TRACKERS", "TrackObserver"]
