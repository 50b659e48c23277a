"""Single-link manipulator driven by a brush DC motor (ROS-free).

Mazenc & Malisoff 2022, Section V, eq. (64)-(67) (model from Dawson, Carroll &
Schneider 1994; parameters from Mazenc, Fridman & Djema 2015).  State
``chi = (q, q_dot, I)`` (load angle [rad], angular velocity [rad/s], armature
current [A]), input ``u = V`` (armature voltage [V]), output ``Y = q``:

    q'     = q_dot + d11(t)
    q_dot' = b1 I - a1 sin q - a2 q_dot + d12(t)
    I'     = b0 u - a3 q_dot - a4 I + d13(t)
    Y      = q + d2(t)                                              (65)

with ``a1 = N/M, a2 = B/M, a3 = K_B/L, a4 = R/L, b0 = 1/L, b1 = 1/M`` and the
paper's values ``b0 = 40, b1 = 15, a1 = 35, a2 = 1, a3 = 36.4, a4 = 200``.

For the single-delay observer the unmeasured part ``xi1 = (q_dot, I)`` enters
linearly: ``xi1' = A1 xi1 + F1(Y, t) + eps1``, ``q' = A2 xi1 + eps2`` with
``A1 = [[-a2, b1], [-a3, -a4]]``, ``A2 = [1, 0]`` and
``F1(s, t) = (-a1 sin s, b0 u(t))`` (eq. 66-67; the ``-k xi2 + k Y`` terms of
eq. 66 belong to the observer, not the plant).

Model uncertainties used by ``fto-simulate --uncertainty`` (the epsilons of
eq. 66: ``eps_{1,1} = d12``, ``eps_{1,2} = d13``, ``eps_2 = d11``):
``d11(t) = 0``, ``d12(t) = 0.5 sin(3 t)``, ``d13(t) = 0.2 cos(5 t)``.
The measurement disturbance ``d2 = eps_3`` is Gaussian noise added by the
simulator (``--noise SIGMA``, e.g. 1e-3 rad).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Mapping, Sequence

import numpy as np

from .simulate import ModelSpec, Rhs
from ..core.errors import BadArgument


@dataclass(frozen=True)
class DCMotorParams:
    """Parameters of eq. (65); defaults are the paper's values (Section V)."""

    b0: float = 40.0   #: 1/L
    b1: float = 15.0   #: 1/M
    a1: float = 35.0   #: N/M (gravity)
    a2: float = 1.0    #: B/M (viscous friction)
    a3: float = 36.4   #: K_B/L (back EMF)
    a4: float = 200.0  #: R/L (armature resistance)

    @classmethod
    def from_mapping(cls, params: Mapping[str, float] | None) -> "DCMotorParams":
        """Build from a dict (missing keys keep their defaults); unknown keys raise ValueError."""
        params = dict(params or {})
        unknown = set(params) - set(cls.__dataclass_fields__)
        if unknown:
            raise BadArgument(f"unknown dc_motor parameter(s) {sorted(unknown)}; "
                             f"known: {sorted(cls.__dataclass_fields__)}")
        return cls(**{k: float(v) for k, v in params.items()})


DEFAULT_PARAMS = DCMotorParams()
STATE_NAMES = ("q", "q_dot", "I")
#: default initial state (q, q_dot, I)
DEFAULT_X0 = (0.5, -1.0, 0.2)
#: half-period of the square component of the default voltage profile [s]
SQUARE_HALF_PERIOD = 0.7


def rhs(t: float, x: Sequence[float] | np.ndarray, u: float | Sequence[float] | np.ndarray,
        delta1: Sequence[float] | np.ndarray | None = None,
        params: DCMotorParams = DEFAULT_PARAMS) -> np.ndarray:
    """Right-hand side of eq. (65): ``chi' = f(chi, u) + delta1``.

    Args:
        t: time (unused: the nominal model is time-invariant; kept for the
            ``f(t, x, u)`` signature).
        x: state ``(q, q_dot, I)``.
        u: voltage ``V`` (scalar or length-1 array).
        delta1: additive uncertainty ``(d11, d12, d13)`` *evaluated at t*, or None.
        params: model parameters.
    """
    q, qd, cur = float(x[0]), float(x[1]), float(x[2])
    v = float(np.asarray(u, dtype=float).reshape(-1)[0])
    p = params
    dx = np.array([
        qd,
        p.b1 * cur - p.a1 * math.sin(q) - p.a2 * qd,
        p.b0 * v - p.a3 * qd - p.a4 * cur,
    ])
    if delta1 is not None:
        dx += np.asarray(delta1, dtype=float).reshape(3)
    return dx


