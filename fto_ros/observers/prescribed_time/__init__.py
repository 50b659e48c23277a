"""The prescribed-time observer (Holloway & Krstic 2019): the adapter (parameters, design),
its kernel and the paper's design quantities."""
from .adapter import PrescribedTimeObserver
from .design import c_matrix, gain_coefficients, p_bar, p_bar_closed_form

__all__ = ["PrescribedTimeObserver", "c_matrix", "gain_coefficients", "p_bar", "p_bar_closed_form"]
