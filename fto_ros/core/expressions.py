"""Known model terms given as text in a params file, compiled once to fast functions.

A user writes e.g. ``F1: ["-35*sin(y0)", "40*u0"]``; this module parses each string
with sympy against a closed vocabulary (the outputs ``y0..y{p-1}``, the inputs
``u0..u{m-1}``, numbers, ``pi``, ``E`` and the usual elementary functions), refuses
anything else with a message naming the parameter, and compiles the vector to one
plain-Python function ``f(y, u) -> tuple[float, ...]`` using ``math`` (a few
microseconds per call, no numpy allocation).
"""
from __future__ import annotations

import ast
import math
from typing import Callable, Sequence

import sympy
from sympy.parsing.sympy_parser import (convert_xor, parse_expr,
                                        standard_transformations)

from . import expression_budget
from .errors import ConfigError, short

#: functions a model expression may call
FUNCTIONS = {name: getattr(sympy, name) for name in (
    "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh",
    "exp", "log", "sqrt", "Abs", "sign", "Min", "Max", "Piecewise", "floor", "ceiling")}
FUNCTIONS["abs"] = sympy.Abs
FUNCTIONS["min"] = sympy.Min
FUNCTIONS["max"] = sympy.Max

_TRANSFORMS = standard_transformations + (convert_xor,)


def symbols(prefix: str, count: int) -> list[sympy.Symbol]:
    """``[prefix0, prefix1, ...]`` as real sympy symbols."""
    return [sympy.Symbol(f"{prefix}{i}", real=True) for i in range(count)]


#: the only Python syntax a model expression may use: arithmetic, names, numbers, calls
_NODES = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Call, ast.Name, ast.Load, ast.Constant,
          ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow, ast.BitXor, ast.USub, ast.UAdd, ast.Mod,
          # for Piecewise((expr, condition), ...): tuples and comparisons
          ast.Tuple, ast.Compare, ast.Lt, ast.Gt, ast.LtE, ast.GtE)


#: an expression longer than this (characters), with more AST nodes, or nested deeper, is
#: refused before anything evaluates it (a model term is a line, not a program)
MAX_CHARS = 2000
MAX_NODES = 600
MAX_DEPTH = 200
#: a literal exponent may not exceed this in magnitude (y0**1000 is fine, 9**99999999 is not)
MAX_EXPONENT = 1000.0


def _literal(node: ast.AST) -> float | None:
    """The value of a numeric literal, possibly signed; None for anything else."""
    sign = 1.0
    while isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        sign = -sign if isinstance(node.op, ast.USub) else sign
        node = node.operand
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) \
            and not isinstance(node.value, bool):
        try:
            return sign * float(node.value)
        except OverflowError:
            return math.inf
    return None


def _check_syntax(text: str, parameter: str) -> None:
    """Refuse anything but bounded arithmetic on names and numbers, BEFORE sympy evaluates it.

    sympy's parser runs the text as Python: attribute access, subscripts, lambdas,
    comparisons or boolean operators could reach the interpreter or be silently mis-read;
    exponent towers (10**10**10) and huge literal exponents make it compute numbers with
    billions of digits (a hang); a very long or deeply nested text makes it recurse
    without end; a constant, power or expansion over the cost budget (expression_budget.py)
    keeps it busy for minutes.  All are refused here, quickly, in one line.
    """
    if len(text) > MAX_CHARS:
        raise ConfigError(parameter, f"expression too long ({len(text)} characters; at most "
                          f"{MAX_CHARS})")
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        raise ConfigError(parameter, f"cannot parse {short(text)}: {exc.msg}") from None
    except (RecursionError, MemoryError, ValueError):
        raise ConfigError(parameter, f"expression nested too deeply (at most {MAX_DEPTH} "
                          "levels)") from None
    count = 0
    stack = [(tree, 0)]
    while stack:
        node, depth = stack.pop()
        count += 1
        if count > MAX_NODES:
            raise ConfigError(parameter, f"expression too large (more than {MAX_NODES} terms "
                              "and operators)")
        if depth > MAX_DEPTH:
            raise ConfigError(parameter, f"expression nested too deeply (at most {MAX_DEPTH} "
                              "levels)")
        if not isinstance(node, _NODES):
            raise ConfigError(parameter, f"{short(text)}: '{type(node).__name__}' is not allowed "
                              "in a model expression (arithmetic, numbers, names and function "
                              "calls only)")
        if isinstance(node, ast.Constant):
            if not isinstance(node.value, (int, float)):          # (True: Piecewise's otherwise)
                raise ConfigError(parameter, f"{short(text)}: only numeric constants are allowed")
            if isinstance(node.value, float) and not math.isfinite(node.value):
                raise ConfigError(parameter, f"{short(text)}: the constant {node.value} is not "
                                  "finite")
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.keywords:
                raise ConfigError(parameter, f"{short(text)}: only plain calls like sin(y0) are "
                                  "allowed")
            if node.func.id not in FUNCTIONS:
                raise ConfigError(parameter, f"{short(text)} calls unknown function(s) "
                                  f"{node.func.id}; allowed: {', '.join(sorted(FUNCTIONS))}")
        if isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Pow, ast.BitXor)):
            _check_power(node, text, parameter)
        stack.extend((child, depth + 1) for child in ast.iter_child_nodes(node))
    # what sympy would build: constants' sizes, powers of powers, nested exponentials, the
    # terms of the expansion (core/expression_budget.py)
    expression_budget.check(tree, text, parameter)


