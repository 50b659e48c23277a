"""Exact FOH/ZOH steps (fto_ros/core/discretize.py's step matrices and core/exact_step.py,
the compiled step every linear kernel takes, with its cache in a work array) against
closed forms and solve_ivp."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from fto_ros.core import discretize, exact_step as XS, step_cache as SC
from fto_ros.core.discretize import foh_matrices


def zoh_matrices(A, B, h):
    """(Phi, Gamma) of the held input, written out independently (Van Loan with w held)."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A * h, B * h
    E = expm(M)
    return E[:n, :n], E[:n, n:]


class Stepper:
    """core/exact_step.py's compiled step with its cache in a work array of its own, as a
    kernel holds it."""

    def __init__(self, A, B, cache_size: int = 256):
        self.A, self.B = np.array(A, dtype=float), np.array(B, dtype=float)
        self.n, self.m = self.B.shape
        self.slots, self.size = cache_size, self.n * (self.n + 2 * self.m)
        self.wk = np.zeros(SC.cache_floats(self.slots, self.size))
        SC.cache_init(self.wk, 0, self.slots)
        self._scratch = np.zeros(self.n + 2 * self.m)

    @property
    def misses(self) -> int:
        return SC.cache_misses(self.wk, 0)

    def stacked(self, h):
        return np.array(XS.stacked(self.A, self.B, h, self.wk, 0, self.slots))

    def step(self, x, w0, w1, h):
        out = np.zeros(self.n)
        z = np.concatenate((x, w0, w1)).astype(float)
        XS.exact_step(self.A, self.B, z, h, self.wk, 0, self.slots, out, self._scratch)
        return out


def scalar_closed_form(a: float, b: float, h: float):
    """(Phi, G0, G1) of x' = a x + b w, w linear from w0 (s = 0) to w1 (s = h).

    x(h) = e^{ah} x0 + b int_0^h e^{a(h-s)} (w0 + (w1 - w0) s/h) ds, with
    int_0^h e^{a(h-s)} ds = (e^{ah} - 1)/a and
    int_0^h e^{a(h-s)} s ds = (e^{ah} - 1 - a h)/a^2.
    """
    gam = b * math.expm1(a * h) / a
    gam1 = b * (math.expm1(a * h) - a * h) / (a * a * h)
    return math.exp(a * h), gam - gam1, gam1


# -- scalar system: analytic integral --------------------------------------------------
@pytest.mark.parametrize("a", [-3.0, -0.2, 0.7, 5.0])
@pytest.mark.parametrize("h", [1e-3, 0.05, 0.4, 2.0])
def test_foh_scalar_matches_closed_form(a, h):
    b = 1.7
    Phi, G0, G1 = foh_matrices(np.array([[a]]), np.array([[b]]), h)
    phi, g0, g1 = scalar_closed_form(a, b, h)
    assert Phi.shape == G0.shape == G1.shape == (1, 1)
    assert Phi[0, 0] == pytest.approx(phi, rel=1e-12)
    assert G0[0, 0] == pytest.approx(g0, rel=1e-9, abs=1e-14)
    assert G1[0, 0] == pytest.approx(g1, rel=1e-9, abs=1e-14)


@pytest.mark.parametrize("a", [-4.0, 1.3])
def test_scalar_step_with_linear_input_is_the_analytic_solution(a):
    b, h, x0, w0, w1 = -0.8, 0.3, 1.25, 2.0, -3.0
    st = Stepper(np.array([[a]]), np.array([[b]]))
    x = st.step(np.array([x0]), np.array([w0]), np.array([w1]), h)
    # written out independently of the (Phi, G0, G1) split
    c = (w1 - w0) / h
    # x' = a x + b (w0 + c s):  x_p = alpha + beta s with beta = a alpha + b w0, a beta + b c = 0
    beta = -b * c / a
    alpha = (beta - b * w0) / a
    exact = alpha + beta * h + (x0 - alpha) * math.exp(a * h)
    assert x.shape == (1,)
    assert x[0] == pytest.approx(exact, rel=1e-11)


def test_foh_g1_vanishes_for_a_held_input_only_in_the_sum():
    # w1 = w0: the step depends on G0 + G1 only, which is the ZOH Gamma
    a, b, h = -2.0, 3.0, 0.25
    Phi, G0, G1 = foh_matrices(np.array([[a]]), np.array([[b]]), h)
    assert G1[0, 0] != 0.0
    assert (G0 + G1)[0, 0] == pytest.approx(b * math.expm1(a * h) / a, rel=1e-12)


