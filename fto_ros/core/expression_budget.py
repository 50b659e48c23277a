"""The cost budget of a model expression, checked on its parsed Python tree before sympy sees
the text (core/expressions.py calls :func:`check` after the syntax check).

sympy computes exactly: a constant such as ``((10**300)**1000)**1000`` or
``exp(exp(exp(exp(exp(exp(1))))))`` is a number with billions of digits, and a term such as
``(q + V + 1)**1000*current`` is harmless as text but expands (the plant derivations expand
and differentiate) into half a million terms.  Either kept fto-design and every start from
that params file busy for minutes with no output.  This module estimates, from the tree
alone and in microseconds, what sympy would build, and refuses beyond the budget:

- **constants**: every constant sub-expression is evaluated in floating point as it is
  built (``cmath``; an overflow is a refusal: a model constant beyond double range cannot be
  used), and the decimal digits of its exact value are bounded (an exact product or sum
  adds the digits of its operands, an integer power multiplies them by the exponent): at
  most :data:`MAX_DIGITS`;
- **powers**: the exponents along a power of a power multiply (``(a**100)**100`` is
  ``a**10000``): their product at most :data:`MAX_POWER`;
- **exponentials**: ``exp``, ``sinh``, ``cosh`` nested at most :data:`MAX_EXP_NESTING` deep;
- **expansion**: the number of terms the full expansion would have, counted up the tree (a
  sum adds its operands' counts, a product multiplies them, a sum of k terms to an integer
  power e makes C(k+e-1, e) terms, a function call counts its arguments' terms): at most
  :data:`MAX_TERMS`.

A refusal is one ConfigError line naming the parameter.  ROS-free.
"""
from __future__ import annotations

import ast
import cmath
import math
from dataclasses import dataclass

from .errors import ConfigError, short

#: most decimal digits of an exact constant (numerator and denominator together; Python
#: prints no integer of more than 4300 digits)
MAX_DIGITS = 4000
#: largest product of the exponents along a power of a power
MAX_POWER = 1000
#: deepest nesting of exponential functions (exp, sinh, cosh)
MAX_EXP_NESTING = 3
#: most terms the full expansion of an expression may have
MAX_TERMS = 5000

_EXPONENTIAL = {"exp", "sinh", "cosh"}
_CMATH = {"sin": cmath.sin, "cos": cmath.cos, "tan": cmath.tan, "asin": cmath.asin,
          "acos": cmath.acos, "atan": cmath.atan, "sinh": cmath.sinh, "cosh": cmath.cosh,
          "tanh": cmath.tanh, "exp": cmath.exp, "log": cmath.log, "sqrt": cmath.sqrt,
          "Abs": abs, "abs": abs}
_NAMED = {"pi": math.pi, "E": math.e}
_LOG10_2 = math.log10(2)


@dataclass(frozen=True)
class Cost:
    """What a sub-expression would cost sympy.  ``value``: its value when it is a constant
    (None: not a constant, or not known here); ``digits``: of its exact value (an exact
    constant: integers and their ratios, sums, products and integer powers; 0 for the rest:
    a floating-point number has a fixed precision);
    ``power``: the product of the exponents along its powers; ``nesting``: of exponentials;
    ``terms``: of its full expansion."""

    value: complex | None = None
    constant: bool = False
    digits: float = 0.0
    power: float = 1.0
    nesting: int = 0
    terms: float = 1.0


