"""The newton_inversion observer (Possieri, Vidano & Novara 2020): the adapter (design) and
its kernel."""
from .adapter import NewtonInversionObserver, implicit_flow

__all__ = ["NewtonInversionObserver", "implicit_flow"]
