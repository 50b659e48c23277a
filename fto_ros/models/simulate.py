"""Model-agnostic plant simulator with a zero-order-hold input (ROS-free).

The simulator plays the part of a DAC + plant + sensor: the input profile
``u_profile(t)`` is sampled at the input instants ``t_u[k]`` and held constant
on ``[t_u[k], t_u[k+1])``; the plant ``x' = f(t, x, u) + delta1(t)`` is
integrated *piecewise* between consecutive breakpoints (the union of the input
instants and the requested sample instants), so that the held input is exact
and no integrator step ever straddles an input jump.  Each piece is solved with
``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-11, atol 1e-12 by default).

A plant is described by a :class:`ModelSpec` (state names, output map, default
initial state, default input profile, default model uncertainty and a factory
``make_rhs(params) -> f(t, x, u)``); the registry of specs is
``fto_ros.models.MODELS``.
"""
from __future__ import annotations

import math

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np
from scipy.integrate import solve_ivp

from ..core.errors import BadArgument, SimulationFailed

#: ``f(t, x, u) -> x_dot`` (x and u 1-D float arrays)
Rhs = Callable[[float, np.ndarray, np.ndarray], np.ndarray]
#: ``u_profile(t) -> u`` (scalar or 1-D array-like)
InputProfile = Callable[[float], "np.ndarray | Sequence[float] | float"]
#: ``delta1(t) -> additive process disturbance`` (length n)
Disturbance = Callable[[float], "np.ndarray | Sequence[float]"]


@dataclass(frozen=True)
class ModelSpec:
    """Everything the simulator and ``fto-simulate`` need to know about one plant.

    To add a plant: write ``fto_ros/models/<name>.py`` with its right-hand side
    and a ``SPEC = ModelSpec(...)``, then add it to ``MODELS`` in
    ``fto_ros/models/__init__.py``.

    Attributes:
        name: registry key and ROS system name (topics ``/<name>/...``).
        description: one line for ``--help`` and the bag metadata.
        state_names: names of the state components (length n).
        input_names: names of the input components (length m).
        output_names: names of the measured outputs (length p).
        default_params: parameter name -> value; ``make_rhs`` accepts this dict
            (possibly with some values replaced).
        make_rhs: ``params -> f(t, x, u)``, the nominal right-hand side.
        output: ``x -> y`` (length p), the noise-free measurement map.
        default_x0: default initial state (length n).
        default_input: ``t -> u`` (length m), the default input profile
            (sampled and held by the simulator).
        input_description: human-readable formula of ``default_input``.
        uncertainty: ``t -> delta1(t)`` (length n), the additive model
            uncertainty switched on by ``fto-simulate --uncertainty``; ``None``
            if the model defines none.
        uncertainty_description: human-readable formula of ``uncertainty``.
        joint_names: one joint name per output if the outputs are joint
            positions (published as ``sensor_msgs/JointState``); empty otherwise.
    """

    name: str
    description: str
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    default_params: Mapping[str, float]
    make_rhs: Callable[[Mapping[str, float]], Rhs]
    output: Callable[[np.ndarray], np.ndarray]
    default_x0: tuple[float, ...]
    default_input: InputProfile
    input_description: str = ""
    uncertainty: Disturbance | None = None
    uncertainty_description: str = ""
    joint_names: tuple[str, ...] = field(default=())

    @property
    def n(self) -> int:
        """State dimension."""
        return len(self.state_names)

    @property
    def m(self) -> int:
        """Input dimension."""
        return len(self.input_names)

    @property
    def p(self) -> int:
        """Output dimension."""
        return len(self.output_names)


