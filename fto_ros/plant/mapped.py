"""An observer that runs in other coordinates than the plant's and publishes the plant's.

The observability form of ``global_norm`` and ``high_gain`` (z_k = k-th derivative of y) is
the plant's own state only when the plant is already a chain; otherwise the derivation finds
z = T x (T constant) and the observer runs on z.  :func:`mapped_class` returns a subclass
that takes and gives plant coordinates: the estimate is T^-1 z_hat, an initial estimate
x0 (observer.initial_estimate) becomes T x0, and the states carry the plant's names.  The
map is the observer's own (``map_states``): its compiled kernel applies it, so the runner,
which reads the kernel's state, publishes plant coordinates.
ROS-free.
"""
from __future__ import annotations

import numpy as np

from ..observers.base import Observer


def mapped_class(cls: type[Observer], T: np.ndarray, names: list[str]) -> type[Observer]:
    """``cls`` publishing x = T^-1 z (see the module doc)."""
    T = np.array(T, dtype=float)

    class Mapped(cls):  # type: ignore[misc, valid-type]
        state_map = np.linalg.inv(T)

        def __init__(self, cfg):
            super().__init__(cfg)
            self.state_names = list(names)
            self.map_states(T)

    Mapped.__name__ = Mapped.__qualname__ = f"Mapped{cls.__name__}"
    return Mapped