# -- 2x2 rotation / unstable system vs solve_ivp ---------------------------------------------
A_ROT = np.array([[0.4, 3.0], [-3.0, 0.4]])            # eigenvalues 0.4 +- 3i: unstable spiral
B_ROT = np.array([[1.0, -0.5], [0.3, 2.0]])


def ivp_linear_input(A, B, x0, w0, w1, h):
    w = lambda s: w0 + (w1 - w0) * s / h  # noqa: E731
    sol = solve_ivp(lambda s, x: A @ x + B @ w(s), (0.0, h), x0, method="DOP853",
                    rtol=1e-12, atol=1e-14)
    assert sol.success
    return sol.y[:, -1]


@pytest.mark.parametrize("h", [0.01, 0.3, 1.5])
def test_2x2_unstable_rotation_matches_solve_ivp(h):
    x0 = np.array([0.7, -1.1])
    w0 = np.array([1.0, -2.0])
    w1 = np.array([-0.5, 3.0])
    st = Stepper(A_ROT, B_ROT)
    x = st.step(x0, w0, w1, h)
    ref = ivp_linear_input(A_ROT, B_ROT, x0, w0, w1, h)
    np.testing.assert_allclose(x, ref, rtol=1e-9, atol=1e-11)


def test_2x2_phi_is_expm_and_zoh_gamma_is_the_integral():
    h = 0.37
    Phi, G0, G1 = foh_matrices(A_ROT, B_ROT, h)
    np.testing.assert_allclose(Phi, expm(A_ROT * h), rtol=1e-13, atol=1e-14)
    # A nonsingular: int_0^h e^{As} ds B = A^-1 (e^{Ah} - I) B
    gamma = np.linalg.solve(A_ROT, (expm(A_ROT * h) - np.eye(2)) @ B_ROT)
    np.testing.assert_allclose(G0 + G1, gamma, rtol=1e-12, atol=1e-14)
    # first-order part: A^-2 (e^{Ah} - I - A h) B / h
    Ainv = np.linalg.inv(A_ROT)
    g1 = Ainv @ Ainv @ (expm(A_ROT * h) - np.eye(2) - A_ROT * h) @ B_ROT / h
    np.testing.assert_allclose(G1, g1, rtol=1e-10, atol=1e-13)


def test_rectangular_b_shapes():
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, -2.0, -3.0]])
    B = np.array([[1.0], [0.0], [2.0]])
    Phi, G0, G1 = foh_matrices(A, B, 0.1)
    assert Phi.shape == (3, 3) and G0.shape == (3, 1) and G1.shape == (3, 1)
    Pz, Gz = zoh_matrices(A, B, 0.1)
    assert Pz.shape == (3, 3) and Gz.shape == (3, 1)
    st = Stepper(A, B)
    assert st.stacked(0.1).shape == (3, 3 + 2)
    x = st.step(np.ones(3), np.array([1.0]), np.array([2.0]), 0.1)
    ref = ivp_linear_input(A, B, np.ones(3), np.array([1.0]), np.array([2.0]), 0.1)
    np.testing.assert_allclose(x, ref, rtol=1e-10, atol=1e-12)


