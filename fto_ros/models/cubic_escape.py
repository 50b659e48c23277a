"""Plants with growing or oscillating trajectories for the ``global_norm`` observer. ROS-free.

Both are in the observability form of Astolfi & Praly 2005 (eq. 1-2), y = x0, no input:

- ``cubic_escape``: x0' = x1, x1' = -x1 + x0^3.  From x(0) = (0.6, 0) the solution escapes
  in finite time, t_e = 3.8541 s (computed with solve_ivp DOP853, rtol = atol = 1e-12, as
  the time where |x0| + |x1| reaches 1e8; x0 passes 10 at 3.7095 s, 30 at 3.8067 s, 100 at
  3.8401 s).  Output-to-state stable with V = x1^2/2 + x0^2: V' <= -V + 5 x0^2 + x0^6.
- ``van_der_pol``: x0' = x1, x1' = (1 - x0^2) x1 - x0, x(0) = (2, 0) (near the limit cycle,
  |x0| <= 2.01, |x1| <= 2.68).
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from .simulate import ModelSpec, Rhs

#: escape time from the default x(0) = (0.6, 0) (see the module docstring)
CUBIC_ESCAPE_TIME = 3.8541


def _no_input(t: float) -> np.ndarray:
    return np.zeros(0)


def output(x) -> np.ndarray:
    """y = x0."""
    return np.array([x[0]], dtype=float)


def _cubic_rhs(params: Mapping[str, float] | None = None) -> Rhs:
    p = {"damping": 1.0, **(params or {})}
    d = float(p["damping"])

    def f(t, x, u):
        return np.array([x[1], -d * x[1] + x[0] ** 3])
    return f


def _vdp_rhs(params: Mapping[str, float] | None = None) -> Rhs:
    p = {"mu": 1.0, **(params or {})}
    mu = float(p["mu"])

    def f(t, x, u):
        return np.array([x[1], mu * (1.0 - x[0] ** 2) * x[1] - x[0]])
    return f


CUBIC_ESCAPE_SPEC = ModelSpec(
    name="cubic_escape",
    description="x0' = x1, x1' = -x1 + x0^3, y = x0; escapes at t = 3.8541 s from x(0) = (0.6, 0)",
    state_names=("x0", "x1"),
    input_names=(),
    output_names=("y",),
    default_params={"damping": 1.0},
    make_rhs=_cubic_rhs,
    output=output,
    default_x0=(0.6, 0.0),
    default_input=_no_input,
    input_description="none",
)

VAN_DER_POL_SPEC = ModelSpec(
    name="van_der_pol",
    description="Van der Pol oscillator x0' = x1, x1' = (1 - x0^2) x1 - x0, y = x0",
    state_names=("x0", "x1"),
    input_names=(),
    output_names=("y",),
    default_params={"mu": 1.0},
    make_rhs=_vdp_rhs,
    output=output,
    default_x0=(2.0, 0.0),
    default_input=_no_input,
    input_description="none",
)
