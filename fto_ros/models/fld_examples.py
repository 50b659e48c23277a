"""The two examples of Fridman, Levant & Davila 2007, Section 6 (ROS-free).

Example 1 (6.1), strongly observable (relative degree r = n = 4), unstable
(eigenvalues -3, -2, -1, 1)::

    x' = A x + D zeta(t),  y = C x,  A = [[0,1,0,0],[0,0,1,0],[0,0,0,1],[6,5,-5,-5]],
    D = B = (0,0,0,1)^T,  C = (1,0,0,0),  x(0) = (1, 0, 1, 1),
    zeta(t) = cos 0.5t + 0.5 sin t + 0.5,
    output noise (6.1.1): 0.1 sin(1037 |cos(687 t)|)    (fto-simulate --output-disturbance)

Example 2 (6.2), strongly detectable (r = 3 < n_O = 4 < n = 6), unstable, invariant zeros
-1, -2, -3::

    A = [[0,1,0,0,0,0],[0,0,1,0,0,0],[0,0,0,1,0,0],[7,-17,17,-2,0,0],[1,3,4,5,-1,3],
         [1,3,4,5,0,-3]],  D = B = (0,0,1,0,0,0)^T,  C = (1,0,0,0,0,0),  x(0) = (1,...,1),
    same zeta(t).

Both with u = 0, so the specs have no known input (no /input topic).
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from .simulate import Rhs
from .unknown_input import UnknownInputModelSpec
from ..core.errors import BadArgument

EXAMPLE1_A = np.array([[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [6, 5, -5, -5]], dtype=float)
EXAMPLE1_D = np.array([0, 0, 0, 1], dtype=float)
EXAMPLE1_C = np.array([[1, 0, 0, 0]], dtype=float)
EXAMPLE1_X0 = (1.0, 0.0, 1.0, 1.0)
#: the paper's Luenberger gain (poles -1, -2, -3, -4) and K = P~^-1
EXAMPLE1_L = np.array([5, 5, 5, 5], dtype=float)

EXAMPLE2_A = np.array([[0, 1, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0], [0, 0, 0, 1, 0, 0],
                       [7, -17, 17, -2, 0, 0], [1, 3, 4, 5, -1, 3], [1, 3, 4, 5, 0, -3]],
                      dtype=float)
EXAMPLE2_D = np.array([0, 0, 1, 0, 0, 0], dtype=float)
EXAMPLE2_C = np.array([[1, 0, 0, 0, 0, 0]], dtype=float)
EXAMPLE2_X0 = (1.0,) * 6
EXAMPLE2_L = np.array([8, 36, 97, 313, 0, 0], dtype=float)


def zeta(t: float) -> np.ndarray:
    """The paper's 'unknown' input zeta(t) = cos 0.5t + 0.5 sin t + 0.5 (both examples)."""
    return np.array([math.cos(0.5 * t) + 0.5 * math.sin(t) + 0.5])


def example1_noise(t: float) -> np.ndarray:
    """The paper's deterministic output noise 0.1 sin(1037 |cos(687 t)|) (Section 6.1.1)."""
    return np.array([0.1 * math.sin(1037.0 * abs(math.cos(687.0 * t)))])


def _make_rhs_factory(A: np.ndarray, D: np.ndarray):
    def make_rhs(params: Mapping[str, float] | None = None) -> Rhs:
        if params:
            raise BadArgument(f"this model has no parameters, got {sorted(params)}")

        def f(t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
            return A @ x + D * (math.cos(0.5 * t) + 0.5 * math.sin(t) + 0.5)

        return f
    return make_rhs


def output(x: Sequence[float] | np.ndarray) -> np.ndarray:
    """y = x1, as a length-1 array."""
    return np.array([x[0]], dtype=float)


def no_input(t: float) -> np.ndarray:
    """u = 0: the examples have no known input (m = 0)."""
    return np.zeros(0)


ZETA_TEXT = "zeta(t) = cos(0.5 t) + 0.5 sin(t) + 0.5"

EXAMPLE1_SPEC = UnknownInputModelSpec(
    name="fld_example1",
    description="Fridman, Levant & Davila 2007, Example 1: unstable 4-state plant, strongly "
                "observable, unknown input zeta",
    state_names=("x1", "x2", "x3", "x4"),
    input_names=(),
    output_names=("y",),
    default_params={},
    make_rhs=_make_rhs_factory(EXAMPLE1_A, EXAMPLE1_D),
    output=output,
    default_x0=EXAMPLE1_X0,
    default_input=no_input,
    input_description="none (u = 0)",
    unknown_input=zeta,
    unknown_input_names=("zeta",),
    unknown_input_description=ZETA_TEXT + ", entering x4' (D = (0, 0, 0, 1))",
    output_disturbance=example1_noise,
    output_disturbance_description="0.1 sin(1037 |cos(687 t)|) added to y (Section 6.1.1)",
)

EXAMPLE2_SPEC = UnknownInputModelSpec(
    name="fld_example2",
    description="Fridman, Levant & Davila 2007, Example 2: unstable 6-state plant, strongly "
                "detectable (r = 3, zeros -1, -2, -3), unknown input zeta",
    state_names=("x1", "x2", "x3", "x4", "x5", "x6"),
    input_names=(),
    output_names=("y",),
    default_params={},
    make_rhs=_make_rhs_factory(EXAMPLE2_A, EXAMPLE2_D),
    output=output,
    default_x0=EXAMPLE2_X0,
    default_input=no_input,
    input_description="none (u = 0)",
    unknown_input=zeta,
    unknown_input_names=("zeta",),
    unknown_input_description=ZETA_TEXT + ", entering x3' (D = (0, 0, 1, 0, 0, 0))",
)
