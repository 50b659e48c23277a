"""prescribed_time (Holloway & Krstic 2019): the paper's design and its refusals.

- **Design** (eq. 18-23, Proposition 1, Lemma 4): p_bar from the recursion equals the
  closed form exactly (rational arithmetic); the gains are i-th order polynomials in mu_1
  and, for n = 2, the paper's closed forms g1 = l1 + 2 (m+2)/T mu1,
  g2 = l2 + l1 (m+2)/T mu1 + (m+1)(m+2)/T^2 mu1^2.
- **The step is exact**: Lemma 1's transformation gives the error system's transition
  matrix in closed form; it is checked against a stiff ODE solver and, near T (where the
  gains are 1e6..1e40), against the same formula in 60-digit arithmetic.

(Example 1, the third-order example and Theorem 1 on random configurations:
test_prescribed_time_theorem1.py; continuous operation: test_prescribed_time_operation.py;
the live node: test/system/test_prescribed_time_live.py; the cases: test/support/
prescribed_time_cases.py.)
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fto_ros.core.errors import ConfigError
from fto_ros.models.canonical_form import CanonicalPlant
from fto_ros.observers import REGISTRY
from fto_ros.observers.prescribed_time import (PrescribedTimeObserver, c_matrix,
                                               gain_coefficients, p_bar, p_bar_closed_form)
from fto_ros.runner import Runner, load_params_file
from prescribed_time_cases import DI_CONFIG, EXAMPLE1_M, make


# -------------------------------------------------------------------- the paper's design
@pytest.mark.parametrize("n", range(1, 9))
@pytest.mark.parametrize("m", [1, 2, 3, 5, 10])
def test_pbar_recursion_equals_proposition_1(n, m):
    """(18)-(21) via Remark 1's algorithm == Proposition 1's closed form, exactly."""
    for T in (Fraction(1), Fraction(5), Fraction(7, 3)):
        closed = p_bar_closed_form(n, m, T)
        C = c_matrix(n, m)
        for i in range(n):
            for j in range(n):
                rec = Fraction(C[i][j]) / T ** (i - j) if j <= i else Fraction(0)
                assert rec == closed[i][j], (n, m, T, i, j)
    # and the float version used by the observer
    assert np.allclose(p_bar(n, m, 2.5), np.array(p_bar_closed_form(n, m, Fraction(5, 2)), float),
                       rtol=1e-14, atol=0)


def test_example1_design_constants():
    """Example 1: p11 = p22 = 1, p12 = 0, p21 = -(m+2)/T."""
    for m in EXAMPLE1_M:
        pb = p_bar(2, m, 5.0)
        assert pb[0, 0] == pb[1, 1] == 1.0 and pb[0, 1] == 0.0
        assert pb[1, 0] == pytest.approx(-(m + 2) / 5.0, rel=1e-15)


@pytest.mark.parametrize("m", EXAMPLE1_M)
@pytest.mark.parametrize("T, l1, l2", [(5.0, 1.0, 1.0), (0.7, 3.0, 2.0), (20.0, 0.5, 4.0)])
def test_gains_are_the_papers_closed_forms(m, T, l1, l2):
    H = gain_coefficients(2, m, T, [l1, l2])
    assert H[0].tolist() == pytest.approx([l1, 2 * (m + 2) / T, 0.0], rel=1e-14, abs=1e-14)
    assert H[1].tolist() == pytest.approx([l2, l1 * (m + 2) / T, (m + 1) * (m + 2) / T ** 2],
                                          rel=1e-14)
    obs = make(T=T, m=m, l=[l1, l2])
    for s in (0.0, 0.3 * T, 0.9 * T, 0.999 * T, T - 1e-9 * T):
        mu = T / (T - s)
        g = obs.gains_at(mu)
        assert g[0] == pytest.approx(l1 + 2 * (m + 2) / T * mu, rel=1e-13)
        assert g[1] == pytest.approx(l2 + l1 * (m + 2) / T * mu + (m + 1) * (m + 2) / T ** 2 * mu ** 2,
                                     rel=1e-13)


@pytest.mark.parametrize("n", range(1, 9))
def test_gains_are_ith_order_polynomials_lemma_4(n):
    H = gain_coefficients(n, 2, 1.5, np.poly(-np.arange(1, n + 1))[1:])
    for i in range(n):
        assert np.all(H[i, i + 2:] == 0.0)
        assert H[i, i + 1] > 0            # leading coefficient: the gains grow like mu^i


def test_gain_evaluation_does_not_allocate():
    """gains_at fills one preallocated buffer (no per-step allocation)."""
    obs = make()
    g1 = obs.gains_at(2.0)
    g2 = obs.gains_at(3.0)
    assert g1 is g2 is obs._g


@pytest.mark.parametrize("n, m, T, s0, s1", [
    (1, 1, 1.0, 0.0, 0.7), (2, 1, 5.0, 0.0, 1.0), (2, 3, 5.0, 4.0, 4.9), (3, 2, 2.0, 0.3, 1.8),
    (4, 1, 1.0, 0.1, 0.9), (5, 2, 3.0, 0.5, 2.5)])
def test_transition_is_the_error_system_lemma_1(n, m, T, s0, s1):
    """Phi from Lemma 1 == the error system (8)-(9) with the gains (22)-(23), integrated."""
    l = np.poly(-np.linspace(1.0, 2.0, n))[1:]
    obs = make(CanonicalPlant(tuple([0.0] * n), (1.0,)), T=T, m=m, l=l.tolist())
    A = np.diag(np.ones(n - 1), 1) if n > 1 else np.zeros((1, 1))

    def f(s, X):
        M = A.copy()
        M[:, 0] -= obs.gains_at(T / (T - s))
        return (M @ X.reshape(n, n)).ravel()
    sol = solve_ivp(f, (s0, s1), np.eye(n).ravel(), method="Radau", rtol=1e-12, atol=1e-14)
    ref = sol.y[:, -1].reshape(n, n)
    ours = np.column_stack([obs.transition_window(np.eye(n)[j], s0, s1) for j in range(n)])
    assert np.abs(ours - ref).max() <= 1e-8 * np.abs(ref).max()


def test_transition_precision_near_T_against_60_digits():
    """Near T the gains reach 1e6..1e40; the scaled product stays accurate (each entry
    compared on its natural scale max(1/(T - s), 1/h)^(i-j)): measured 1.6e-10 (n = 6),
    1.6e-8 (n = 8) and 4e-5 (n = 10, only within a few samples of T, which the default
    sampling limit never reaches): the cancellation inside P*^-1 e^(Lambda h) P* grows with
    the combinatorial entries of P* (up to 3e10 for n = 8, m = 20), no rescaling helps."""
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 60
    rng = np.random.default_rng(0)
    worst = {}
    for n in (2, 4, 6, 8, 10):
        for m in (1, 3, 10, 20):
            l = np.poly(-rng.uniform(0.5, 5, n))[1:]
            obs = make(CanonicalPlant(tuple([0.0] * n), (1.0,)), T=1.0, m=m, l=l.tolist())
            C = mp.matrix(c_matrix(n, m))
            Lam = mp.zeros(n, n)
            for i in range(n):
                Lam[i, 0] = -mp.mpf(l[i])
                if i + 1 < n:
                    Lam[i, i + 1] = 1
            for sa in (0.0, 0.5, 0.99, 0.999, 0.9995):
                h = 1e-3 if sa < 0.999 else 4e-4
                sb = sa + h

                def W(s):
                    mu = 1 / (1 - mp.mpf(s))
                    P = mp.matrix(n, n)
                    for i in range(n):
                        for j in range(i + 1):
                            P[i, j] = C[i, j] * mu ** (i - j)
                    return mu ** (n + m) * P
                ref = W(sb) ** -1 * mp.expm(Lam * mp.mpf(h)) * W(sa)
                ref = np.array(ref.tolist(), dtype=float)
                ours = np.column_stack([obs.transition_window(np.eye(n)[j], sa, sb) for j in range(n)])
                k = max(1.0 / (1.0 - sa), 1.0 / h)
                scale = np.array([[k ** (i - j) for j in range(n)] for i in range(n)])
                worst[n] = max(worst.get(n, 0.0), float(np.max(np.abs(ours - ref) / scale)))
    assert worst[2] < 1e-13 and worst[4] < 1e-11 and worst[6] < 1e-9 and worst[8] < 1e-7, worst
    assert worst[10] < 1e-3, worst


def test_window_ending_at_T_maps_every_error_to_zero():
    obs = make(CanonicalPlant((0.0,) * 4, (1.0,)), T=2.0, m=1)
    v = np.array([3.0, -1.0, 2.0, 5.0])
    assert np.all(obs.transition_window(v, 2.0 - 1e-3, 2.0) == 0.0)


# ------------------------------------------------------------------------ refusals
@pytest.mark.parametrize("over, name, words", [
    (dict(l=[1.0, -1.0]), "prescribed_time.l", "not Hurwitz"),
    (dict(l=[0.0, 1.0]), "prescribed_time.l", "not Hurwitz"),
    (dict(l=[1.0]), "prescribed_time.l", "expected n = 2"),
    (dict(T=0.0), "prescribed_time.T", "> 0"),
    (dict(T=-1.0), "prescribed_time.T", ">= 0"),
    (dict(a=[0.0]), "prescribed_time.a", "expected n = 2"),
    (dict(b=[1.0, 2.0]), "prescribed_time.b", "n - r + 1 = 1"),
    (dict(b=[0.0]), "prescribed_time.b", "nonzero"),
    (dict(relative_degree=3), "prescribed_time.relative_degree", "1..n"),
    (dict(n_inputs=0), "prescribed_time.b", "empty"),
    (dict(m=0), "prescribed_time.m", ">= 1"),
    (dict(t_stop=6.0), "prescribed_time.t_stop", "<= T"),
    (dict(g_max=1.0), "prescribed_time.g_max", "start at"),
    (dict(mode="constant"), "prescribed_time.mode", "g_max"),
    (dict(mode="forever"), "prescribed_time.mode", "one of"),
    (dict(state_names=["x"]), "prescribed_time.state_names", "expected 2"),
    (dict(state_map=[1.0, 2.0, 2.0, 4.0]), "prescribed_time.state_map", "invertible"),
    (dict(F=["sin(q)", "0"]), "prescribed_time.F[0]", "q"),
])
def test_bad_configuration_is_refused_with_the_parameter_name(over, name, words):
    with pytest.raises(ConfigError) as exc:
        make(**over)
    assert exc.value.parameter == name and words in str(exc.value), str(exc.value)


def test_refusals_reach_the_runner_as_one_line():
    flat = load_params_file(DI_CONFIG)
    flat["prescribed_time.l"] = [1.0, -2.0]
    with pytest.raises(ConfigError, match=r"parameter 'prescribed_time.l': .*not Hurwitz"):
        Runner(flat)


def test_registered_with_its_schema():
    assert REGISTRY["prescribed_time"] is PrescribedTimeObserver
    dims = {p.name for p in PrescribedTimeObserver.PARAMS if p.read_only}
    assert dims == {"n_states", "relative_degree", "n_inputs", "state_names"}
    assert all(p.description for p in PrescribedTimeObserver.PARAMS)
