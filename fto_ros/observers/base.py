"""The observer protocol and the parameter schema every observer declares.

ROS-free.  An observer is built from a dict of already-typed parameter values
(keyed by the short names of its ``PARAMS``) and is then driven sample by
sample with ``update(t, y, u)``.  The runner wraps it; the node and the replay
harness only ever talk to the runner.
"""
from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ..core.errors import ConfigError


#: parameter kinds, mapped one to one onto ROS 2 parameter types
KINDS = ("bool", "int", "double", "string", "double_array", "int_array", "string_array")


class SampleRejected(Exception):
    """Raised by ``Observer.update`` for a sample it cannot use.

    The observer must leave its state untouched when it raises this (compute
    the new state first, commit it only when it is finite), so a bad sample can
    never corrupt the estimate.  ``reason`` is a short snake_case tag counted
    in the diagnostics.
    """

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class Param:
    """One parameter of an observer (or of the runner).

    ``name`` is relative to its section (the observer type for observer
    parameters), e.g. ``A1`` becomes the ROS parameter ``single_delay.A1``.
    ``min``/``max`` bound a scalar (or every element of an array).
    ``read_only`` parameters change the structure (dimensions, models) and can
    only be set at start-up; the others may be changed at run time and are
    re-validated by rebuilding the observer.
    """

    name: str
    kind: str
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    read_only: bool = True
    choices: tuple[str, ...] = field(default=())

    def __post_init__(self):
        if self.kind not in KINDS:
            raise TypeError(f"unknown parameter kind {self.kind!r}")

    def coerce(self, value: Any, full_name: str | None = None) -> Any:
        """Return ``value`` converted to this parameter's type, or raise ConfigError.

        Integers are accepted for doubles (``30`` for ``30.0``), and ints and
        doubles for double arrays: robot_localization's opaque
        InvalidParameterTypeException is exactly what users complain about.
        """
        name = full_name or self.name
        kind = self.kind
        try:
            if kind == "bool":
                if not isinstance(value, (bool, np.bool_)):
                    raise ConfigError(name, f"expected true or false, got {value!r}")
                return bool(value)
            if kind == "int":
                if isinstance(value, (bool, str)) or not float(value).is_integer():
                    raise ConfigError(name, f"expected an integer, got {value!r}")
                out = int(value)
                self._check_range(name, out)
                return out
            if kind == "double":
                if isinstance(value, (bool, str)):
                    raise ConfigError(name, f"expected a number, got {value!r}")
                out = float(value)
                if not math.isfinite(out):
                    raise ConfigError(name, f"must be finite, got {value!r}")
                self._check_range(name, out)
                return out
            if kind == "string":
                if not isinstance(value, str):
                    raise ConfigError(name, f"expected a string, got {value!r}")
                if self.choices and value not in self.choices:
                    raise ConfigError(
                        name, f"must be one of {', '.join(self.choices)}; got {value!r}")
                return value
            if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
                raise ConfigError(name, f"expected a list, got {value!r}")
            if kind == "string_array":
                if not all(isinstance(v, str) for v in value):
                    raise ConfigError(name, f"expected a list of strings, got {list(value)!r}")
                return [str(v) for v in value]
            if kind == "int_array":
                if not all(not isinstance(v, (bool, str)) and float(v).is_integer() for v in value):
                    raise ConfigError(name, f"expected a list of integers, got {list(value)!r}")
                out = [int(v) for v in value]
            else:  # double_array
                if any(isinstance(v, (bool, str)) for v in value):
                    raise ConfigError(name, f"expected a list of numbers, got {list(value)!r}")
                out = [float(v) for v in value]
                if not all(math.isfinite(v) for v in out):
                    raise ConfigError(name, "must contain only finite numbers")
            for v in out:
                self._check_range(name, v)
            return out
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ConfigError):
                raise
            raise ConfigError(name, f"cannot read {value!r} as {kind}") from None

    def _check_range(self, name: str, v: float) -> None:
        if self.min is not None and v < self.min:
            raise ConfigError(name, f"must be >= {self.min}, got {v}")
        if self.max is not None and v > self.max:
            raise ConfigError(name, f"must be <= {self.max}, got {v}")


def resolve(params: Sequence[Param], values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Typed values for ``params`` from ``values`` (short names), defaults filled in.

    A name in ``values`` that no parameter declares is refused: a typo in a
    params file must not be silently ignored.
    """
    known = {p.name for p in params}
    for key in values:
        if key not in known:
            raise ConfigError(prefix + key, "unknown parameter (known: "
                              + ", ".join(sorted(known)) + ")")
    out = {}
    for p in params:
        raw = values.get(p.name, p.default)
        out[p.name] = None if raw is None else p.coerce(raw, prefix + p.name)
    return out


def matrix(cfg: Mapping[str, Any], name: str, rows: int, cols: int, prefix: str = "") -> np.ndarray:
    """The flat row-major array ``cfg[name]`` as a rows x cols matrix, or ConfigError."""
    flat = cfg[name]
    if flat is None or len(flat) != rows * cols:
        got = "nothing" if flat is None else f"{len(flat)} values"
        raise ConfigError(prefix + name, f"expected a {rows}x{cols} matrix as {rows * cols} "
                          f"values in row-major order, got {got}")
    return np.asarray(flat, dtype=float).reshape(rows, cols)


class Observer(abc.ABC):
    """Sample-driven, variable-step state observer.

    Subclasses set ``TYPE`` (the registry name) and ``PARAMS`` and implement the
    abstract methods.  Times are seconds (float), ``y`` has length
    ``n_outputs``, ``u`` length ``n_inputs`` (an empty array when there is no
    known input).  ``u`` given at time t is the input applied from t on
    (zero-order hold, like a DAC) unless the observer's ``input_hold`` says
    first-order hold.
    """

    TYPE: str = ""
    PARAMS: tuple[Param, ...] = ()
    DESCRIPTION: str = ""

    n_states: int
    n_outputs: int
    n_inputs: int
    state_names: list[str]

    # -- life cycle -----------------------------------------------------
    @abc.abstractmethod
    def reset(self, t0: float, x0_hat: np.ndarray | None = None) -> None:
        """Restart the observer at time t0 (the first sample is taken at t0)."""

    @abc.abstractmethod
    def update(self, t: float, y: np.ndarray, u: np.ndarray) -> None:
        """Take the sample y measured at t (> the previous t) with the current input u.

        Either commits a new, finite state or raises SampleRejected and leaves
        the state as it was.
        """

    # -- outputs --------------------------------------------------------
    @property
    @abc.abstractmethod
    def estimate(self) -> np.ndarray:
        """x-hat at the time of the last update, in the plant's own coordinates."""

    @property
    def unknown_input(self) -> np.ndarray | None:
        """Estimate of the unknown input, for observers that identify it."""
        return None

    @property
    def guaranteed_time(self) -> float:
        """Time after reset from which the estimate is guaranteed (inf: none, the default)."""
        return math.inf

    #: the output residual of the last update, kept by the observer (nan before one)
    _residual: float = math.nan

    @property
    def output_residual(self) -> float:
        """Norm of the one-step output prediction error at the last update."""
        return self._residual

    @property
    def health(self) -> float:
        """The observer-specific health figure published on ``convergence``."""
        return float("nan")

    #: what ``health`` is, for the docs and the diagnostics
    HEALTH_NAME: str = ""

    def diagnostics(self) -> dict[str, Any]:
        """Observer-specific key-values for /diagnostics (human-readable)."""
        return {}