def _is_power(node: ast.AST) -> bool:
    return isinstance(node, ast.BinOp) and isinstance(node.op, (ast.Pow, ast.BitXor))


def _check_power(node: ast.BinOp, text: str, parameter: str) -> None:
    # '^' becomes '**' token by token, so a^b^c is read as a**(b**c): a tower too
    if any(_is_power(n) for n in ast.walk(node.right)) or (
            isinstance(node.op, ast.BitXor) and _is_power(node.left)):
        raise ConfigError(parameter, f"{short(text)}: exponent towers (a**b**c) are not allowed")
    exponent = _literal(node.right)
    if exponent is None:
        return          # an exponent with names: evaluated per sample, overflow is rejected there
    if abs(exponent) > MAX_EXPONENT:
        raise ConfigError(parameter, f"{short(text)}: the exponent {exponent:g} is too large "
                          f"(at most {MAX_EXPONENT:g} in magnitude)")
    base = _literal(node.left)
    if base is not None and base != 0 and abs(exponent) * math.log10(abs(base)) > 300:
        raise ConfigError(parameter, f"{short(text)}: the constant {short(base)}**{exponent:g} "
                          "is beyond double range")


def _check_finite_constants(expr: sympy.Expr, text: str, parameter: str) -> None:
    """Every constant part of expr (a subtree without symbols) must be a finite real number:
    1/0, log(0), exp(1000), sqrt(-1) are refused, whatever else the expression holds."""
    if expr.has(sympy.zoo, sympy.oo, -sympy.oo, sympy.nan):
        raise ConfigError(parameter, f"{short(text)} has a non-finite constant (a division by "
                          "zero, log(0), an infinity)")
    walk = sympy.preorder_traversal(expr)
    for node in walk:
        if node.free_symbols or isinstance(node, (sympy.Tuple, sympy.logic.boolalg.Boolean)):
            continue
        walk.skip()
        if isinstance(node, sympy.Number) and node.is_finite:
            continue
        try:
            value = complex(node.evalf(20))
        except (TypeError, ValueError, OverflowError, ZeroDivisionError):
            value = complex(math.nan)
        if value.imag != 0 or not math.isfinite(value.real):
            raise ConfigError(parameter, f"{short(text)}: its constant part {short(str(node))} "
                              f"is not a finite real number")


def parse(text: str, allowed: Sequence[sympy.Symbol], parameter: str) -> sympy.Expr:
    """Parse ``text`` as an expression in ``allowed`` symbols, or raise ConfigError."""
    if not isinstance(text, str) or not text.strip():
        raise ConfigError(parameter, "empty expression" if isinstance(text, str) or text is None
                          else f"expected an expression (text), got {short(text)}")
    _check_syntax(text.strip(), parameter)
    local = {s.name: s for s in allowed}
    local.update(FUNCTIONS)
    local.update({"pi": sympy.pi, "E": sympy.E})
    try:
        expr = parse_expr(text, local_dict=local, global_dict={"__builtins__": {}, **_sympy_atoms()},
                          transformations=_TRANSFORMS, evaluate=True)
    except Exception as exc:  # sympy raises many kinds on malformed text
        raise ConfigError(parameter, f"cannot parse {short(text)}: {exc.__class__.__name__}: "
                          f"{short(exc)}") from None
    if not isinstance(expr, sympy.Expr):
        raise ConfigError(parameter, f"{short(text)} is not a scalar expression")
    unknown = sorted(s.name for s in expr.free_symbols if s not in set(allowed))
    if unknown:
        raise ConfigError(parameter, f"{short(text)} uses unknown name(s) {', '.join(unknown)}; "
                          f"allowed: {', '.join(s.name for s in allowed) or 'none'}")
    bad = sorted({type(f).__name__ for f in expr.atoms(sympy.Function)
                  if type(f) not in set(FUNCTIONS.values())})
    if bad:
        raise ConfigError(parameter, f"{short(text)} calls unknown function(s) {', '.join(bad)}")
    _check_finite_constants(expr, text, parameter)
    return expr


