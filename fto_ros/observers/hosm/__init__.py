"""The hosm observer (Fridman, Levant & Davila 2007): the adapter (design) and its kernel."""
from .adapter import HosmObserver

__all__ = ["HosmObserver"]
