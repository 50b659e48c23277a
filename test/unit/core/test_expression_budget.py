"""The cost budget of a model expression (core/expression_budget.py), checked on the parsed
tree before sympy sees the text (F5, F6), and names matched whole (F20).  The budget is
called here on the tree alone, so a broken budget fails these tests instead of hanging in
sympy; test/system/test_expression_bombs.py runs the issue's expressions through fto-design."""
from __future__ import annotations

import ast
import math

import pytest
import sympy

from fto_ros.core import expression_budget as B
from fto_ros.core.errors import ConfigError
from fto_ros.core.expressions import parse
from fto_ros.core.symbolic_model import check_names


def cost(text: str) -> B.Cost:
    return B.check(ast.parse(text, mode="eval"), text, "plant.f[1]")


def refused(text: str, *words: str) -> str:
    with pytest.raises(ConfigError) as info:
        cost(text)
    msg = str(info.value)
    assert msg.startswith("parameter 'plant.f[1]': ") and "\n" not in msg
    assert all(w in msg for w in words), msg
    return msg


@pytest.mark.parametrize("text,words", [
    # the expressions (F5, F6)
    ("((10**300)**1000)**1000", ("exponent", "powers of powers")),
    ("exp(exp(exp(exp(exp(exp(1))))))", ("nested 4 deep",)),
    ("(q_dot + current + q + V)**300", ("4.59e+06 terms",)),
    ("(q + V + 1)**1000*current", ("5.02e+05 terms",)),
    # their relatives
    ("((1/3)**1000)**1000", ("powers of powers",)),
    ("(q**40)**40", ("exponent 1.6e+03",)),
    ("2**(10*200)", ("exponent 2e+03",)),
    ("exp(exp(exp(exp(q))))", ("nested 4 deep",)),
    ("sinh(cosh(exp(exp(q))))", ("nested 4 deep",)),
    ("exp(exp(exp(exp(1))))*0 + q", ("nested 4 deep",)),
    ("exp(800)*exp(800)", ("not a finite real number",)),
    ("10**300*10**300", ("not a finite real number",)),
    ("(q + V + 1)**30*(q + current + 1)**30", ("2.46e+05 terms",)),
    ("sin((q + V + current + q_dot)**20)*(q + V)**20", ("terms",)),
    ("(1001/1000)**1000*q", ("digits",)),
    ("1/(q + V + 1)**200", ("terms",)),
])
def test_expensive_expressions_are_refused_in_one_line(text, words):
    refused(text, *words)


@pytest.mark.parametrize("text", [
    "q**1000", "(q + V + 1)**95*current", "exp(exp(exp(1)))*q", "-exp(-exp(q))",
    "1.001**1000*q", "(2/3)**1000*q", "2**(10*100)*q", "sqrt(q**2 + V**2)/(1 + q**2)**3",
    "Piecewise((q, q < 0), (q**2, True))", "(q**10)**10", "sin(q)*cos(V) + 35*sin(q)",
])
def test_reasonable_expressions_pass(text):
    c = cost(text)
    assert c.terms <= B.MAX_TERMS and c.power <= B.MAX_POWER


def test_the_term_count_of_a_power_of_a_sum_is_the_multinomial_count():
    assert f"{math.comb(303, 3):.3g}" in refused("(a + b + c + d)**300")   # C(k+e-1, e)
    assert cost("(a + b + c)**20").terms == pytest.approx(math.comb(22, 2), rel=1e-9)
    assert cost("(a + b)**10*(c + d + e)").terms == pytest.approx(11 * 3, rel=1e-9)
    assert cost("sin(a + b)*(c + d)").terms == 4


def test_a_constant_of_the_plant_block_is_bounded_too():
    from fto_ros.core.symbolic_model import parse_constants
    with pytest.raises(ConfigError) as info:
        parse_constants(["a=1", "b0=((10**300)**1000)**1000"], "plant.constants", set())
    assert "plant.constants[1]" in str(info.value) and "exponent" in str(info.value)


def test_parse_refuses_before_sympy_and_still_reads_the_rest():
    y = sympy.symbols("y0 u0", real=True)
    with pytest.raises(ConfigError, match="terms"):
        parse("(y0 + u0 + 1)**1000*u0", list(y), "luenberger.F[1]")
    assert parse("(y0 + u0)**2", list(y), "luenberger.F[1]") == (y[0] + y[1]) ** 2


@pytest.mark.parametrize("name", ["q\n", "q\r", "q ", " q", "q\nq", "q\t"])
def test_a_name_with_a_newline_or_space_is_refused(name):
    with pytest.raises(ConfigError) as info:
        check_names(["x", name], "plant.states", set())
    assert "plant.states" in str(info.value) and "not a valid name" in str(info.value)


def test_valid_names_pass():
    taken: set[str] = set()
    check_names(["q", "q_dot", "I2", "current"], "plant.states", taken)
    assert taken == {"q", "q_dot", "I2", "current"}