def _sympy_atoms() -> dict:
    # what parse_expr's generated code needs to build numbers and symbols
    return {"Integer": sympy.Integer, "Float": sympy.Float, "Rational": sympy.Rational,
            "Symbol": sympy.Symbol}


class VectorFunction:
    """A vector of expressions in ``y`` (outputs) and ``u`` (inputs), compiled.

    ``f(y, u)`` returns a tuple of floats.  ``is_zero`` tells whether every
    component is identically zero (callers can skip it), ``exprs`` keeps the
    sympy expressions (for Jacobians and docs).
    """

    def __init__(self, texts: Sequence[str], n_outputs: int, n_inputs: int, parameter: str,
                 length: int | None = None):
        if length is not None and len(texts) != length:
            raise ConfigError(parameter, f"expected {length} expression(s), got {len(texts)}")
        self.y_syms = symbols("y", n_outputs)
        self.u_syms = symbols("u", n_inputs)
        allowed = self.y_syms + self.u_syms
        self.exprs = [parse(t, allowed, f"{parameter}[{i}]") for i, t in enumerate(texts)]
        self.is_zero = all(e == 0 for e in self.exprs)
        self.parameter = parameter
        self._fn: Callable = compile_exprs(self.exprs, (self.y_syms, self.u_syms))

    def __len__(self) -> int:
        return len(self.exprs)

    def __call__(self, y, u) -> tuple:
        try:
            return self._fn(y, u)
        except (ValueError, OverflowError, ZeroDivisionError):
            # math raises where numpy would give nan/inf (log(-1), exp(1000), 1/0):
            # report non-finite, the caller rejects the sample and keeps its state
            return (float("nan"),) * len(self.exprs)

    def jacobian_y(self) -> list[list[sympy.Expr]]:
        """d f_i / d y_j as sympy expressions."""
        return [[sympy.diff(e, s) for s in self.y_syms] for e in self.exprs]


class NamedFunction:
    """Expressions over arbitrary named scalar symbols, compiled to one plain-Python function.

    ``NamedFunction(["-x1 + y**3"], ["y", "x1"], "global_norm.f")`` parses every text
    with :func:`parse` against exactly those names (anything else is refused with a
    ConfigError naming ``parameter[i]``) and compiles the tuple with
    ``sympy.lambdify(modules='math', cse=True)``; ``fn(*values)`` returns a tuple of
    floats (all NaN if ``math`` raises, e.g. log(-1) or an overflow).  ``exprs`` keeps
    the sympy expressions, ``syms`` the symbols (in the order of ``names``), so callers
    can differentiate or substitute them.
    """

    def __init__(self, texts: Sequence[str], names: Sequence[str], parameter: str,
                 length: int | None = None):
        if length is not None and len(texts) != length:
            raise ConfigError(parameter, f"expected {length} expression(s), got {len(texts)}")
        self.syms = [sympy.Symbol(n, real=True) for n in names]
        self.exprs = [parse(t, self.syms, f"{parameter}[{i}]" if len(texts) > 1 else parameter)
                      for i, t in enumerate(texts)]
        self.parameter = parameter
        self._fn = compile_exprs(self.exprs, self.syms)

    def __len__(self) -> int:
        return len(self.exprs)

    def __call__(self, *values) -> tuple:
        try:
            return self._fn(*values)
        except (ValueError, OverflowError, ZeroDivisionError, TypeError):
            return (float("nan"),) * len(self.exprs)


def compile_exprs(exprs: Sequence[sympy.Expr], args: Sequence) -> Callable:
    """``fn(*values) -> tuple`` of the sympy ``exprs`` over ``args`` (lambdify, math, cse).

    ``args`` are symbols, or groups (lists) of symbols passed as one sequence each, as in
    ``fn(y, u)``."""
    return sympy.lambdify(list(args), tuple(exprs), modules="math", cse=True)
