"""``external_torque``: an arm's external joint torques from its positions and efforts by the
windowed momentum identity, exact T after any change, on the actual stamps, with contact
and collision levels per joint (docs/external_torque.md)."""
from .adapter import ExternalTorqueObserver

__all__ = ["ExternalTorqueObserver"]