# -- ZOH == FOH with w1 = w0 -----------------------------------------------------------------
@pytest.mark.parametrize("h", [1e-4, 0.02, 0.9])
def test_zoh_equals_foh_with_held_input(h):
    Pz, Gz = zoh_matrices(A_ROT, B_ROT, h)
    Pf, G0, G1 = foh_matrices(A_ROT, B_ROT, h)
    np.testing.assert_allclose(Pz, Pf, rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(Gz, G0 + G1, rtol=1e-12, atol=1e-15)
    x0, w = np.array([0.3, -0.2]), np.array([1.5, -0.7])
    st = Stepper(A_ROT, B_ROT)
    np.testing.assert_allclose(st.step(x0, w, w, h), Pz @ x0 + Gz @ w, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(st.step(x0, w, w, h), ivp_linear_input(A_ROT, B_ROT, x0, w, w, h),
                               rtol=1e-9, atol=1e-11)


def test_zoh_scalar_closed_form():
    a, b, h = 2.5, -1.5, 0.2
    P, G = zoh_matrices(np.array([[a]]), np.array([[b]]), h)
    assert P[0, 0] == pytest.approx(math.exp(a * h), rel=1e-13)
    assert G[0, 0] == pytest.approx(b * math.expm1(a * h) / a, rel=1e-12)


# -- cache -----------------------------------------------------------------------------------
def test_cache_same_step_costs_one_expm():
    st = Stepper(A_ROT, B_ROT)
    assert st.misses == 0
    x = np.array([1.0, 0.0])
    w = np.array([0.0, 0.0])
    for _ in range(500):
        x = st.step(x, w, w, 1e-3)
    assert st.misses == 1
    # a second step size is one more miss; going back to the first is a hit
    st.step(x, w, w, 2e-3)
    st.step(x, w, w, 1e-3)
    st.step(x, w, w, 2e-3)
    assert st.misses == 2
    # the cached result is a fresh computation's
    np.testing.assert_allclose(st.stacked(1e-3), np.hstack(foh_matrices(A_ROT, B_ROT, 1e-3)),
                               rtol=1e-14, atol=1e-16)


def test_cache_key_is_the_nanosecond():
    st = Stepper(A_ROT, B_ROT)
    st.stacked(0.001)
    st.stacked(0.001 + 1e-13)         # same nanosecond: same entry
    st.stacked(0.0005 + 0.0005)       # float noise in a sum of stamps: same entry
    assert st.misses == 1
    st.stacked(0.001 + 1e-9)          # next nanosecond: a new entry
    assert st.misses == 2


def test_cache_is_bounded_and_evicts():
    st = Stepper(A_ROT, B_ROT, cache_size=3)
    for h in (1e-3, 2e-3, 3e-3, 4e-3):
        st.stacked(h)
    assert st.misses == 4
    st.stacked(4e-3)
    assert st.misses == 4              # the newest is kept
    st.stacked(1e-3)
    assert st.misses == 5              # the oldest was evicted
    # results stay correct after eviction
    np.testing.assert_allclose(st.stacked(1e-3), np.hstack(foh_matrices(A_ROT, B_ROT, 1e-3)),
                               rtol=1e-14, atol=1e-16)


# -- stiff system: exact where Euler explodes ----------------------------------------------
def stiff_reference_sin(lam, x0, t):
    """x0' = lam (x0 - sin t), x1' = x0 - x1 from (x0(0), x1(0)), solved by hand."""
    a, b = lam ** 2 / (1 + lam ** 2), lam / (1 + lam ** 2)        # x0_p = a sin + b cos
    c = x0[0] - b
    al, be = (a + b) / 2, (b - a) / 2                             # x1_p = al sin + be cos
    d = x0[1] - be - c / (lam + 1)
    return np.array([a * math.sin(t) + b * math.cos(t) + c * math.exp(lam * t),
                     al * math.sin(t) + be * math.cos(t) + c * math.exp(lam * t) / (lam + 1)
                     + d * math.exp(-t)])


def stiff_reference_ramp(lam, x0, t, r):
    """The same system with the input r t instead of sin t."""
    q = r / lam                                                   # x0_p = r t + q
    c = x0[0] - q
    n = q - r                                                     # x1_p = r t + n
    d = x0[1] - n - c / (lam + 1)
    return np.array([r * t + q + c * math.exp(lam * t),
                     r * t + n + c * math.exp(lam * t) / (lam + 1) + d * math.exp(-t)])


def test_stiff_references_solve_the_ode():
    # the hand solutions above satisfy the ODE (finite differences at a slow time scale)
    lam, x0 = -1e4, (5.0, 0.0)
    A = np.array([[lam, 0.0], [1.0, -1.0]])
    for ref, w in ((lambda t: stiff_reference_sin(lam, x0, t), math.sin),
                   (lambda t: stiff_reference_ramp(lam, x0, t, 0.3), lambda t: 0.3 * t)):
        np.testing.assert_allclose(ref(0.0), x0, atol=1e-14)
        for t in (0.01, 0.1, 0.2):
            e = 1e-6
            deriv = (ref(t + e) - ref(t - e)) / (2 * e)
            np.testing.assert_allclose(deriv, A @ ref(t) + np.array([-lam * w(t), 0.0]),
                                       rtol=1e-6, atol=1e-6)


def test_stiff_system_stays_exact_where_euler_blows_up():
    lam, h = -1e4, 1e-3
    A = np.array([[lam, 0.0], [1.0, -1.0]])
    B = np.array([[-lam], [0.0]])     # x0' = lam (x0 - w): tracks w with a 0.1 ms time constant
    st = Stepper(A, B)
    x = np.array([5.0, 0.0])
    x_euler = x.copy()
    T = 0.0
    for k in range(200):
        w0 = np.array([math.sin(T)])
        w1 = np.array([math.sin(T + h)])
        x = st.step(x, w0, w1, h)
        x_euler = x_euler + h * (A @ x_euler + B @ w0)
        T += h
    assert np.all(np.isfinite(x))
    assert abs(x_euler[0]) > 1e100                 # (1 + lam h)^200 = 9^200
    # the FOH of sin() is the only approximation: O(h^2) on the forced part
    np.testing.assert_allclose(x, stiff_reference_sin(lam, (5.0, 0.0), T), rtol=0, atol=2e-7)
    # with a linear-in-time input the step is exact to round-off
    x = np.array([5.0, 0.0])
    for k in range(200):
        x = st.step(x, np.array([0.3 * k * h]), np.array([0.3 * (k + 1) * h]), h)
    np.testing.assert_allclose(x, stiff_reference_ramp(lam, (5.0, 0.0), 200 * h, 0.3),
                               rtol=1e-10, atol=1e-13)


def test_stiff_phi_is_tiny_not_negative():
    Phi, G0, G1 = foh_matrices(np.array([[-1e4]]), np.array([[1.0]]), 1e-3)
    assert Phi[0, 0] == pytest.approx(math.exp(-10.0), rel=1e-12)
    phi, g0, g1 = scalar_closed_form(-1e4, 1.0, 1e-3)
    assert G0[0, 0] == pytest.approx(g0, rel=1e-9)
    assert G1[0, 0] == pytest.approx(g1, rel=1e-9)


# -- composition: a variable step sequence equals one step over the total --------------------
def test_variable_steps_compose_to_one_step_for_linear_input():
    rng = np.random.default_rng(1234)
    # step sizes as whole nanoseconds (stamps are), 0.1 ms .. 20 ms
    steps_ns = rng.integers(100_000, 20_000_000, size=60)
    t = np.concatenate(([0], np.cumsum(steps_ns))) * 1e-9
    c0, c1 = np.array([0.5, -1.0]), np.array([2.0, 0.25])
    w = lambda s: c0 + c1 * s  # noqa: E731
    st = Stepper(A_ROT, B_ROT)
    x0 = np.array([0.2, -0.4])
    x = x0.copy()
    for ta, tb in zip(t[:-1], t[1:]):
        x = st.step(x, w(ta), w(tb), tb - ta)
    one = Stepper(A_ROT, B_ROT).step(x0, w(t[0]), w(t[-1]), t[-1] - t[0])
    scale = np.max(np.abs(one))
    np.testing.assert_allclose(x, one, rtol=1e-9, atol=1e-12 * scale)
    np.testing.assert_allclose(x, ivp_linear_input(A_ROT, B_ROT, x0, w(t[0]), w(t[-1]), t[-1]),
                               rtol=1e-8)
    assert st.misses == len(set(steps_ns.tolist()))


def test_piecewise_constant_input_is_not_a_linear_one():
    # sanity: the composition test can fail -- ZOH steps do not reproduce the FOH one-shot
    st = Stepper(A_ROT, B_ROT)
    x0 = np.array([0.2, -0.4])
    w0, w1 = np.array([0.0, 0.0]), np.array([1.0, 1.0])
    x = x0.copy()
    for k in range(10):
        wk = w0 + (w1 - w0) * k / 10
        x = st.step(x, wk, wk, 0.1)
    one = st.step(x0, w0, w1, 1.0)
    assert np.max(np.abs(x - one)) > 1e-3


def test_irregular_steps_are_composed_from_cached_ones():
    """After COMPOSE_AFTER distinct sizes a new whole-quantum size is composed of cached
    power-of-two steps: the same exact step (to rounding), no new expm per size."""
    st = Stepper(A_ROT, B_ROT)
    ref = Stepper(A_ROT, B_ROT)
    x0, w0, w1 = np.array([1.0, -0.5]), np.array([0.3, 0.1]), np.array([-0.2, 0.4])
    rng = np.random.default_rng(7)
    sizes = rng.integers(1000, 3000, size=400) * discretize.STEP_QUANTUM
    for h in sizes:
        np.testing.assert_allclose(st.step(x0, w0, w1, h),
                                   np.hstack(foh_matrices(A_ROT, B_ROT, h)) @ np.concatenate((x0, w0, w1)),
                                   rtol=1e-12, atol=1e-13)
    assert st.misses < discretize.COMPOSE_AFTER + 15       # not one per size
    for h in sizes[:5]:
        ref.step(x0, w0, w1, h)
    assert ref.misses == 5                                  # a few sizes: exact matrices
