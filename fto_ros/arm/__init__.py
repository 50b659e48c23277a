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
- :mod:`.window`: the windowed momentum estimator's compiled numerics on the actual sample
  instants (the kernel's quadrature weights on any node spacing, centred velocities, the
  encoder-noise residual);
- :mod:`.detect`: contact and collision levels per joint and the calibration against the
  encoder's noise, compiled, inside an estimator's state;
- :mod:`.collision`: the threshold of a false-alarm bound, the guaranteed detection time.

The estimators themselves are observer families run by the runner (observers/
external_torque, observers/momentum_observer); docs/external_torque.md derives them.
"""
from .model import RigidBodyModel, load_model

__all__ = ["RigidBodyModel", "load_model"]
