"""Rigid-body arms from their URDF (ROS-free): the dynamics (Pinocchio), external joint
torques with a guaranteed time, collision detection.

- :mod:`.model`: :class:`RigidBodyModel`, M(q), C(q, v) v, C^T v, g(q), friction, inverse
  and forward dynamics, momentum, link Jacobians, from a URDF file or string;
- :mod:`.steps`: the estimators' per-sample steps, pure functions over flat float64 arrays
  (the robust exact differentiator's velocity, the windowed momentum estimator, the
  generalized-momentum observer, finite differences);
- :mod:`.steps_compiled`: the window estimator's steps compiled (numba), used when numba is on;
- :mod:`.external_torque`: the adapters that own a design, restart it and call Pinocchio;
- :mod:`.collision`: thresholds from a false-alarm bound, detection with hysteresis.

docs/external_torque.md derives the estimator, its guaranteed time and its noise gain.
"""
from .model import RigidBodyModel, load_model

__all__ = ["RigidBodyModel", "load_model"]
