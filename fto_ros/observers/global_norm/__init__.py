"""The global observer with a state-norm estimator (Astolfi & Praly 2005): the adapter, its
kernel, the exact companion-matrix steps it shares with high_gain, and the gains of eq. (79)."""
from .adapter import GlobalNormObserver
from .companion import expm_of as companion_expm, step_of as companion_step
from .design import gains_numeric

__all__ = ["GlobalNormObserver", "companion_expm", "companion_step", "gains_numeric"]
