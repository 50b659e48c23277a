"""An observer that runs in other coordinates than the plant's and publishes the plant's.

The observability form of ``global_norm`` and ``high_gain`` (z_k = k-th derivative of y) is
the plant's own state only when the plant is already a chain; otherwise the derivation finds
z = T x (T constant) and the observer runs on z.  :func:`mapped_class` returns a subclass
that takes and gives plant coordinates: the estimate is T^-1 z_hat, an initial estimate
x0 (observer.initial_estimate) becomes T x0, and the states carry the plant's names.
ROS-free.
"""
from __future__ import annotations

import numpy as np

from ..observers.base import Observer


def mapped_class(cls: type[Observer], T: np.ndarray, names: list[str]) -> type[Observer]:
    """``cls`` publishing x = T^-1 z (see the module doc)."""
    T = np.array(T, dtype=float)
    Tinv = np.linalg.inv(T)

    class Mapped(cls):  # type: ignore[misc, valid-type]
        state_map = Tinv

        def __init__(self, cfg):
            super().__init__(cfg)
            self.state_names = list(names)

        def reset(self, t0, x0_hat=None):
            super().reset(t0, None if x0_hat is None else T @ np.asarray(x0_hat, dtype=float))

        @property
        def estimate(self):
            return Tinv @ np.asarray(super().estimate, dtype=float)

    Mapped.__name__ = Mapped.__qualname__ = f"Mapped{cls.__name__}"
    return Mapped
