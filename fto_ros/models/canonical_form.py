"""Linear SISO plants in observer canonical form (Holloway & Krstic 2019, eq. 1-6). ROS-free.

    x_i' = x_{i+1} - a_{n-i} y            i = 1, ..., r - 1
    x_i' = x_{i+1} - a_{n-i} y + b_{n-i} u  i = r, ..., n - 1
    x_n' = -a_0 y + b_0 u,                 y = x_1

i.e. ``x' = (A - a e_1') x + [0_(r-1); b] u`` with A the upper shift, a = (a_{n-1}, ..., a_0),
b = (b_rho, ..., b_0), rho = n - r.  The transfer function is
(b_rho s^rho + ... + b_0) / (s^n + a_{n-1} s^(n-1) + ... + a_0).

Two examples, registered in ``fto_ros.models.MODELS``:

- ``double_integrator``: the paper's Example 1, x1' = x2, x2' = u, y = x1, with
  u(t) = sin(10 t) + cos(t) and x(0) = (20, 1) (Figs. 4-6).
- ``third_order``: n = 3, relative degree r = 2, a lightly damped plant with a
  zero, G(s) = (s + 2) / (s^3 + 0.6 s^2 + 4 s + 1) (poles -0.26, -0.17 +- 1.99j,
  zero -2), u(t) = sin(3 t) + 0.5 cos(0.7 t), x(0) = (1, -2, 3).

The simulator holds the input between the 1 kHz input instants (ZOH, like a DAC);
the observer configs say ``input_hold: zoh`` accordingly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from .simulate import ModelSpec, Rhs
from ..core.errors import BadArgument


@dataclass(frozen=True)
class CanonicalPlant:
    """a = (a_{n-1}, ..., a_0), b = (b_rho, ..., b_0), relative degree r = n - rho."""

    a: tuple[float, ...]
    b: tuple[float, ...]

    @property
    def n(self) -> int:
        return len(self.a)

    @property
    def r(self) -> int:
        return self.n - (len(self.b) - 1)

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """(A - a e_1', [0; b]) as arrays (n x n, n)."""
        n = self.n
        A = np.diag(np.ones(n - 1), 1) if n > 1 else np.zeros((1, 1))
        A[:, 0] -= np.asarray(self.a, dtype=float)
        B = np.zeros(n)
        B[self.r - 1:] = self.b
        return A, B

    def params(self) -> dict[str, float]:
        """The coefficients by the paper's names: a_{n-1}..a_0, b_rho..b_0."""
        n, rho = self.n, len(self.b) - 1
        out = {f"a{n - 1 - i}": float(v) for i, v in enumerate(self.a)}
        out.update({f"b{rho - i}": float(v) for i, v in enumerate(self.b)})
        return out

    @classmethod
    def from_params(cls, params: Mapping[str, float], n: int, rho: int) -> "CanonicalPlant":
        known = {f"a{k}" for k in range(n)} | {f"b{k}" for k in range(rho + 1)}
        unknown = set(params) - known
        if unknown:
            raise BadArgument(f"unknown parameter(s) {sorted(unknown)}; known: {sorted(known)}")
        a = tuple(float(params[f"a{n - 1 - i}"]) for i in range(n))
        b = tuple(float(params[f"b{rho - i}"]) for i in range(rho + 1))
        return cls(a, b)


def _make_rhs_factory(n: int, rho: int):
    def make_rhs(params: Mapping[str, float] | None = None) -> Rhs:
        plant = CanonicalPlant.from_params(params or {}, n, rho)
        A, B = plant.matrices()

        def f(t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
            return A @ x + B * u[0]

        return f
    return make_rhs


def output(x: Sequence[float] | np.ndarray) -> np.ndarray:
    """y = x_1, as a length-1 array."""
    return np.array([x[0]], dtype=float)


# -- the paper's Example 1 ----------------------------------------------------------
DOUBLE_INTEGRATOR = CanonicalPlant(a=(0.0, 0.0), b=(1.0,))


def example1_input(t: float) -> np.ndarray:
    """u(t) = sin(10 t) + cos(t) (Example 1)."""
    return np.array([math.sin(10.0 * t) + math.cos(t)])


DOUBLE_INTEGRATOR_SPEC = ModelSpec(
    name="double_integrator",
    description="double integrator x1' = x2, x2' = u, y = x1 (Holloway & Krstic 2019, Example 1)",
    state_names=("x1", "x2"),
    input_names=("u",),
    output_names=("y",),
    default_params=DOUBLE_INTEGRATOR.params(),
    make_rhs=_make_rhs_factory(2, 0),
    output=output,
    default_x0=(20.0, 1.0),
    default_input=example1_input,
    input_description="u(t) = sin(10 t) + cos(t); zero-order hold at the input instants",
    joint_names=("joint1",),
)

# -- a third-order plant of relative degree 2 -----------------------------------------
THIRD_ORDER = CanonicalPlant(a=(0.6, 4.0, 1.0), b=(1.0, 2.0))


def third_order_input(t: float) -> np.ndarray:
    """u(t) = sin(3 t) + 0.5 cos(0.7 t)."""
    return np.array([math.sin(3.0 * t) + 0.5 * math.cos(0.7 * t)])


THIRD_ORDER_SPEC = ModelSpec(
    name="third_order",
    description="third-order plant of relative degree 2 in observer canonical form, "
                "(s + 2) / (s^3 + 0.6 s^2 + 4 s + 1)",
    state_names=("x1", "x2", "x3"),
    input_names=("u",),
    output_names=("y",),
    default_params=THIRD_ORDER.params(),
    make_rhs=_make_rhs_factory(3, 1),
    output=output,
    default_x0=(1.0, -2.0, 3.0),
    default_input=third_order_input,
    input_description="u(t) = sin(3 t) + 0.5 cos(0.7 t); zero-order hold at the input instants",
)
