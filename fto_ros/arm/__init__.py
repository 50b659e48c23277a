"""The arm room (ROS-free): an arm's rigid-body dynamics from its URDF, external joint
torques with a guaranteed time, collision detection.

- :mod:`.source`: the URDF text from a file or a string, its size bounded;
- :mod:`.urdf`: the XML read as physics and validated (masses, inertias, axes, friction),
  ``<mimic>`` joints, the default joint list;
- :mod:`.tree`: the kinematic tree as packed arrays, payloads;
- :mod:`.dynamics`: compiled rigid-body algorithms over them (CRBA, RNEA, Mdot, the
  Christoffel C, Jacobians);
- :mod:`.model`: :class:`RigidBodyModel`, the facade: M(q), C(q, v), g(q), friction,
  inverse and forward dynamics, momentum, Jacobians, passive and mimic joints, payloads;
- :mod:`.pin_reference`: the same terms from Pinocchio, the reference the tests hold the
  compiled ones to;
- :mod:`.steps`: the estimators' per-sample steps, pure functions over flat float64 arrays
  (the robust exact differentiator's velocity, the windowed momentum estimator, the
  generalized-momentum observer, finite differences);
- :mod:`.steps_compiled`: the window estimator's steps compiled (numba), used when numba is on;
- :mod:`.external_torque`: the adapters that own a design, restart it and call the model;
- :mod:`.collision`: thresholds from a false-alarm bound, detection with hysteresis.

docs/external_torque.md derives the estimator, its guaranteed time and its noise gain.
"""
from .model import RigidBodyModel, load_model

__all__ = ["RigidBodyModel", "load_model"]
