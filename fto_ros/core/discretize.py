"""Exact sampled-data steps of linear systems ``x' = A x + B w(t)``.

Between two samples the input ``w`` is either held (ZOH) or linear (FOH).  The
step matrices come from one matrix exponential of an augmented matrix (Van
Loan's construction), exact for any step size; they are cached per step size
(integer nanoseconds), so a fixed-rate stream costs one ``expm`` in all.

    FOH:  x_{k+1} = Phi x_k + G0 w_k + G1 w_{k+1}
    ZOH:  x_{k+1} = Phi x_k + G0 w_k            (G1 = 0)

Plain Euler at the sample rate loses the estimate on stiff or unstable plants;
this does not.
"""
from __future__ import annotations

from collections import OrderedDict

import numpy as np
from scipy.linalg import expm

#: model time runs on this grid (s): an observer's clock counts integer quanta since its
#: (re)start (the base class in observers/base.py owns it), so the steps of a live stream
#: stamped on receipt fall on a few hundred cached step sizes instead of one new matrix
#: exponential per sample, and the model time never drifts from the stamps (float seconds
#: near 1.7e9 resolve only 0.24 us); bag stamps on a ms grid are not changed at all.
STEP_QUANTUM = 1e-6

#: the most sub-steps any observer takes over one interval (differentiator sub-steps, the
#: sampled single_delay predictor): the work per sample is bounded, longer intervals are
#: gaps the runner restarts the observer at
MAX_SUBSTEPS = 1000

#: ExactStepper.step composes new step sizes from cached power-of-two ones after this many
#: distinct sizes
COMPOSE_AFTER = 64


def quanta(dt: float) -> int:
    """dt (s) as a whole number of STEP_QUANTUM."""
    return round(dt / STEP_QUANTUM)


def quantized_step(h: float) -> float:
    """h rounded to the STEP_QUANTUM grid (0.0 for steps under half a quantum)."""
    return quanta(h) * STEP_QUANTUM


class StepCache:
    """``build(h)`` per step size, cached: the one step-size cache every observer uses.

    Keys are integer nanoseconds and ``build`` receives the step rounded to them (the
    observers' steps are whole STEP_QUANTUM); ``exact=True`` keys on the float h itself,
    for callers whose steps are arbitrary (the differentiator used on its own).  Bounded
    (least recently built first out), so a stream with ever new step sizes costs one
    ``build`` per sample, never unbounded memory.
    """

    def __init__(self, build, size: int = 256, exact: bool = False):
        self._build = build
        self._size = size
        self._exact = exact
        self._data: OrderedDict = OrderedDict()
        self.misses = 0

    def __call__(self, h: float):
        key = h if self._exact else round(h * 1e9)
        value = self._data.get(key)
        if value is None:
            if not key > 0:
                raise ValueError(f"step must be at least 1 ns, got {h!r} s")
            self.misses += 1
            value = self._build(key if self._exact else key * 1e-9)
            self._data[key] = value
            if len(self._data) > self._size:
                self._data.popitem(last=False)
        return value

    def clear(self) -> None:
        self._data.clear()

    def __len__(self) -> int:
        return len(self._data)

    def __contains__(self, key: int) -> bool:
        """Whether the step of ``key`` ns (or the exact float key) is cached."""
        return key in self._data


def foh_matrices(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, G0, G1) of the first-order-hold step of length h > 0."""
    n, m = B.shape
    M = np.zeros((n + 2 * m, n + 2 * m))
    M[:n, :n] = A * h
    M[:n, n:n + m] = B * h
    M[n:n + m, n + m:] = np.eye(m)      # w' = slope, slope given per unit of h
    E = expm(M)
    Phi = E[:n, :n]
    Gam = E[:n, n:n + m]                 # integral of e^{A(h-s)} B ds
    Gam1 = E[:n, n + m:]                 # integral of e^{A(h-s)} B (s/h) ds
    return Phi, Gam - Gam1, Gam1


def zoh_matrices(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma) of the zero-order-hold step of length h > 0."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A * h
    M[:n, n:] = B * h
    E = expm(M)
    return E[:n, :n], E[:n, n:]


class ExactStepper:
    """Cached exact FOH/ZOH step of ``x' = A x + B w``.

    ``step(x, w0, w1, h)`` returns x after h with w linear from w0 to w1 (pass
    ``w1 = w0`` for a held input).  The step matrices are stacked as
    ``[Phi | G0 | G1]`` so a step is one matrix-vector product.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, cache_size: int = 256):
        self.A = np.array(A, dtype=float)
        self.B = np.array(B, dtype=float)
        if self.A.ndim != 2 or self.A.shape[0] != self.A.shape[1] or self.B.shape[0] != self.A.shape[0]:
            raise ValueError(f"bad shapes A {self.A.shape}, B {self.B.shape}")
        self.n = self.A.shape[0]
        self.m = self.B.shape[1]
        self.stacked = StepCache(lambda h: np.hstack(foh_matrices(self.A, self.B, h)), cache_size)

    @property
    def misses(self) -> int:
        return self.stacked.misses

    def step(self, x: np.ndarray, w0: np.ndarray, w1: np.ndarray, h: float) -> np.ndarray:
        """x after a step of h with the input linear from w0 to w1.

        Once a stream has shown more than COMPOSE_AFTER step sizes (irregular stamps), a
        new size that is a whole number of STEP_QUANTUM is composed of cached power-of-two
        steps (the input interpolated at the joints: the same linear input, so the same
        exact step up to rounding) instead of costing a new matrix exponential each: at
        most ~21 cached sizes per second of step length.  A regular stream never gets
        there and keeps one product per step."""
        key = round(h * 1e9)
        q = quanta(h)
        if key in self.stacked or self.stacked.misses < COMPOSE_AFTER or q <= 0 \
                or abs(q * STEP_QUANTUM - h) > 1e-12:
            return self.stacked(h) @ np.concatenate((x, w0, w1))
        done, wa = 0, w0
        for bit in range(q.bit_length() - 1, -1, -1):
            d = 1 << bit
            if not q & d:
                continue
            wb = w1 if done + d == q else w0 + (w1 - w0) * ((done + d) / q)
            x = self.stacked(d * STEP_QUANTUM) @ np.concatenate((x, wa, wb))
            done, wa = done + d, wb
        return x
