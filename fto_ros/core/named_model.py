"""A plant written as text in its own names, parsed once (ROS-free).

``x' = f(x, u, d)``, ``y = h(x, u)`` with named states x, known inputs u, unknown inputs d
and named constants, every expression parsed by :func:`fto_ros.core.expressions.parse`
against exactly those names (anything else is refused naming ``<prefix>f[i]``), names and
constants checked by :mod:`fto_ros.core.symbolic_model`.  Shared by the plant block
(``fto_ros.plant``) and the observers that take the model as text (``ekf``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import sympy

from .errors import ConfigError
from .expressions import parse
from .symbolic_model import MAX_NAMES, check_names, parse_constants


@dataclass
class NamedModel:
    """The parsed model.  ``f``, ``h`` have the constants substituted as numbers; ``f_raw``
    keeps them as symbols (to write the model back as text with its constants)."""

    states: list[str]
    inputs: list[str]
    unknown_inputs: list[str]
    constants: dict[str, float]
    x: list[sympy.Symbol]
    u: list[sympy.Symbol]
    d: list[sympy.Symbol]
    f: list[sympy.Expr]
    h: list[sympy.Expr]
    f_raw: list[sympy.Expr]

    @property
    def n(self) -> int:
        return len(self.states)

    @property
    def m(self) -> int:
        return len(self.inputs)

    @property
    def p(self) -> int:
        return len(self.h)

    @property
    def q(self) -> int:
        return len(self.d)

    def nominal(self, exprs: Sequence[sympy.Expr]) -> list[sympy.Expr]:
        """``exprs`` with every unknown input set to zero (the nominal plant)."""
        zero = {s: sympy.Integer(0) for s in self.d}
        return [e.xreplace(zero) for e in exprs]


def parse_model(states: Sequence[str] | None, inputs: Sequence[str] | None,
                f: Sequence[str] | None, h: Sequence[str] | None,
                constants: Sequence[str] | None = (), unknown_inputs: Sequence[str] | None = (),
                prefix: str = "") -> NamedModel:
    """Parse and check a model; ConfigError names ``<prefix><parameter>``."""
    P = prefix
    if not states:
        raise ConfigError(P + "states", "missing: name the states, e.g. [q, q_dot, current]")
    if not f:
        raise ConfigError(P + "f", f"missing: one expression per state ({', '.join(states)})")
    if not h:
        raise ConfigError(P + "h", "missing: one expression per measured output, e.g. [q]")
    states, inputs, unknown = list(states), list(inputs or []), list(unknown_inputs or [])
    taken: set[str] = set()
    check_names(states, P + "states", taken)
    check_names(inputs, P + "inputs", taken)
    check_names(unknown, P + "unknown_inputs", taken)
    n = len(states)
    if len(f) != n:
        raise ConfigError(P + "f", f"expected {n} expression(s), one per state "
                          f"({', '.join(states)}), got {len(f)}")
    if len(h) > MAX_NAMES:
        raise ConfigError(P + "h", f"{len(h)} outputs: at most {MAX_NAMES}")
    consts = parse_constants(list(constants or []), P + "constants", taken)
    x = [sympy.Symbol(s, real=True) for s in states]
    u = [sympy.Symbol(s, real=True) for s in inputs]
    d = [sympy.Symbol(s, real=True) for s in unknown]
    c = [sympy.Symbol(k, real=True) for k in consts]
    subs = {s: sympy.Float(consts[s.name]) for s in c}
    f_raw = [parse(t, x + u + d + c, f"{P}f[{i}]") for i, t in enumerate(f)]
    f_expr = [e.xreplace(subs) for e in f_raw]
    h_expr = []
    for i, t in enumerate(h):
        e = parse(t, x + u + d + c, f"{P}h[{i}]").xreplace(subs)
        if e.free_symbols & set(d):
            raise ConfigError(f"{P}h[{i}]", f"{t!r} uses an unknown input: outputs may depend on "
                              "the states and the known inputs only")
        h_expr.append(e)
    for name, exprs, texts in (("f", f_expr, f), ("h", h_expr, h)):
        for i, e in enumerate(exprs):
            if e.has(sympy.zoo, sympy.nan, sympy.oo, -sympy.oo):
                raise ConfigError(f"{P}{name}[{i}]", f"{texts[i]!r} is not finite (it "
                                  f"simplifies to {e})")
    return NamedModel(states=states, inputs=inputs, unknown_inputs=unknown, constants=consts,
                      x=x, u=u, d=d, f=f_expr, h=h_expr, f_raw=f_raw)
