"""A bounded cache of per-step-size matrices inside a kernel's work array.

A table of ``slots`` entries of
``size`` floats each, keyed by the step in integer nanoseconds, filled in order and
replaced first-in first-out once full (so a stream with ever new step sizes never grows
memory, and what is cached depends only on the sequence of steps, never on timing).
It lives in a float64 work array at ``base``:

    [next slot, misses, filled, last hit, keys[slots], values[slots * size]]

``find`` returns the offset of a cached value (or -1), ``claim`` the offset where a new
one goes (counting a miss).  The cache is not part of an observer's state: a rejected
sample may leave an entry it built, which is what the next request for that step would
build again.
"""
from __future__ import annotations

import numpy as np

from .jit import jit

HEADER = 4


def cache_floats(slots: int, size: int) -> int:
    """Floats the cache of ``slots`` entries of ``size`` takes in a work array."""
    return HEADER + slots + slots * size


def cache_init(wk: np.ndarray, base: int, slots: int) -> None:
    """An empty cache at ``wk[base:]`` (Python, at build time)."""
    wk[base:base + HEADER] = (0.0, 0.0, 0.0, -1.0)
    wk[base + HEADER:base + HEADER + slots] = -1.0


@jit
def cache_find(wk, base, slots, size, key):
    keys = base + HEADER
    last = int(wk[base + 3])
    if last >= 0 and wk[keys + last] == key:
        return keys + slots + last * size
    filled = int(wk[base + 2])
    for i in range(filled):
        if wk[keys + i] == key:
            wk[base + 3] = i
            return keys + slots + i * size
    return -1


@jit
def cache_claim(wk, base, slots, size, key):
    keys = base + HEADER
    i = int(wk[base])
    wk[base] = (i + 1) % slots
    wk[base + 1] += 1.0
    if wk[base + 2] < slots:
        wk[base + 2] += 1.0
    wk[keys + i] = key
    wk[base + 3] = i
    return keys + slots + i * size


@jit
def cache_misses(wk, base):
    return int(wk[base + 1])


@jit
def cache_clear(wk, base, slots):
    """Forget every entry (the miss count stays), from compiled code."""
    wk[base] = 0.0
    wk[base + 2] = 0.0
    wk[base + 3] = -1.0
    for i in range(slots):
        wk[base + HEADER + i] = -1.0