def make_rhs(params: Mapping[str, float] | DCMotorParams | None = None) -> Rhs:
    """Return the nominal ``f(t, x, u)`` of eq. (65) for the given parameters."""
    p = params if isinstance(params, DCMotorParams) else DCMotorParams.from_mapping(params)
    b0, b1, a1, a2, a3, a4 = p.b0, p.b1, p.a1, p.a2, p.a3, p.a4
    sin = math.sin

    def f(t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        qd, cur = x[1], x[2]
        return np.array([qd, b1 * cur - a1 * sin(x[0]) - a2 * qd, b0 * u[0] - a3 * qd - a4 * cur])

    return f


def output(x: Sequence[float] | np.ndarray) -> np.ndarray:
    """Noise-free measurement ``Y = q``, as a length-1 array."""
    return np.array([x[0]], dtype=float)


def single_delay_split(params: DCMotorParams = DEFAULT_PARAMS) -> tuple[np.ndarray, np.ndarray]:
    """The paper's linear split (eq. 67): ``A1 = [[-a2, b1], [-a3, -a4]]`` (2x2), ``A2 = [[1, 0]]`` (1x2).

    The unmeasured state is ``xi1 = (q_dot, I)``, the measured one ``xi2 = q``.
    """
    a1_mat = np.array([[-params.a2, params.b1], [-params.a3, -params.a4]])
    a2_mat = np.array([[1.0, 0.0]])
    return a1_mat, a2_mat


def single_delay_f1(y: float, u: float, params: DCMotorParams = DEFAULT_PARAMS) -> np.ndarray:
    """The nonlinearity ``F1(Y, t) = (-a1 sin Y, b0 u(t))`` of eq. (66)-(67)."""
    return np.array([-params.a1 * math.sin(y), params.b0 * float(u)])


def default_voltage(t: float) -> np.ndarray:
    """Default input profile ``V(t) = 2 + 3 sin(2 pi 0.5 t) + 1.5 sq(t)`` [V] (length-1 array).

    ``sq(t) = +1`` on ``[1.4 k, 1.4 k + 0.7)`` and ``-1`` on ``[1.4 k + 0.7, 1.4 (k+1))``:
    a slow sine plus voltage steps every 0.7 s, so both smooth and abrupt
    excitation are present.  The simulator samples it and holds it (ZOH).
    """
    sq = 1.0 if math.floor(t / SQUARE_HALF_PERIOD + 1e-9) % 2 == 0 else -1.0
    return np.array([2.0 + 3.0 * math.sin(2.0 * math.pi * 0.5 * t) + 1.5 * sq])


def uncertainty(t: float) -> np.ndarray:
    """Model uncertainty ``delta1(t) = (d11, d12, d13) = (0, 0.5 sin 3t, 0.2 cos 5t)``."""
    return np.array([0.0, 0.5 * math.sin(3.0 * t), 0.2 * math.cos(5.0 * t)])


SPEC = ModelSpec(
    name="dc_motor",
    description="single-link manipulator driven by a brush DC motor "
                "(Mazenc & Malisoff 2022, eq. 65)",
    state_names=STATE_NAMES,
    input_names=("V",),
    output_names=("q",),
    default_params=asdict(DEFAULT_PARAMS),
    make_rhs=make_rhs,
    output=output,
    default_x0=DEFAULT_X0,
    default_input=default_voltage,
    input_description="V(t) = 2 + 3 sin(2 pi 0.5 t) + 1.5 sq(t) [V], sq = +1 on "
                      "[1.4k, 1.4k+0.7), -1 on [1.4k+0.7, 1.4k+1.4); zero-order hold "
                      "at the input instants",
    uncertainty=uncertainty,
    uncertainty_description="delta1(t) = (d11, d12, d13) = (0, 0.5 sin(3t), 0.2 cos(5t)) "
                            "(eps_2, eps_11, eps_12 of eq. 66)",
    joint_names=("joint1",),
)
