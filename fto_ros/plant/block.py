"""The ``plant`` block: one model of the plant, written once, parsed once (ROS-free).

Standard ROS parameters (a params file's ``plant:`` mapping)::

    plant.states          [q, q_dot, current]          names, n of them
    plant.inputs          [V]                          known inputs (may be empty)
    plant.unknown_inputs  [tau_L]                      unknown inputs (optional)
    plant.constants       ["b1=15", "a1=35", ...]      name=value, each may use the earlier ones
    plant.f               ["q_dot", "b1*current - a1*sin(q) - ...", ...]   x' = f(x, u, d)
    plant.h               ["q"]                        y = h(x, u), one expression per output

Parsed by :func:`fto_ros.core.named_model.parse_model` (names, constants and expressions
checked there, errors naming ``plant.f[i]``).  A plant whose linearisation is unobservable
from h at every point of a seeded sample is refused naming ``plant.h``.  :func:`to_text`
writes a derived expression back as text in an observer's vocabulary, floats printed
exactly, so nothing is rounded on the way.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
import sympy
from sympy.printing.str import StrPrinter

from ..core.errors import BadArgument, ConfigError
from ..core.named_model import NamedModel, parse_model
from ..core.params import Param, resolve

PREFIX = "plant."

#: the plant block's schema: declared by the node, resolved by :func:`fto_ros.plant.expand`
PLANT_PARAMS: tuple[Param, ...] = (
    Param("states", "string_array", None, "plant state names, e.g. [q, q_dot, current] "
          "(n = length); the observers publish their estimates under these names"),
    Param("inputs", "string_array", [], "known input names, e.g. [V] (m = length; empty: none)"),
    Param("unknown_inputs", "string_array", [], "unknown input names, e.g. [tau_L] (hosm "
          "identifies them; the other observers take them as zero)"),
    Param("constants", "string_array", [], "named constants 'name=value' usable in f and h, "
          "e.g. ['b1=15', 'a1=35']; a value may use the constants before it (a runtime change "
          "derives everything again)", read_only=False),
    Param("f", "string_array", None, "x' = f(x, u, d): one expression per state in the state, "
          "input, unknown-input and constant names (sin, cos, exp, sqrt, ... allowed)"),
    Param("h", "string_array", None, "y = h(x, u): one expression per measured output"),
    Param("units", "string_array", [], "unit of each state, e.g. [rad, rad/s, A] (empty: "
          "none); the replay figure labels its axes with them and fto-design says hosm's M "
          "in them (an output that is a state has that state's unit)"),
    Param("unknown_input_units", "string_array", [], "unit of each unknown input, e.g. [N m] "
          "(empty: none)"),
)


class Plant(NamedModel):
    """A parsed, checked plant block, with the texts it was written in."""

    constant_texts: list[str]
    f_texts: list[str]
    h_texts: list[str]

    @staticmethod
    def where(name: str, i: int) -> str:
        """The parameter name of expression ``i`` of f or h, e.g. 'plant.f[1]'."""
        return f"{PREFIX}{name}[{i}]"


def given(flat: Mapping[str, Any]) -> bool:
    """Whether the flat parameters carry a plant block (any ``plant.*`` value set).

    The node fills every declared parameter with its default, so a value equal to the
    default (None, []) counts as not given."""
    return any(k.startswith(PREFIX) and v not in (None, [], ()) for k, v in flat.items())


def parse_plant(values: Mapping[str, Any]) -> Plant:
    """A :class:`Plant` from the typed plant parameters (short names), or ConfigError."""
    model = parse_model(values.get("states"), values.get("inputs"), values.get("f"),
                        values.get("h"), values.get("constants"), values.get("unknown_inputs"),
                        prefix=PREFIX)
    plant = Plant(**vars(model))
    plant.constant_texts = list(values.get("constants") or [])
    plant.f_texts, plant.h_texts = list(values["f"]), list(values["h"])
    for key, names in (("units", plant.states), ("unknown_input_units", plant.unknown_inputs)):
        given_units = values.get(key) or []
        if given_units and len(given_units) != len(names):
            raise ConfigError(PREFIX + key, f"expected one unit per name ({len(names)}: "
                              f"{', '.join(names) or 'none'}), got {len(given_units)}")
    check_observable(plant)
    return plant


def resolve_plant(flat: Mapping[str, Any]) -> Plant:
    """The plant of the flat parameters (``plant.*`` keys), typed and parsed."""
    values = {k[len(PREFIX):]: v for k, v in flat.items() if k.startswith(PREFIX)}
    return parse_plant(resolve(PLANT_PARAMS, values, prefix=PREFIX))


def units_of(flat: Mapping[str, Any]) -> tuple[list[str], list[str], list[str]]:
    """(state units, unknown-input units, output units) of the flat parameters' plant
    block, '' where none is given: an output whose h is a state has that state's unit.
    Empty lists without units.  Read as given (the runner validates the block)."""
    states = list(flat.get(PREFIX + "states") or [])
    units = [str(u) for u in flat.get(PREFIX + "units") or []]
    ui_units = [str(u) for u in flat.get(PREFIX + "unknown_input_units") or []]
    if len(units) != len(states):
        return [], ui_units, []
    by_state = dict(zip(states, units))
    outputs = [by_state.get(str(h).strip(), "") for h in flat.get(PREFIX + "h") or []]
    return units, ui_units, outputs


def labelled(name: str, unit: str) -> str:
    """'q [rad]', or the name alone without a unit."""
    return f"{name} [{unit}]" if unit else name


class _Printer(StrPrinter):
    """sympy's text form with every float written exactly (repr), so printing and parsing
    again gives the same number; integers and rationals stay exact."""

    def _print_Float(self, expr):
        return repr(float(expr))


def to_text(expr: sympy.Expr, rename: Mapping[sympy.Symbol, sympy.Expr] | None = None) -> str:
    """``expr`` as text, symbols replaced by ``rename`` first (e.g. a measured state by y0)."""
    if rename:
        expr = expr.xreplace(dict(rename))
    return _Printer().doprint(expr)


def number(value) -> float:
    """A constant (sympy or numpy) as a float; ValueError if it is not a finite number."""
    v = float(value)
    if not math.isfinite(v):
        raise BadArgument(f"{value} is not finite")
    return v


def _undetectable(A: np.ndarray, C: np.ndarray):
    """(eigenvalue, state index) of a mode with Re >= 0 that the output does not see (PBH),
    or None when (A, C) is detectable."""
    n = A.shape[0]
    for lam in np.linalg.eigvals(A):
        if lam.real < -1e-9:
            continue
        pbh = np.vstack([A - lam * np.eye(n), C])
        _, s, vh = np.linalg.svd(pbh)
        tol = max(pbh.shape) * np.finfo(float).eps * max(s[0], 1.0) * 1e3
        if np.sum(s > tol) < n:
            return lam, int(np.argmax(np.abs(vh[-1])))
    return None


def check_observable(plant: Plant, points: int = 4, seed: int = 7) -> None:
    """Refuse a plant whose linearisation (df/dx, dh/dx) has, at every one of a few seeded
    random points (states and inputs standard normal, unknown inputs 0), a mode with
    Re >= 0 that the output does not see (PBH): no observer can recover it.  Unobservable
    but stable modes are left to the observers that accept them (hosm, strongly
    detectable plants); each derivation checks what its paper needs.  Points where f or h
    is not defined are skipped; when none is defined nothing is decided here."""
    n = plant.n
    jac = sympy.lambdify([plant.x, plant.u],
                         [sympy.Matrix(plant.nominal(plant.f)).jacobian(plant.x),
                          sympy.Matrix(plant.h).jacobian(plant.x)], modules="numpy", cse=True)
    rng = np.random.default_rng(seed)
    hidden = None
    for _ in range(points):
        try:
            with np.errstate(all="ignore"):
                A, C = (np.asarray(M, dtype=float).reshape(shape) for M, shape in
                        zip(jac(rng.standard_normal(n), rng.standard_normal(plant.m)),
                            ((n, n), (plant.p, n))))
        except (ValueError, ZeroDivisionError, OverflowError, TypeError):
            continue
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(C))):
            continue
        hidden = _undetectable(A, C)
        if hidden is None:
            return
    if hidden is not None:
        lam, j = hidden
        raise ConfigError(PREFIX + "h", f"the plant is not observable from h: its linearisation "
                          f"has a mode at {complex(lam).real:.4g}"
                          + (f"{complex(lam).imag:+.4g}j" if abs(complex(lam).imag) > 1e-12 else "")
                          + f" that the output never sees ({plant.states[j]} does not show in "
                          "the output), at every point tried")


def compiled(plant: Plant):
    """(f(x, u, d) -> tuple, h(x, u) -> tuple): the plant compiled once (math functions), for
    simulating it (fto-simulate) and for tests."""
    from ..core.expressions import compile_exprs
    return (compile_exprs(plant.f, (plant.x, plant.u, plant.d)),
            compile_exprs(plant.h, (plant.x, plant.u)))
