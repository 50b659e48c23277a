"""The observability form through a constant map, shared by global_norm and high_gain.

Both observers run on z = (y, y', ..., y^(n-1)).  That is the plant's own state only when
the plant is already a chain (x0' = x1, ..., y = x0); otherwise the plant block finds
z = T x with T constant (plant/derive.py) and gives it as ``<family>.chain_map``.  The
observer then takes and publishes plant coordinates itself: its kernel maps an initial
estimate x0 to T x0 at a restart and publishes T^-1 z_hat, so the runner and a composition
(``track``) read plant coordinates off its state like any other family's.  ROS-free.
"""
from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.params import Param, matrix

PARAM = Param("chain_map", "double_array", [], "n x n matrix T (row-major): the observer runs "
              "on the observability form's coordinates z = T x and takes and publishes the "
              "plant's x (x0 -> T x0, x_hat = T^-1 z_hat); empty: z = x. The plant block "
              "derives it when the plant is a chain only through such a map")


def chain_map(cfg, n: int, prefix: str) -> np.ndarray | None:
    """T of ``cfg["chain_map"]`` (n x n, invertible), or None when not given."""
    if not cfg["chain_map"]:
        return None
    T = matrix(cfg, "chain_map", n, n, prefix)          # finite: Param refuses anything else
    if np.linalg.matrix_rank(T) < n:
        raise ConfigError(prefix + "chain_map", "must be an invertible matrix")
    return T


def write_map(c: np.ndarray, at: int, T: np.ndarray) -> None:
    """T, then T^-1, row-major into the kernel's constants from ``c[at]`` on."""
    m = T.shape[0]
    c[at:at + 2 * m * m] = np.concatenate((T.ravel(), np.linalg.inv(T).ravel()))