class _Budget:
    def __init__(self, text: str, parameter: str, names: frozenset[str]):
        self.text, self.parameter, self.names = text, parameter, names

    def refuse(self, what: str) -> None:
        raise ConfigError(self.parameter, f"{short(self.text)}: {what}")

    # ---------------------------------------------------------------- the tree, bottom up
    def cost(self, node: ast.AST) -> Cost:
        if isinstance(node, ast.Expression):
            return self.cost(node.body)
        if isinstance(node, ast.Constant):
            return self._constant(node.value)
        if isinstance(node, ast.Name):
            if node.id in _NAMED and node.id not in self.names:
                return Cost(value=_NAMED[node.id], constant=True)
            return Cost()
        if isinstance(node, ast.UnaryOp):
            c = self.cost(node.operand)
            value = None if c.value is None else (-c.value if isinstance(node.op, ast.USub)
                                                  else c.value)
            return Cost(value, c.constant, c.digits, c.power, c.nesting, c.terms)
        if isinstance(node, ast.BinOp):
            left, right = self.cost(node.left), self.cost(node.right)
            if isinstance(node.op, (ast.Pow, ast.BitXor)):
                return self._power(left, right, node.right)
            return self._arithmetic(node.op, left, right)
        if isinstance(node, ast.Call):
            return self._call(node)
        # Piecewise's tuples and comparisons: their parts, side by side
        parts = [self.cost(c) for c in ast.iter_child_nodes(node)]
        return Cost(terms=sum(p.terms for p in parts) or 1.0,
                    nesting=max((p.nesting for p in parts), default=0),
                    power=max((p.power for p in parts), default=1.0))

    def _constant(self, value) -> Cost:
        if isinstance(value, bool):
            return Cost(value=complex(value), constant=True)
        if isinstance(value, int):
            digits = max(1, abs(value).bit_length()) * _LOG10_2
            self._digits(digits)
            return Cost(value=self._finite(lambda: complex(value)), constant=True, digits=digits)
        return Cost(value=complex(value), constant=True)

    def _arithmetic(self, op: ast.operator, a: Cost, b: Cost) -> Cost:
        constant = a.constant and b.constant
        exact = constant and a.digits > 0 and b.digits > 0
        digits = a.digits + b.digits if exact else 0.0
        self._digits(digits)
        value = None
        if a.value is not None and b.value is not None:
            x, y = a.value, b.value
            value = self._finite({ast.Add: lambda: x + y, ast.Sub: lambda: x - y,
                                  ast.Mult: lambda: x * y, ast.Div: lambda: x / y,
                                  ast.Mod: lambda: None}.get(type(op), lambda: None))
        if isinstance(op, (ast.Add, ast.Sub, ast.Mod)):
            terms = a.terms + b.terms
        else:                                  # a product (a quotient: its denominator too)
            terms = a.terms * b.terms
        return self._checked(Cost(value, constant, digits, max(a.power, b.power),
                                  max(a.nesting, b.nesting), terms))

    def _power(self, base: Cost, exp: Cost, exp_node: ast.AST) -> Cost:
        e = exp.value.real if exp.value is not None and exp.value.imag == 0 else None
        literal = e is not None and exp.constant
        size = abs(e) if literal else 1.0
        power = max(base.power, 1.0) * max(size, exp.power)
        if power > MAX_POWER:
            self.refuse(f"the exponent {_num(power)} is too large (powers of powers multiply: "
                        f"at most {MAX_POWER})")
        constant = base.constant and exp.constant
        exact = constant and base.digits > 0 and exp.digits > 0
        whole = literal and float(size).is_integer()
        digits = (base.digits * (size if whole else 1.0) + exp.digits) if exact else 0.0
        self._digits(digits)
        value = None
        if base.value is not None and exp.value is not None:
            b, x = base.value, exp.value
            value = self._finite(lambda: 0j if b == 0 and x.real > 0 else b ** x)
        if literal:
            terms = _multinomial(base.terms, math.floor(size))
        else:
            terms = base.terms * exp.terms
        return self._checked(Cost(value, constant, digits, power,
                                  max(base.nesting, exp.nesting), terms))

    def _call(self, node: ast.Call) -> Cost:
        name = node.func.id if isinstance(node.func, ast.Name) else ""
        args = [self.cost(a) for a in node.args]
        nesting = max((a.nesting for a in args), default=0) + (name in _EXPONENTIAL)
        if nesting > MAX_EXP_NESTING:
            self.refuse(f"exponentials nested {nesting} deep (exp, sinh, cosh: at most "
                        f"{MAX_EXP_NESTING})")
        constant = bool(args) and all(a.constant for a in args)
        value = None
        fn = _CMATH.get(name)
        if fn is not None and len(args) == 1 and args[0].value is not None:
            x = args[0].value
            value = self._finite(lambda: fn(x))
        return self._checked(Cost(value, constant, 0.0,
                                  max((a.power for a in args), default=1.0), nesting,
                                  sum(a.terms for a in args) or 1.0))

    # ---------------------------------------------------------------- the limits
    def _finite(self, compute) -> complex | None:
        """The value ``compute()`` gives in floating point; a refusal when it overflows;
        None when it is not a number here (a division by zero, a domain error: sympy
        and the later checks decide)."""
        try:
            value = compute()
        except OverflowError:
            value = complex(math.inf)
        except (ZeroDivisionError, ValueError, TypeError):
            return None
        if value is None:
            return None
        value = complex(value)
        if math.isinf(value.real) or math.isinf(value.imag):
            self.refuse("a constant part is not a finite real number (beyond double range, "
                        "|value| > 1.8e308)")
        return None if cmath.isnan(value) else value

    def _digits(self, digits: float) -> None:
        if digits > MAX_DIGITS:
            self.refuse(f"a constant part would have about {_num(digits)} digits (at most "
                        f"{MAX_DIGITS})")

    def _checked(self, c: Cost) -> Cost:
        if c.terms > MAX_TERMS:
            self.refuse(f"expanded it would have about {_num(c.terms)} terms (at most "
                        f"{MAX_TERMS}); write it factored into smaller parts, or expand "
                        "it by hand")
        return c


def _multinomial(k: float, e: int) -> float:
    """Terms of (a sum of k terms) ** e expanded: C(k + e - 1, e)."""
    if k <= 1 or e <= 1:
        return k if e >= 1 else 1.0
    if k > 1e6:
        return math.inf
    lg = math.lgamma(k + e) - math.lgamma(e + 1) - math.lgamma(k)
    return math.inf if lg > 700 else math.exp(lg)


def _num(x: float) -> str:
    return "infinitely many" if math.isinf(x) else f"{x:.3g}"


def check(tree: ast.AST, text: str, parameter: str, names=()) -> Cost:
    """Refuse (ConfigError naming ``parameter``) an expression over the budget; its cost.
    ``names``: the symbols the expression may use (they shadow ``pi`` and ``E``)."""
    return _Budget(text, parameter, frozenset(names)).cost(tree)
