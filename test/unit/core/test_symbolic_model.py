"""core/symbolic_model.py: the observability map (2)-(3) of Possieri, Vidano & Novara 2020
derived from text, against hand derivations (example (22), the DC motor), the paper's
bounds (16) on J'J for example (22), and the refusals (singular / malformed models)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import sympy

from fto_ros.core.errors import ConfigError
from fto_ros.core.symbolic_model import SymbolicModel
from fto_ros.models import possieri_example as pe

DC_CONSTANTS = ["b0=40", "b1=15", "a1=35", "a2=1", "a3=36.4", "a4=200"]
DC_F = ["q_dot", "b1*current - a1*sin(q) - a2*q_dot", "b0*V - a3*q_dot - a4*current"]


def example():
    return SymbolicModel(["x1", "x2"], ["u"], list(pe.F_TEXT), [pe.H_TEXT])


def test_example22_map_matches_the_paper_closed_form():
    m = example()
    rng = np.random.default_rng(1)
    for _ in range(50):
        x = rng.uniform(-3, 3, 2)
        u, du = rng.uniform(-10, 10, 2)
        ue = [u, du, 0.0]
        O, J, G = (lambda e: (e[:2], np.reshape(e[2:6], (2, 2)), e[6:]))(m.evaluate(list(x), ue))
        np.testing.assert_allclose(O, pe.observability_map(x, u), rtol=1e-12, atol=1e-12)
        # J by hand: d/dx of [x1 + 1/s, u x1 + (u+1)/s + u + x1 + x2], s = x2^2 + 1
        s = x[1] ** 2 + 1
        a = -2 * x[1] / s ** 2
        np.testing.assert_allclose(J, [[1, a], [u + 1, (u + 1) * a + 1]], rtol=1e-12, atol=1e-12)
        assert np.linalg.det(J) == pytest.approx(1.0, abs=1e-9)       # det J = 1 everywhere
        # G = dO/du_e u_e^(1,n) = [0, u' (x1 + 1/s + 1)]
        np.testing.assert_allclose(G, [0.0, du * (x[0] + 1 / s + 1)], rtol=1e-12, atol=1e-12)
    assert m.input_orders == [1] and m.uses_input_derivatives


def test_example22_jacobian_bounds_reproduce_the_paper():
    """Section V: 0.00529 I <= J'J <= 188.753 I for |u_e| <= 10 (J depends on x2 and u)."""
    m = example()
    rep = m.check([0.0, 0.0], [0.0] * 3, box=[0, 0, -3, 3], input_box=[-10, 10], grid=101)
    assert rep["box_min_sigma2"] == pytest.approx(0.00529, rel=0.02)
    assert rep["box_max_sigma2"] == pytest.approx(188.753, rel=0.005)


def test_dc_motor_map_matches_hand_derivation():
    m = SymbolicModel(["q", "q_dot", "current"], ["V"], DC_F, ["q"], DC_CONSTANTS)
    q, qd, cur = m.x
    expect = [q, qd, 15 * cur - 35 * sympy.sin(q) - qd]
    assert all(sympy.simplify(a - b) == 0 for a, b in zip(m.O, expect))
    assert m.input_orders == [-1] and not m.uses_input_derivatives    # O does not see V
    J = m.jacobian([0.3, 1.0, 2.0], [0.0] * 4)
    np.testing.assert_allclose(J, [[1, 0, 0], [0, 1, 0], [-35 * math.cos(0.3), -1, 15]], atol=1e-12)


def test_constants_can_build_on_each_other():
    m = SymbolicModel(["x"], [], ["-k2*x"], ["x"], ["k=2", "k2=k**2 + sin(0)"])
    assert m.constants == {"k": 2.0, "k2": 4.0}
    assert m.evaluate([1.0], [])[0] == 1.0


@pytest.mark.parametrize("f,h,x0,msg", [
    (["x1", "x2"], ["x1"], [0, 0], "rank 1 < 2"),             # x2 never reaches y
    (["x2", "-x1"], ["x1**3"], [0, 0], "rank 0 < 2"),          # singular at x_hat(0) = 0
])
def test_singular_map_at_the_initial_estimate_is_refused(f, h, x0, msg):
    m = SymbolicModel(["x1", "x2"], [], f, h, prefix="newton_inversion.")
    with pytest.raises(ConfigError) as e:
        m.check(x0, [], prefix="newton_inversion.")
    assert e.value.parameter == "newton_inversion.h" and msg in str(e.value)
    assert "x_hat(0)" in str(e.value)


def test_singular_map_over_the_box_is_refused():
    m = SymbolicModel(["x1", "x2"], [], ["x2", "-x1"], ["x1**3"], prefix="newton_inversion.")
    m.check([1.0, 0.0], [])                                    # fine at x_hat(0)
    with pytest.raises(ConfigError) as e:
        m.check([1.0, 0.0], [], box=[-1, 1, -1, 1], grid=5, prefix="newton_inversion.")
    assert e.value.parameter == "newton_inversion.check_box" and "x = [0" in str(e.value)


@pytest.mark.parametrize("states,inputs,f,h,consts,param", [
    (["x1"], [], ["sin("], ["x1"], [], "f[0]"),
    (["x1"], [], ["x3"], ["x1"], [], "f[0]"),                      # unknown name
    (["x1"], [], ["__import__('os')"], ["x1"], [], "f[0]"),
    (["x1"], [], ["x1.real"], ["x1"], [], "f[0]"),
    (["x1"], [], ["foo(x1)"], ["x1"], [], "f[0]"),
    (["x1", "x2"], [], ["x1"], ["x1"], [], "f"),                   # one f per state
    (["x1"], [], ["x1"], ["x1", "x1"], [], "h"),                   # single output
    (["x1"], [], ["x1"], [], [], "h"),
    (["sin"], [], ["sin"], ["sin"], [], "states"),                 # reserved name
    (["x1", "x1"], [], ["x1", "x1"], ["x1"], [], "states"),        # duplicate
    (["x1"], ["x1"], ["x1"], ["x1"], [], "inputs"),
    (["lambda"], [], ["1"], ["1"], [], "states"),                  # keyword
    ([], [], [], ["1"], [], "states"),
    (["x1"], [], ["x1"], ["x1"], ["a1"], "constants[0]"),          # not name=value
    (["x1"], [], ["x1"], ["x1"], ["a1=x1"], "constants[0]"),       # not a number
    (["x1"], [], ["1/(x1 - x1)"], ["x1"], [], "f[0]"),             # zoo
])
def test_malformed_models_are_refused(states, inputs, f, h, consts, param):
    with pytest.raises(ConfigError) as e:
        SymbolicModel(states, inputs, f, h, consts, prefix="newton_inversion.")
    assert e.value.parameter == "newton_inversion." + param, str(e.value)


def test_undefined_points_give_none_not_an_exception():
    m = SymbolicModel(["x1", "x2"], [], ["x2", "-x1"], ["log(x1)"])
    assert m.evaluate([-1.0, 0.0], []) is None
    assert m.observation([-1.0, 0.0], []) is None
