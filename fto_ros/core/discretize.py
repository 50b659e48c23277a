"""Exact sampled-data steps of linear systems ``x' = A x + B w(t)``: the step matrices and
the time grid the kernels share.

Between two samples the input ``w`` is either held (ZOH) or linear (FOH).  The
step matrices come from one matrix exponential of an augmented matrix (Van
Loan's construction), exact for any step size; kernels cache them per step size
(integer nanoseconds, core/exact_step.py and core/step_cache.py), so a fixed-rate
stream costs one ``expm`` in all.

    FOH:  x_{k+1} = Phi x_k + G0 w_k + G1 w_{k+1}
    ZOH:  x_{k+1} = Phi x_k + G0 w_k            (G1 = 0)

Plain Euler at the sample rate loses the estimate on stiff or unstable plants;
this does not.
"""
from __future__ import annotations

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

#: core/exact_step.py composes new step sizes from cached power-of-two ones after this many
#: distinct sizes
COMPOSE_AFTER = 64


def quanta(dt: float) -> int:
    """dt (s) as a whole number of STEP_QUANTUM."""
    return round(dt / STEP_QUANTUM)


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
