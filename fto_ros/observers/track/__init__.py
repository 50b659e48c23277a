"""Acquire, then track: the design (design.py), the compiled composition (adapter.py,
kernel.py) and, for acquirers not yet compiled, the Python one (legacy.py)."""
from .adapter import TrackKernelObserver
from .design import ACQUIRERS, MODE_NAMES, TRACKERS, TrackObserver
from .legacy import LegacyTrackObserver

__all__ = ["ACQUIRERS", "MODE_NAMES", "TRACKERS", "LegacyTrackObserver", "TrackKernelObserver",
           "TrackObserver"]
