"""The continuous-discrete extended Kalman filter: the adapter (model, noise, restart) and
its kernel."""
from .adapter import MAX_SUBSTEPS, ExtendedKalmanFilter

__all__ = ["ExtendedKalmanFilter", "MAX_SUBSTEPS"]
