"""The nonlinear example (22) of Possieri, Vidano & Novara 2020 (ROS-free).

    x1' = (u - 5)/(x2^2 + 1) + u x1 + u + x1 + x2 + (6 - 10 x1 x2)/(x2^2 + 1)^2
          - 10 x2/(x2^2 + 1)^3                                           (22a)
    x2' = -5 x1 - 3 x2 - 5/(x2^2 + 1)                                    (22b)
    y   = x1 + 1/(x2^2 + 1)                                              (22c)

with u(t) = 0.4 sin 3t + 0.5 sin 2t + 0.2 sin 5t and x(0) = (1, 2) (Section V).  Its
observability map O_1 = [y, u x1 + (u + 1)/(x2^2 + 1) + u + x1 + x2] has det J = 1 but no
closed-form inverse: the case the Newton-like inversion is for.

``SPEC`` registers it for ``fto-simulate`` (which holds the input between samples).  The
committed bags were made instead by :func:`simulate_example` with the *continuous* input
(as the paper's simulation has it; a held input makes y' jump at every input instant)
and the paper's three output cases (``measurement_disturbance``): none, band-limited
white noise of power 1e-4 sampled at 1e-3 (Simulink's definition: a new Gaussian value
every 1e-3 s with variance power / sample time = 0.1), and d(t) = 0.01 sin 48t; see
``scripts/make_possieri_bags.py``.
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
from scipy.integrate import solve_ivp

from .simulate import ModelSpec, Rhs
from ..core.errors import BadArgument, SimulationFailed

STATE_NAMES = ("x1", "x2")
DEFAULT_X0 = (1.0, 2.0)
#: the paper's model as text, for the params files and the tests
F_TEXT = ("(u - 5)/(x2**2 + 1) + u*x1 + u + x1 + x2 + (6 - 10*x1*x2)/(x2**2 + 1)**2 "
          "- 10*x2/(x2**2 + 1)**3",
          "-5*x1 - 3*x2 - 5/(x2**2 + 1)")
H_TEXT = "x1 + 1/(x2**2 + 1)"
NOISE_POWER, NOISE_SAMPLE_TIME = 1e-4, 1e-3
SINE_AMPLITUDE, SINE_FREQUENCY = 0.01, 48.0


def f(x: Sequence[float], u: float) -> np.ndarray:
    """Right-hand side (22a)-(22b)."""
    x1, x2 = float(x[0]), float(x[1])
    s = x2 * x2 + 1.0
    return np.array([(u - 5.0) / s + u * x1 + u + x1 + x2 + (6.0 - 10.0 * x1 * x2) / s ** 2
                     - 10.0 * x2 / s ** 3,
                     -5.0 * x1 - 3.0 * x2 - 5.0 / s])


def output(x: Sequence[float] | np.ndarray) -> np.ndarray:
    """y = x1 + 1/(x2^2 + 1) (22c), as a length-1 array."""
    return np.array([float(x[0]) + 1.0 / (float(x[1]) ** 2 + 1.0)])


def observability_map(x: Sequence[float], u: float) -> np.ndarray:
    """The paper's closed form of O_1(x, u) (Section V)."""
    x1, x2 = float(x[0]), float(x[1])
    s = x2 * x2 + 1.0
    return np.array([x1 + 1.0 / s, u * x1 + (u + 1.0) / s + u + x1 + x2])


def input_signal(t: float) -> float:
    """u(t) = 0.4 sin 3t + 0.5 sin 2t + 0.2 sin 5t."""
    return 0.4 * math.sin(3 * t) + 0.5 * math.sin(2 * t) + 0.2 * math.sin(5 * t)


def input_derivatives(t: float, order: int) -> list[float]:
    """u, u', ..., u^(order) at t (exact)."""
    out = []
    for k in range(order + 1):
        out.append(sum(a * w ** k * math.sin(w * t + k * math.pi / 2)
                       for a, w in ((0.4, 3.0), (0.5, 2.0), (0.2, 5.0))))
    return out


def default_input(t: float) -> np.ndarray:
    return np.array([input_signal(t)])


def make_rhs(params: Mapping[str, float] | None = None) -> Rhs:
    if params:
        raise BadArgument(f"possieri_example has no parameters, got {sorted(params)}")

    def rhs(t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return f(x, float(u[0]))

    return rhs


def simulate_example(t: np.ndarray, disturbance: str = "none", seed: int = 0,
                     x0: Sequence[float] = DEFAULT_X0) -> dict[str, np.ndarray]:
    """Simulate (22) with the continuous input at the instants t (starting at t[0]).

    ``disturbance``: ``none``, ``white_noise`` (band-limited white noise: one Gaussian
    value per NOISE_SAMPLE_TIME, held, variance NOISE_POWER / NOISE_SAMPLE_TIME, seeded)
    or ``sinusoid`` (0.01 sin 48 t).  Returns t, x (N, 2), u (N, 1), y_true, y (N, 1).
    """
    t = np.asarray(t, dtype=float)
    sol = solve_ivp(lambda tt, xx: f(xx, input_signal(tt)), (t[0], t[-1]), list(x0),
                    method="DOP853", t_eval=t, rtol=1e-12, atol=1e-13)
    if not sol.success:
        raise SimulationFailed(f"simulation failed: {sol.message}")
    x = sol.y.T
    u = np.array([[input_signal(tt)] for tt in t])
    y_true = np.array([output(xi) for xi in x])
    if disturbance == "none":
        d = np.zeros_like(y_true)
    elif disturbance == "white_noise":
        rng = np.random.default_rng(seed)
        k = np.floor((t - t[0]) / NOISE_SAMPLE_TIME + 1e-9).astype(int)
        values = rng.standard_normal(k.max() + 1) * math.sqrt(NOISE_POWER / NOISE_SAMPLE_TIME)
        d = values[k].reshape(-1, 1)
    elif disturbance == "sinusoid":
        d = (SINE_AMPLITUDE * np.sin(SINE_FREQUENCY * t)).reshape(-1, 1)
    else:
        raise BadArgument(f"unknown disturbance {disturbance!r} (none, white_noise, sinusoid)")
    return {"t": t, "x": x, "u": u, "y_true": y_true, "y": y_true + d}


SPEC = ModelSpec(
    name="possieri_example",
    description="nonlinear example (22) of Possieri, Vidano & Novara 2020 (no closed-form "
                "inverse of the observability map)",
    state_names=STATE_NAMES,
    input_names=("u",),
    output_names=("y",),
    default_params={},
    make_rhs=make_rhs,
    output=output,
    default_x0=DEFAULT_X0,
    default_input=default_input,
    input_description="u(t) = 0.4 sin 3t + 0.5 sin 2t + 0.2 sin 5t",
)
