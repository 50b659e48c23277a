"""The single-delay observer (Mazenc & Malisoff 2022): the adapter (parameters, checks), its
design (design.py) and the kernels of its two forms (continuous.py, sampled.py, sharing
kernel.py)."""
from .adapter import Continuous, Sampled, SingleDelayObserver
from .design import design, noise_bound_constant, theorem2_mu

__all__ = ["Continuous", "Sampled", "SingleDelayObserver", "design",
           "noise_bound_constant", "theorem2_mu"]
