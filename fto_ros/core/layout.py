"""Where the blocks of a compiled kernel's flat arrays go: a builder of offsets.

A kernel's state, constants and work memory are flat float64 arrays (observers/kernel.py);
an adapter lays them out once, block by block, and hands the kernel the offsets.  ROS-free.
"""
from __future__ import annotations

import numpy as np


class Layout:
    """The blocks of one flat array, in the order taken (``head`` leading floats first)."""

    def __init__(self, head: int = 0):
        self.data: list[float] = [0.0] * head

    @property
    def size(self) -> int:
        return len(self.data)

    def take(self, size: int) -> int:
        """Reserve ``size`` floats (zeros); their offset."""
        self.data += [0.0] * int(size)
        return len(self.data) - int(size)

    def put(self, values) -> int:
        """Append ``values`` (flattened, row-major); their offset."""
        flat = np.ascontiguousarray(values, dtype=float).ravel().tolist()
        self.data += flat
        return len(self.data) - len(flat)

    def array(self) -> np.ndarray:
        return np.array(self.data, dtype=float)
