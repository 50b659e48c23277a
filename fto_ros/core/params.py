"""The parameter schema every observer and the plant block declare (``Param``), resolving
values against it, and the checks of vectors and sizes the runner and the observers share.

ROS-free.  The dotted ROS names are built from these in runner/settings.py and
nodes/parameters.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import ConfigError, UsageError, short


#: parameter kinds, mapped one to one onto ROS 2 parameter types
KINDS = ("bool", "int", "double", "string", "double_array", "int_array", "string_array")
#: most elements of an array parameter (the largest matrix an observer takes, 64 x 64, has
#: 4096): a longer one is refused before its elements are looked at
MAX_ARRAY = 10_000


def check_vector(v, n: int, what: str) -> str | None:
    """None if v is a sequence of n finite numbers, else the rejection reason
    ``<what>_not_an_array``, ``_wrong_length``, ``_not_numeric`` or ``_non_finite``."""
    try:
        length = len(v)
    except TypeError:
        return f"{what}_not_an_array"
    if length != n:
        return f"{what}_wrong_length"
    try:
        for x in v:
            if not math.isfinite(x):
                return f"{what}_non_finite"
    except TypeError:
        return f"{what}_not_numeric"
    return None


def check_size(name: str, value: Any) -> None:
    """ConfigError for a list longer than :data:`MAX_ARRAY` (looks at its length only)."""
    if isinstance(value, (list, tuple, np.ndarray)) and len(value) > MAX_ARRAY:
        raise ConfigError(name, f"a list of {len(value)} elements: at most {MAX_ARRAY}")


@dataclass(frozen=True)
class Param:
    """One parameter of an observer (or of the runner).

    ``name`` is relative to its section (the observer type for observer
    parameters), e.g. ``A1`` becomes the ROS parameter ``single_delay.A1``.
    A ``default`` of None makes the parameter required (``required``).
    ``min``/``max`` bound a scalar (or every element of an array) inclusively,
    ``gt`` strictly (``gt=0.0``: > 0).
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
    gt: float | None = None

    def __post_init__(self):
        if self.kind not in KINDS:
            raise UsageError(f"unknown parameter kind {self.kind!r}")

    @property
    def required(self) -> bool:
        return self.default is None

    @property
    def lower(self) -> float | None:
        """The smallest accepted value (inclusive), from min or gt."""
        if self.gt is not None:
            return math.nextafter(float(self.gt), math.inf)
        return self.min

    def coerce(self, value: Any, full_name: str | None = None) -> Any:
        """Return ``value`` converted to this parameter's type, or raise ConfigError.

        Integers are accepted for doubles (``30`` for ``30.0``), and ints and
        doubles for double arrays: robot_localization's opaque
        InvalidParameterTypeException is exactly what users complain about.
        Values quoted in messages are shortened (a huge list never is printed whole).
        """
        name = full_name or self.name
        kind = self.kind
        try:
            if kind == "bool":
                if not isinstance(value, (bool, np.bool_)):
                    raise ConfigError(name, f"expected true or false, got {short(value)}")
                return bool(value)
            if kind == "int":
                if isinstance(value, (bool, str)) or not float(value).is_integer():
                    raise ConfigError(name, f"expected an integer, got {short(value)}")
                out = int(value)
                self._check_range(name, out)
                return out
            if kind == "double":
                if isinstance(value, (bool, str)):
                    raise ConfigError(name, f"expected a number, got {short(value)}")
                out = float(value)
                if not math.isfinite(out):
                    raise ConfigError(name, f"must be finite, got {short(value)}")
                self._check_range(name, out)
                return out
            if kind == "string":
                if not isinstance(value, str):
                    raise ConfigError(name, f"expected a string, got {short(value)}")
                if self.choices and value not in self.choices:
                    raise ConfigError(
                        name, f"must be one of {', '.join(self.choices)}; got {short(value)}")
                return value
            if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
                raise ConfigError(name, f"expected a list, got {short(value)}")
            check_size(name, value)
            if kind == "string_array":
                if not all(isinstance(v, str) for v in value):
                    raise ConfigError(name, f"expected a list of strings, got {short(value)}")
                bad = [v for v in value if self.choices and v not in self.choices]
                if bad:
                    raise ConfigError(name, f"each must be one of {', '.join(self.choices)}; "
                                      f"got {short(bad[0])}")
                return [str(v) for v in value]
            if kind == "int_array":
                if not all(not isinstance(v, (bool, str)) and float(v).is_integer() for v in value):
                    raise ConfigError(name, f"expected a list of integers, got {short(value)}")
                out = [int(v) for v in value]
            else:  # double_array
                if any(isinstance(v, (bool, str)) for v in value):
                    raise ConfigError(name, f"expected a list of numbers, got {short(value)}")
                out = [float(v) for v in value]
                if not all(math.isfinite(v) for v in out):
                    raise ConfigError(name, "must contain only finite numbers")
            for v in out:
                self._check_range(name, v)
            return out
        except (TypeError, ValueError, OverflowError) as exc:
            if isinstance(exc, ConfigError):
                raise
            what = "a number too large for a double" if isinstance(exc, OverflowError) else kind
            raise ConfigError(name, f"cannot read {short(value)} as {what}") from None

    def _check_range(self, name: str, v: float) -> None:
        if self.gt is not None and not v > self.gt:
            raise ConfigError(name, f"must be > {self.gt}, got {v}")
        if self.min is not None and v < self.min:
            raise ConfigError(name, f"must be >= {self.min}, got {v}")
        if self.max is not None and v > self.max:
            raise ConfigError(name, f"must be <= {self.max}, got {v}")


def resolve(params: Sequence[Param], values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Typed values for ``params`` from ``values`` (short names), defaults filled in.

    A name in ``values`` that no parameter declares is refused: a typo in a
    params file must not be silently ignored.  A value given as null (YAML ``~``,
    an empty ROS parameter) counts as not given: the default applies, and a
    required parameter without a value is refused, so nothing reaches an
    observer as None.
    """
    known = {p.name for p in params}
    for key in values:
        if key not in known:
            raise ConfigError(prefix + key, "unknown parameter (known: "
                              + ", ".join(sorted(known)) + ")")
    out = {}
    for p in params:
        raw = values.get(p.name)
        if raw is None:
            if p.required:
                raise ConfigError(prefix + p.name, f"required: {p.description}")
            raw = p.default
        out[p.name] = p.coerce(raw, prefix + p.name)
    return out


def matrix(cfg: Mapping[str, Any], name: str, rows: int, cols: int, prefix: str = "") -> np.ndarray:
    """The flat row-major array ``cfg[name]`` as a rows x cols matrix, or ConfigError."""
    flat = cfg[name]
    if flat is None or len(flat) != rows * cols:
        got = "nothing" if flat is None else f"{len(flat)} values"
        raise ConfigError(prefix + name, f"expected a {rows}x{cols} matrix as {rows * cols} "
                          f"values in row-major order, got {got}")
    return np.asarray(flat, dtype=float).reshape(rows, cols)
