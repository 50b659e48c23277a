"""``arm_kalman``: an arm's joint velocities by a Kalman filter on its URDF's rigid-body
model, with a disturbance torque per joint (docs/arm.md)."""
from .adapter import ArmKalmanFilter

__all__ = ["ArmKalmanFilter"]
