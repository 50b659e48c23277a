"""hosm observer (Fridman, Levant & Davila 2007): structure checks, the paper's examples, MIMO,
known output terms and config validation.  (Transactional updates, the configs and bags, a
large design and M from a recording: test_hosm_operation.py; the cases: test/support/
hosm_cases.py.)

Ground truth comes from an exact simulation: zeta(t) is a sum of sinusoids, i.e. the output of
a linear exosystem, so plant + exosystem is one linear system stepped with expm (machine
precision, no integrator tolerance in the comparison).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.core.params import resolve
from fto_ros.core.structure import StructureError, analyse, invariant_zeros, relative_degree
from fto_ros.models import fld_examples as fx
from fto_ros.observers import REGISTRY
from fto_ros.observers.base import ConfigError
from fto_ros.observers.hosm import HosmObserver
from hosm_cases import ex1, ex2, exo_traj, fld_traj, make, run


# -- structure ------------------------------------------------------------------------------
def test_registered():
    assert REGISTRY["hosm"] is HosmObserver


def test_structure_example1_matches_paper():
    st = analyse(fx.EXAMPLE1_A, fx.EXAMPLE1_C, fx.EXAMPLE1_D[:, None], fx.EXAMPLE1_L[:, None])
    assert st.r == [4] and st.strongly_observable and len(st.zeros) == 0
    # the paper's K = P~^-1 (Section 6.1.1)
    K = np.array([[1, 0, 0, 0], [5, 1, 0, 0], [5, 5, 1, 0], [5, 5, 5, 1]], dtype=float)
    np.testing.assert_allclose(st.Tinv, K, atol=1e-12)
    # (29): a_1..a_4 from det(sI - (A - LC)) = (s+1)(s+2)(s+3)(s+4) = s^4 + 10 s^3 + 35 s^2 + 50 s + 24
    np.testing.assert_allclose(st.G, [[-24, -50, -35, -10]], atol=1e-9)
    np.testing.assert_allclose(st.Q, [[1.0]])


def test_structure_example2_matches_paper():
    st = analyse(fx.EXAMPLE2_A, fx.EXAMPLE2_C, fx.EXAMPLE2_D[:, None], fx.EXAMPLE2_L[:, None])
    assert st.r == [3] and not st.strongly_observable
    assert st.n_observable == 4                      # "The observability matrix has rank 4"
    np.testing.assert_allclose(np.sort(st.zeros.real), [-3, -2, -1], atol=1e-8)
    np.testing.assert_allclose(np.sort(st.zeros_a22.real), [-3, -2, -1], atol=1e-8)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(fx.EXAMPLE2_A - np.outer(
        fx.EXAMPLE2_L, fx.EXAMPLE2_C)).real), [-4, -3, -3, -2, -1, -1], atol=1e-6)
    # T2 D = 0: zeta does not drive the zero dynamics
    assert np.abs(st.T[3:] @ fx.EXAMPLE2_D).max() < 1e-12


def test_rosenbrock_zeros_of_a_known_plant():
    # y/zeta = (s - 2)(s + 3) / ((s + 1)(s + 4)(s + 5)) in controllable canonical form
    den = np.poly([-1, -4, -5])
    A = np.zeros((3, 3))
    A[0, 1] = A[1, 2] = 1
    A[2] = -den[::-1][:3]
    C = np.array([np.poly([2, -3])[::-1]])
    D = np.array([[0.0], [0.0], [1.0]])
    np.testing.assert_allclose(np.sort(invariant_zeros(A, C, D).real), [-3, 2], atol=1e-8)
    assert relative_degree(A, C, D)[0] == [1]
    with pytest.raises(StructureError, match="not strongly detectable.*2") as exc:
        analyse(A, C, D, np.array([[10.0], [0.0], [0.0]]))
    assert exc.value.condition == "not_strongly_detectable"


def refused(match: str, **kw):
    with pytest.raises(ConfigError, match=match) as exc:
        make(**kw)
    return exc.value


def test_non_minimum_phase_plant_refused_naming_the_condition():
    # Example 2 with the zero dynamics' -1 turned into +1: invariant zero at +1
    A = fx.EXAMPLE2_A.copy()
    A[4, 4] = 1.0
    e = refused("not strongly detectable.*1", n_states=6, A=A.ravel().tolist(), C=[1.0, 0, 0, 0, 0, 0],
                D=fx.EXAMPLE2_D.tolist(), L=fx.EXAMPLE2_L.tolist(), M=[2.0])
    assert e.parameter == "hosm.D"


def test_no_relative_degree_refused():
    # zeta drives a state the output never sees
    e = refused("no relative degree", n_states=2, A=[-1.0, 0, 0, -2.0], C=[1.0, 0], D=[0.0, 1.0],
                poles=[-3.0, -4.0], M=[1.0])
    assert e.parameter == "hosm.D"


def test_more_unknown_inputs_than_outputs_refused():
    refused("expected a 3x1 matrix", n_states=3, A=[0.0, 1, 0, 0, 0, 1, 0, 0, 0], C=[1.0, 0, 0],
            D=[0.0, 1, 0, 0, 0, 1], poles=[-1.0, -2, -3], M=[1.0])


def test_singular_decoupling_matrix_refused():
    # two outputs, both see only zeta1 + zeta2: Q singular, no vector relative degree
    refused("vector relative degree does not exist", n_states=2, n_outputs=2,
            A=[-1.0, 0, 0, -2.0], C=[1.0, 0, 0, 1.0], D=[1.0, 1.0, 1.0, 1.0],
            L=[1.0, 0, 0, 1.0], M=[1.0])


def test_luenberger_not_hurwitz_refused():
    e = refused("not Hurwitz", n_states=4, A=fx.EXAMPLE1_A.ravel().tolist(), C=[1.0, 0, 0, 0],
                D=fx.EXAMPLE1_D.tolist(), L=[0.0, 0, 0, 0], M=[1.0])
    assert e.parameter == "hosm.L"


def test_M_below_the_paper_bound_refused():
    e = refused(r"M\[0\] = 0.5 is too small.*0.75", n_states=4, A=fx.EXAMPLE1_A.ravel().tolist(),
                C=[1.0, 0, 0, 0], D=fx.EXAMPLE1_D.tolist(), L=[5.0, 5, 5, 5], M=[0.5],
                smoothness_order=1, unknown_input_derivative_bound=[0.75])
    assert e.parameter == "hosm.M"
    # states only: M against zeta+ (Theorem 3.4); Example 1's M = 2 passes with zeta+ = 2 * 0.9
    assert "> 1.8" in ex1(M=[2.0], identify_unknown_input=False,
                          unknown_input_bound=[1.8]).diagnostics()["M check"]
    refused("M.*too small", n_states=4, A=fx.EXAMPLE1_A.ravel().tolist(), C=[1.0, 0, 0, 0],
            D=fx.EXAMPLE1_D.tolist(), L=[5.0, 5, 5, 5], M=[1.0], identify_unknown_input=False,
            unknown_input_bound=[1.8])


@pytest.mark.parametrize("kw, param", [
    (dict(M=[1.0, 2.0]), "hosm.M"),
    (dict(L=[5.0, 5.0]), "hosm.L"),
    (dict(L=[], poles=[-1.0, -2.0, 3.0, -4.0]), "hosm.poles"),
    (dict(L=[], poles=[]), "hosm.L"),
    (dict(D=[0.0, 0, 0, 0]), "hosm.D"),
    (dict(smoothness_order=4), "hosm.smoothness_order"),     # r + k = 8 > 7
    (dict(differentiator_gains=[1.1, 1.5, 2, 3, 5, 8]), "hosm.differentiator_gains"),
    (dict(differentiator_scheme="livne_levant", differentiator_gains=[1.1, 1.5]),
     "hosm.differentiator_gains"),
    (dict(F=["0", "0", "0", "bogus(y0)"]), "hosm.F[3]"),
    (dict(state_names=["a"]), "hosm.state_names"),
])
def test_bad_config_refused_naming_the_parameter(kw, param):
    with pytest.raises(ConfigError) as exc:
        ex1(**kw)
    assert exc.value.parameter == param


def test_unknown_parameter_refused():
    with pytest.raises(ConfigError, match="unknown parameter"):
        resolve(HosmObserver.PARAMS, {"n_states": 4, "Mm": 1}, "hosm.")


# -- Example 1: exact in finite time (Theorems 3.4, 3.8) ---------------------------------------
T1 = np.arange(8001) * 1e-3


@pytest.fixture(scope="module")
def example1():
    return fld_traj(1, T1)


def test_example1_exact_in_finite_time_noise_free(example1):
    """Noise-free 1 kHz samples: after the transient the state and zeta are exact to the float /
    discretisation floor (Theorem 3.9: e_Oi ~ tau^(n+k-i+2), zeta ~ tau^(k+1) = 1e-6 here; the
    unstable plant's |x| ~ 1e3 makes the round-off of y - C z (~1e-13) the floor)."""
    x, zeta = example1
    X, Z = run(ex1(), T1, x[:, :1])
    late = T1 >= 4.0
    err = np.abs(X - x)[late].max(axis=0)
    assert np.all(err < [1e-10, 1e-7, 1e-5, 1e-3]), err
    assert np.abs(Z - zeta)[late].max() < 1e-2
    # and it really was a transient: large errors at the start
    assert np.abs(X - x)[T1 < 1.0].max() > 1.0


def test_example1_states_only_and_discretisation_order(example1):
    """Section 6.1.1 observer (M = 2, no identification): exact after the transient; the x4 error
    (i = n: order tau^1) grows when the sampling step grows (Fig. 5)."""
    x, _ = example1
    X, Z = run(ex1(M=[2.0], identify_unknown_input=False), T1, x[:, :1])
    assert np.all(np.isnan(Z))
    late = T1 >= 4.0
    err = np.abs(X - x)[late].max(axis=0)
    assert np.all(err < [1e-10, 1e-6, 1e-4, 1e-2]), err
    t10 = np.arange(801) * 1e-2
    x10, _ = fld_traj(1, t10)
    X10, _ = run(ex1(M=[2.0], identify_unknown_input=False), t10, x10[:, :1])
    err10 = np.abs(X10 - x10)[(t10 >= 4.0)].max(axis=0)
    assert err10[1] > err[1]          # x2: tau^3 -> larger with the 10x step


def test_example1_irregular_sampling(example1):
    """Variable step (0.5..1.5 ms at random): still exact after the transient."""
    rng = np.random.default_rng(3)
    t = np.concatenate([[0.0], np.cumsum(rng.integers(500, 1501, 6000) * 1e-6)])
    x, zeta = fld_traj(1, t)
    X, Z = run(ex1(), t, x[:, :1])
    late = t >= 4.0
    assert np.abs(X - x)[late].max() < 2e-3
    assert np.abs(Z - zeta)[late].max() < 2e-2


def test_example1_noise_accuracy_order(example1):
    """Deterministic noise of amplitude eps (the paper's 0.1 sin(1037|cos 687t|), scaled):
    Theorem 3.8: e_O1 ~ eps (the x1 error stays below the noise) and the errors shrink with eps."""
    x, _ = example1
    noise = np.array([fx.example1_noise(s)[0] for s in T1])
    late = T1 >= 5.0
    errs = []
    for eps in (0.1, 0.01):
        X, _ = run(ex1(differentiator_rho=1.0), T1, (x[:, 0] + noise * eps / 0.1)[:, None])
        errs.append(np.abs(X - x)[late].max(axis=0))
    assert errs[0][0] < 0.1 and errs[1][0] < 0.01
    # x2: eps^(n+k)/(n+k+1) = eps^(5/6) -> about 6.8x per decade of eps; at least 4x measured
    assert errs[0][1] / errs[1][1] > 4.0


# -- Example 2: strongly detectable (Theorem 4.2 / 4.4) ----------------------------------------
def test_example2_first_r_canonical_coordinates_exact_rest_asymptotic():
    t = np.arange(5001) * 1e-3
    x, zeta = fld_traj(2, t)
    X, Z = run(ex2(), t, x[:, :1])
    Po = np.vstack([fx.EXAMPLE2_C @ np.linalg.matrix_power(fx.EXAMPLE2_A, i) for i in range(4)])
    eO = np.abs((X - x) @ Po.T)
    late = t >= 2.5
    # the first r = 3 canonical coordinates: exact (float/discretisation floor) in finite time
    assert np.all(eO[late, :3].max(axis=0) < [1e-9, 1e-6, 1e-4]), eO[late, :3].max(axis=0)
    # the 4th canonical coordinate, x5, x6 and zeta: asymptotic, at the zeros' rate (>= e^-1 per s)
    w1, w2 = (t >= 2.5) & (t < 3.0), (t >= 4.5)
    for err in (eO[:, 3], np.abs(X - x)[:, 4], np.abs(X - x)[:, 5], np.abs(Z - zeta)[:, 0]):
        assert err[w2].max() < err[w1].max() * math.exp(-1.0) * 1.5
        assert err[w1].max() > 1e-4           # not exact: this part is asymptotic only


# -- MIMO (Section 5) ---------------------------------------------------------------------------
def mimo_plant():
    """n = 5, two outputs, two unknown inputs, vector relative degree (2, 2), zero dynamics -2."""
    A = np.array([[0, 1, 0, 0, 0],
                  [1, 0.5, -2, 0, 1],
                  [0, 0, 0, 1, 0],
                  [0.5, 1, 0, -1, -1],
                  [1, 0, 1, 0, -2]], dtype=float)
    C = np.array([[1, 0, 0, 0, 0], [0, 0, 1, 0, 0]], dtype=float)
    D = np.array([[0, 0], [1, 0.5], [0, 0], [-0.3, 1], [0, 0]], dtype=float)
    return A, C, D


def test_mimo_vector_relative_degree_and_identification():
    A, C, D = mimo_plant()
    obs = make(n_states=5, n_outputs=2, A=A.ravel().tolist(), C=C.ravel().tolist(),
               D=D.ravel().tolist(), poles=[-2.0, -3, -4, -5, -6], M=[5.0, 5.0], smoothness_order=0)
    st = obs.structure
    assert st.r == [2, 2]
    np.testing.assert_allclose(st.Q, [[1, 0.5], [-0.3, 1]])
    np.testing.assert_allclose(st.zeros.real, [-2.0], atol=1e-8)
    t = np.arange(6001) * 1e-3
    x, zeta = exo_traj(A, D, np.array([1.0, -1, 0.5, 0, 2]), t, [1.0, 2.0],
                       [[(1.0, 0.0, 1.0)], [(2.0, 0.5, 0.0)]], [0.3, -0.2])
    X, Z = run(obs, t, x @ C.T)
    # canonical coordinates y1, y1', y2, y2': exact after the transient
    T1 = np.vstack([C[0], C[0] @ A, C[1], C[1] @ A])
    eO = np.abs((X - x) @ T1.T)
    late = t >= 4.0
    assert eO[late].max() < 1e-5, eO[late].max(axis=0)
    # x5 (zero dynamics, rate 2/s) and zeta: asymptotically exact
    assert np.abs(X - x)[t >= 5.5].max() < 1e-4
    assert np.abs(Z - zeta)[t >= 5.5].max() < 1e-3
    assert np.abs(Z - zeta)[t < 0.5].max() > 0.1


# -- known output term: the DC motor with a load torque ----------------------------------------
DC = dict(n_states=3, n_inputs=1, A=[0.0, 1, 0, 0, -1, 15, 0, -36.4, -200], B=[0.0, 0, 40],
          C=[1.0, 0, 0], D=[0.0, -15, 0], F=["0", "-35*sin(y0)", "0"], poles=[-100.0, -110, -120],
          M=[100.0], smoothness_order=0, state_names=["q", "q_dot", "current"])


@pytest.fixture(scope="module")
def dc_load():
    from fto_ros.models import dc_motor_load
    from fto_ros.models.simulate import simulate, uniform_grid
    spec = dc_motor_load.SPEC
    t = uniform_grid(1.5, 1000.0)
    sim = simulate(spec.make_rhs(dict(spec.default_params)), spec.default_x0, t, spec.default_input)
    tau = np.array([dc_motor_load.load_torque(s)[0] for s in t])
    return t, sim, tau


def test_dc_motor_known_output_term_and_load_torque(dc_load):
    t, sim, tau = dc_load
    obs = make(**DC)
    assert obs.structure.r == [2]
    np.testing.assert_allclose(obs.structure.zeros.real, [-200.0], rtol=1e-8)
    X, Z = run(obs, t, sim.x[:, :1], sim.u)
    late = t >= 0.3
    err = np.abs(X - sim.x)[late].max(axis=0)
    assert np.all(err < [1e-7, 1e-4, 1e-4]), err
    assert np.abs(Z[:, 0] - tau)[late].max() < 1e-2
    # without the known term -a1 sin(q) the model is wrong and so is the estimate
    X2, Z2 = run(make(**{**DC, "F": []}), t, sim.x[:, :1], sim.u)
    assert np.abs(Z2[:, 0] - tau)[late].max() > 0.3
