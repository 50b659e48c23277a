"""The model-free joint velocity baseline: a Kalman filter on an integrator chain per output
(the adapter, its kernel and the bandwidth design)."""
from .adapter import JointKalmanFilter

__all__ = ["JointKalmanFilter"]
