"""``momentum_observer``: the generalized-momentum observer of an arm's external torques (De
Luca et al.), the baseline, on the actual stamps, with the same contact and collision
levels as external_torque (docs/external_torque.md)."""
from .adapter import MomentumObserverFamily

__all__ = ["MomentumObserverFamily"]
