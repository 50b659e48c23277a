"""The constant-gain high-gain observer (global_norm's comparison): the adapter and its kernel."""
from .adapter import HighGainObserver

__all__ = ["HighGainObserver"]