@dataclass
class SimulationResult:
    """Arrays returned by :func:`simulate`.

    Attributes:
        t: (N,) the requested sample instants, sorted, in seconds.
        x: (N, n) the true state at ``t``.
        u: (N, m) the input *acting* at ``t`` (the value held since the latest
            input instant <= t).
        t_u: (K,) the input instants (DAC update times).
        u_k: (K, m) the held input values, ``u_k[k] = u_profile(t_u[k])``,
            acting on ``[t_u[k], t_u[k+1])``.
        y: (N, p) the measured output (with noise) if an output map was given,
            else ``None``.
        y_true: (N, p) the noise-free output, or ``None``.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    t_u: np.ndarray
    u_k: np.ndarray
    y: np.ndarray | None = None
    y_true: np.ndarray | None = None


def _as_1d(value, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    if arr.ndim != 1:
        raise BadArgument(f"{name} must be a scalar or a 1-D vector, got shape {arr.shape}")
    return arr


def simulate(
    f: Rhs,
    x0: Sequence[float] | np.ndarray,
    t_samples: Sequence[float] | np.ndarray,
    u_profile: InputProfile,
    *,
    t_input: Sequence[float] | np.ndarray | None = None,
    delta1: Disturbance | None = None,
    output: Callable[[np.ndarray], np.ndarray] | None = None,
    noise_sigma: float | Sequence[float] | np.ndarray = 0.0,
    rng: np.random.Generator | None = None,
    method: str = "DOP853",
    rtol: float = 1e-11,
    atol: float = 1e-12,
    jumps: Sequence[tuple[float, int, float]] = (),
) -> SimulationResult:
    """Simulate ``x' = f(t, x, u) + delta1(t)`` under a zero-order-hold input.

    Args:
        f: nominal right-hand side ``f(t, x, u)``.
        x0: initial state at ``t_samples[0]`` (the first instant).
        t_samples: sample instants (strictly increasing) at which the state
            (and output) is returned.  ``t_samples[0]`` is the initial time.
        u_profile: ``t -> u``; sampled at the input instants and held.
        t_input: input (DAC) instants, strictly increasing; default
            ``t_samples``.  The first one must be <= ``t_samples[0]`` (the
            input is defined from the start); instants after the last sample
            are ignored.  They need not coincide with ``t_samples`` (e.g. a
            1 kHz input with irregular measurement instants).
        delta1: optional additive process disturbance ``t -> R^n``.
        output: optional measurement map ``x -> y``; then ``y``/``y_true`` are
            returned.
        noise_sigma: standard deviation(s) of the additive Gaussian
            measurement noise on ``y`` (scalar or one per output).
        rng: numpy Generator for the noise (required if any sigma > 0, so
            that every noisy simulation is explicitly seeded).
        method, rtol, atol: passed to ``solve_ivp`` for every piece.
        jumps: ``(t, i, delta)``: at time t (t0 < t <= the last sample) state i jumps by
            delta (x_i(t+) = x_i(t-) + delta: a collision, an impact); a sample at t sees
            the state after the jump.

    Returns:
        A :class:`SimulationResult`.

    Raises:
        ValueError: malformed times, shapes, or a failed integration.
    """
    t_s = np.asarray(t_samples, dtype=float)
    if t_s.ndim != 1 or t_s.size == 0:
        raise BadArgument("t_samples must be a non-empty 1-D array")
    if t_s.size > 1 and not np.all(np.diff(t_s) > 0):
        raise BadArgument("t_samples must be strictly increasing")
    t_u = t_s.copy() if t_input is None else np.asarray(t_input, dtype=float)
    if t_u.ndim != 1 or t_u.size == 0:
        raise BadArgument("t_input must be a non-empty 1-D array")
    if t_u.size > 1 and not np.all(np.diff(t_u) > 0):
        raise BadArgument("t_input must be strictly increasing")
    if t_u[0] > t_s[0]:
        raise BadArgument("the first input instant must be <= the first sample instant "
                         "(the input must be defined from the start)")
    t0, t_end = t_s[0], t_s[-1]
    # Input instants before t0: only the latest one matters (it is acting at t0).
    first = int(np.searchsorted(t_u, t0, side="right")) - 1
    t_u = t_u[first:][t_u[first:] <= t_end]

    x = _as_1d(x0, "x0").copy()
    n = x.size
    u_k = np.array([_as_1d(u_profile(float(tk)), "u_profile(t)") for tk in t_u])
    m = u_k.shape[1]

    jump_at: dict[float, list[tuple[int, float]]] = {}
    for tj, i, delta in jumps:
        if not (t0 < tj <= t_end) or not (0 <= i < n) or not math.isfinite(delta):
            raise BadArgument(f"jump ({tj}, {i}, {delta}): needs {t0} < t <= {t_end}, a state "
                             f"index in 0..{n - 1} and a finite size")
        jump_at.setdefault(float(tj), []).append((int(i), float(delta)))
    # Breakpoints: union of sample instants, input instants (>= t0) and jumps.
    t_break = np.union1d(np.union1d(t_s, np.maximum(t_u, t0)), np.array(sorted(jump_at)))
    out_idx = np.searchsorted(t_break, t_s)
    # index of the input acting on [t_break[i], t_break[i+1])
    u_idx = np.searchsorted(t_u, t_break, side="right") - 1

    x_break = np.empty((t_break.size, n))
    x_break[0] = x
    for i in range(t_break.size - 1):
        ui = u_k[u_idx[i]]
        if delta1 is None:
            def fun(t, xx, _u=ui):
                return f(t, xx, _u)
        else:
            def fun(t, xx, _u=ui):
                return np.asarray(f(t, xx, _u), dtype=float) + _as_1d(delta1(t), "delta1(t)")
        ta, tb = t_break[i], t_break[i + 1]
        sol = solve_ivp(fun, (ta, tb), x, method=method, rtol=rtol, atol=atol,
                        first_step=tb - ta)
        if not sol.success:
            raise SimulationFailed(f"integration failed on [{ta}, {tb}]: {sol.message}")
        x = sol.y[:, -1].copy()
        for i_state, delta in jump_at.get(float(tb), ()):
            x[i_state] += delta
        if not np.all(np.isfinite(x)):
            raise SimulationFailed(f"state became non-finite at t = {tb}")
        x_break[i + 1] = x

    xs = x_break[out_idx]
    us = u_k[u_idx[out_idx]].reshape(t_s.size, m)
    result = SimulationResult(t=t_s, x=xs, u=us, t_u=t_u, u_k=u_k)
    if output is not None:
        y_true = np.array([_as_1d(output(xi), "output(x)") for xi in xs])
        sigma = np.broadcast_to(np.asarray(noise_sigma, dtype=float), (y_true.shape[1],))
        if np.any(sigma < 0):
            raise BadArgument("noise_sigma must be >= 0")
        y = y_true.copy()
        if np.any(sigma > 0):
            if rng is None:
                raise BadArgument("measurement noise needs a seeded numpy Generator (rng)")
            y = y + rng.standard_normal(y.shape) * sigma
        result.y, result.y_true = y, y_true
    return result


def uniform_grid(duration: float, rate: float, t0: float = 0.0) -> np.ndarray:
    """Sample instants ``t0 + k / rate`` for ``k = 0 .. round(duration * rate)``.

    The instants are rounded to whole nanoseconds (as they will be in a bag), so
    that the simulated instants and the recorded time stamps are the same.
    """
    if duration <= 0 or rate <= 0:
        raise BadArgument("duration and rate must be > 0")
    n = int(round(duration * rate))
    return quantize_ns(t0 + np.arange(n + 1) / rate)


def sparse_instants(duration: float, t_min: float, t_max: float,
                    rng: np.random.Generator, t0: float = 0.0) -> np.ndarray:
    """Irregular sample instants with ``t_min <= t[j+1] - t[j] <= t_max`` (seeded).

    Starts at ``t0``; gaps are drawn uniformly (in whole nanoseconds, so the
    bounds hold exactly for the recorded stamps) from ``[t_min, t_max]``; stops
    at the last instant ``<= t0 + duration``.  Used for the sampled-output case (Mazenc & Malisoff 2022,
    Section IV, Theorem 2).
    """
    lo, hi = int(np.ceil(t_min * 1e9 - 1e-3)), int(np.floor(t_max * 1e9 + 1e-3))
    if not 0 < lo <= hi:
        raise BadArgument("need 0 < t_min <= t_max (at nanosecond resolution)")
    start, stop = to_ns(t0), to_ns(t0 + duration)
    times = [start]
    while True:
        nxt = times[-1] + int(rng.integers(lo, hi, endpoint=True))
        if nxt > stop:
            break
        times.append(nxt)
    return np.array(times, dtype=np.int64) / 1e9


def quantize_ns(t: np.ndarray | Sequence[float]) -> np.ndarray:
    """Round times in seconds to whole nanoseconds (the resolution of bag stamps)."""
    return np.round(np.asarray(t, dtype=float) * 1e9) / 1e9


def to_ns(t: float) -> int:
    """Seconds -> integer nanoseconds, ``round(t * 1e9)``."""
    return int(round(float(t) * 1e9))
