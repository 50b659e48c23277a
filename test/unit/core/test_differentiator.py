"""core/differentiator.py: Levant's robust exact differentiator, three discretisations.

What is checked, measured (docs/differentiator.md has the figures):
- the gain tables (non-recursive l~ from the recursive lambdas, the closed-form
  eigenvalue-matched gains for n = 1..3) and the defining property of the default scheme:
  all eigenvalues of the discrete closed loop at 1 - w, n = 1..7 and with filtering;
- accuracy orders of the default scheme: sampling step h^(N-i) and noise eps^((N-i)/N),
  orders 1..5, on f = sin t with L = 1 (bound of |f^(N)|), rho = 2, error = max |z_i -
  f^(i)| over t in [8, 15] s (the transient from z = (f(0), 0, ..., 0) is over by then);
  also under jittered sampling; explicit Euler loses the order of z1 (the test can fail);
- exactness on polynomials of degree n (the errors reach the float floor), with and
  without filtering; filtering lowers the RMS error on noisy signals;
- robustness to a 100x overestimated L.
(Bad arguments, e = 0, constant f, huge h, channels, snapshots, sub-steps, the API:
test_differentiator_api.py.)
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.core import differentiator as dm
from fto_ros.core.differentiator import (Differentiator, ackermann_gain_coefficients, levant_gains,
                                         matched_gain_coefficients, matched_gains,
                                         recursive_to_nonrecursive)

T_END, T_FROM = 15.0, 8.0


def run(n, h, *, T=T_END, t_from=T_FROM, eps=0.0, seed=0, jitter=0.0, signal=None,
        derivs=None, rms=False, predicted=False, **kw):
    """Sample f (default sin t) at step h (optionally jittered by +-jitter/2 h), add uniform
    noise of amplitude eps, differentiate; max (or RMS) |z_i - f^(i)| for t >= t_from, of
    the published (current) estimates, or of the recursion's state (``predicted``)."""
    rng = np.random.default_rng(seed)
    m = int(round(T / h))
    t = np.arange(m + 1) * h
    if jitter:
        t[1:-1] += rng.uniform(-jitter / 2, jitter / 2, m - 1) * h
    f = np.sin(t) if signal is None else signal(t)
    if eps:
        f = f + eps * rng.uniform(-1, 1, m + 1)
    d = Differentiator(n, kw.pop("L", 1.0), **kw)
    d.reset(f[:1])
    dt, fl = np.diff(t).tolist(), f.tolist()
    Z = np.empty((m + 1, n + 1))
    Z[0] = d.estimates[0]
    upd = d.update
    for k in range(m):
        Z[k + 1] = upd(dt[k], fl[k + 1])[0]
        if predicted:
            Z[k + 1] = d.predicted[0]
    if derivs is None:
        der = np.array([np.sin(t + i * np.pi / 2) for i in range(n + 1)]).T
    else:
        der = derivs(t)
    E = (Z - der)[t >= t_from]
    return np.sqrt((E ** 2).mean(0)) if rms else np.abs(E).max(0)


def slopes(xs, errs):
    """Least-squares slope of log err vs log x, per column."""
    lx = np.log(np.asarray(xs))
    le = np.log(np.asarray(errs))
    A = np.vstack([lx, np.ones_like(lx)]).T
    return np.linalg.lstsq(A, le, rcond=None)[0][0]


# -- gains ---------------------------------------------------------------------------------
NOTE_TABLE = {1: (1.1, 1.5), 2: (1.1, 2.12, 2), 3: (1.1, 3.06, 4.16, 3),
              4: (1.1, 4.57, 9.30, 10.03, 5), 5: (1.1, 6.75, 20.26, 32.24, 23.72, 7),
              6: (1.1, 9.91, 43.65, 101.96, 110.08, 47.69, 10),
              7: (1.1, 14.13, 88.78, 295.74, 455.40, 281.37, 84.14, 12)}


@pytest.mark.parametrize("n", range(1, 8))
def test_levant_gains_match_the_table(n):
    assert np.allclose(levant_gains(n), NOTE_TABLE[n], atol=0.006)


def test_recursive_to_nonrecursive():
    assert recursive_to_nonrecursive([1.1, 1.5, 2]) == pytest.approx((1.1, 1.5 * 2 ** 0.5, 2))
    with pytest.raises(ValueError, match="lambdas"):
        recursive_to_nonrecursive([1.0])
    with pytest.raises(ValueError, match="lambdas"):
        recursive_to_nonrecursive([1.0, -2.0])


@pytest.mark.parametrize("w,h", [(0.3, 1e-2), (1.0, 0.5), (1e-3, 1e-4)])
def test_closed_form_gains_match_the_note(w, h):
    table = {1: (2 * w, w ** 2 / h),
             2: (3 * w, (3 * w ** 2 - w ** 3 / 2) / h, w ** 3 / h ** 2),
             3: (4 * w, (6 * w ** 2 - 2 * w ** 3 + w ** 4 / 3) / h, (4 * w ** 3 - w ** 4) / h ** 2,
                 w ** 4 / h ** 3)}
    for n, ref in table.items():
        assert np.allclose(matched_gains(n, w, h), ref, rtol=1e-13), n


def test_stirling_numbers():
    assert [dm.stirling1(4, i) for i in range(5)] == [0, -6, 11, -6, 1]
    assert dm.stirling1(0, 0) == 1 and dm.stirling1(3, 5) == 0


@pytest.mark.parametrize("N", range(2, 9))
def test_stirling_gains_equal_ackermann(N):
    """The closed form and Ackermann's formula (exact rationals) give the same gains."""
    assert np.allclose(matched_gain_coefficients(N), ackermann_gain_coefficients(N, 0),
                       rtol=1e-14, atol=1e-14)


def closed_loop(n, nf, w, h):
    """Unscaled closed-loop matrix A(h) - lambda(w, h) c^T of the default scheme."""
    d = Differentiator(n, 1.0, filter_order=nf)
    AT, hinv, _ = d._mats(h)
    lam = (d._K @ (w ** np.arange(1, d._N + 1))) * hinv
    M = AT.T.copy()
    M[:, 0] -= lam        # innovation f - z0 (nf = 0) or -x1 (nf > 0): both -lambda e_1^T
    return M


@pytest.mark.parametrize("n", range(1, 8))
@pytest.mark.parametrize("nf", [0, 1, 2])
def test_all_eigenvalues_at_one_minus_w(n, nf):
    """The defining property: Phi(h) - lambda e_1^T has all N eigenvalues at exp(h s) = 1 - w,
    i.e. M - (1 - w) I is nilpotent (N-fold root: eigvals are ill-conditioned, so check the
    characteristic polynomial and nilpotency instead); with several h and w."""
    if n + nf + 1 > dm.MAX_CHAIN:
        pytest.skip("chain too long")
    N = n + nf + 1
    for h in (0.1, 1e-2):
        for w in (1e-2, 0.5, 1.0):
            M = closed_loop(n, nf, w, h)
            # characteristic polynomial in h-scaled coordinates (D M D^-1 is h-free)
            D = h ** np.arange(N)
            Ms = (M * D[:, None]) / D[None, :]
            ref = np.poly(np.full(N, 1 - w))
            assert np.allclose(np.poly(Ms), ref, atol=1e-7), (h, w)
            P = np.linalg.matrix_power(Ms - (1 - w) * np.eye(N), N)
            assert np.abs(P).max() < 1e-9 * max(1.0, np.abs(Ms).max()) ** N, (h, w)
            # and not trivially: one Jordan block (the (N-1)th power is not zero)
            Q = np.linalg.matrix_power(Ms - (1 - w) * np.eye(N), N - 1)
            assert np.abs(Q).max() > 1e-6


def test_small_w_is_levant_red_with_binomial_gains():
    """For small w, lambda_i ~ C(N, i+1) (w/h)^(i+1) h^i ... i.e. h r^(i+1) C(N, i+1) |e|^.
    Check lambda_i h^(i) / w^(i+1) -> C(N, i+1) as w -> 0."""
    for n in range(1, 8):
        N = n + 1
        w, h = 1e-7, 1e-3
        lam = matched_gains(n, w, h)
        scaled = lam * h ** np.arange(N) / w ** np.arange(1, N + 1)
        assert np.allclose(scaled, [math.comb(N, i + 1) for i in range(N)], rtol=1e-5)


# -- accuracy orders -------------------------------------------------------------------------
#: an error this small is round-off (values of size 1): no order can be read off it
FLOAT_FLOOR = 1e-12


def assert_orders(hs, E, orders, tol):
    """The slope of log err vs log h is within tol of the order, for every estimate whose
    errors are above the float floor; one at the floor must stay there at every h."""
    above = np.all(E > FLOAT_FLOOR, axis=0)
    s = slopes(hs, E)
    assert np.all(np.abs(s - orders)[above] < tol), s
    assert np.all(E[:, ~above] < 10 * FLOAT_FLOOR), E
    assert above[1:].all(), E            # the derivatives are never at the floor here


@pytest.mark.parametrize("n", range(1, 6))
def test_accuracy_order_in_h(n):
    """Noise-free: |z_i - f^(i)| = O(h^(N-i)); slope of log err vs log h within 0.15.
    (The current estimate of z0 reaches the float floor at small h for large n.)"""
    hs = (2e-2, 1e-2, 5e-3)
    E = np.array([run(n, h) for h in hs])
    N = n + 1
    assert_orders(hs, E, N - np.arange(N), 0.15)
    if n <= 3:      # also at small steps
        hs = (2e-3, 1e-3, 5e-4)
        assert_orders(hs, np.array([run(n, h) for h in hs]), N - np.arange(N), 0.15)


def test_note_numbers_order_2_at_1khz():
    """The note's simulation (of the recursion): n = 2, h = 1e-3 gives (2.0e-9, 3.2e-6,
    2.8e-3); the published current estimate is better on every derivative."""
    e = run(2, 1e-3, predicted=True)
    assert np.allclose(e, (2.0e-9, 3.2e-6, 2.8e-3), rtol=0.1), e
    assert np.all(run(2, 1e-3) < e)


def test_second_derivative_beats_a_double_backward_difference():
    """The estimate at t uses the sample at t (no one-sample lag): on sin t + 0.5 sin 3t at
    1 kHz without noise, the RMS error of f'' from the order-3 differentiator (L = 45 bounds
    |f^(4)| = 41.5) is at most a double backward difference's (measured 5.7e-5 vs 9.7e-3),
    and the lag fix divides it by more than 2 (the recursion's state: 1.4e-4); order 2
    (L = 30): 1.2e-2 against the state's 2.2e-2."""
    def sig(t):
        return np.sin(t) + 0.5 * np.sin(3 * t)

    def der(t):
        return np.array([sig(t), np.cos(t) + 1.5 * np.cos(3 * t),
                         -np.sin(t) - 4.5 * np.sin(3 * t), -np.cos(t) - 13.5 * np.cos(3 * t)]).T
    h, t_from = 1e-3, 2.0
    t = np.arange(int(round(T_END / h)) + 1) * h
    bd2 = np.diff(sig(t), 2) / h ** 2                      # at t[2:], from f(t-2h..t)
    keep = t[2:] >= t_from
    bd_rms = np.sqrt(np.mean((bd2 - der(t)[2:, 2])[keep] ** 2))
    kw = dict(t_from=t_from, signal=sig, derivs=der, rms=True, L=45.0)
    cur, pred = run(3, h, **kw), run(3, h, predicted=True, **kw)
    assert cur[2] <= bd_rms, (cur, bd_rms)
    assert cur[2] < 0.5 * pred[2], (cur, pred)
    kw.update(L=30.0, derivs=lambda t: der(t)[:, :3])
    assert np.all(run(2, h, **kw)[1:] < 0.6 * run(2, h, predicted=True, **kw)[1:])


@pytest.mark.parametrize("n", [2, 4])
def test_accuracy_order_with_jittered_sampling(n):
    """Steps uniformly in [0.5 h, 1.5 h]: the orders in (mean) h hold (RMS error: the max
    over a random grid depends on where the longest steps fall)."""
    hs = (2e-2, 1e-2, 5e-3)
    E = np.array([run(n, h, jitter=1.0, seed=3, rms=True, predicted=True) for h in hs])
    s = slopes(hs, E)
    N = n + 1
    assert np.all(np.abs(s - (N - np.arange(N))) < 0.2), s
    # and the level: within 2x of the regular grid at the largest step, 1.5 h (measured:
    # below it for n = 2, up to 1.7x above it for z0 of n = 4)
    ref = run(n, 1.5e-2, rms=True, predicted=True)
    assert np.all(E[1] < 2 * ref), (E[1], ref)
    # the published estimate is at least as good on every derivative (its z0 is the sample
    # itself to within the deadbeat gain: the recursion's order does not apply to it)
    cur = np.array([run(n, h, jitter=1.0, seed=3, rms=True) for h in hs])
    assert np.all(cur[:, 1:] <= E[:, 1:]), (cur, E)


@pytest.mark.parametrize("n", range(1, 6))
def test_accuracy_order_in_noise(n):
    """Uniform noise of amplitude eps, h = 2e-4: |z_i - f^(i)| = O(eps^((N-i)/N)).
    Random (not worst-case) noise measures slightly below the worst-case theory; slope
    within 0.15 of (N - i)/N over eps = 1e-6..1e-3."""
    epss = (1e-6, 1e-5, 1e-4, 1e-3)
    E = np.array([run(n, 2e-4, T=12.0, t_from=6.0, eps=e, seed=1) for e in epss])
    s = slopes(epss, E)
    N = n + 1
    assert np.all(np.abs(s - (N - np.arange(N)) / N) < 0.15), s


def test_euler_loses_the_order_of_the_intermediate_derivative():
    """The bar the default scheme meets and the naive scheme does not: z1 of n = 2."""
    hs = (2e-3, 1e-3, 5e-4)
    s_euler = slopes(hs, np.array([run(2, h, scheme="euler", T=25, t_from=15) for h in hs]))
    s_ll = slopes(hs, np.array([run(2, h, scheme="livne_levant", T=25, t_from=15) for h in hs]))
    assert abs(s_euler[1] - 1.0) < 0.15, s_euler           # O(h), not O(h^2)
    assert np.all(np.abs(s_ll - (3, 2, 1)) < 0.2), s_ll     # Livne-Levant keeps them


def test_default_beats_euler_and_livne_levant_at_1khz():
    em = run(3, 1e-3, T=25, t_from=15)
    for scheme in ("euler", "livne_levant"):
        other = run(3, 1e-3, T=25, t_from=15, scheme=scheme)
        assert np.all(em < other), (scheme, em, other)


def test_overestimated_L_does_not_degrade_the_default_scheme():
    """L = 100 instead of 1 (n = 2, h = 1e-3): the default scheme stays within 2x on every
    derivative; Livne-Levant's z2 error grows more than 5x."""
    em1, em100 = run(2, 1e-3), run(2, 1e-3, L=100.0)
    assert np.all(em100 < 2 * em1), (em1, em100)
    assert em100[2] < 4e-3
    ll1 = run(2, 1e-3, T=25, t_from=15, scheme="livne_levant")
    ll100 = run(2, 1e-3, T=25, t_from=15, scheme="livne_levant", L=100.0)
    assert ll100[2] > 5 * ll1[2], (ll1, ll100)


# -- exactness, filtering ------------------------------------------------------------------
def poly(n, seed=0):
    c = np.random.default_rng(seed).uniform(-1, 1, n + 1)
    P = np.polynomial.Polynomial(c)
    return P, (lambda t: np.array([P.deriv(i)(t) if i else P(t) for i in range(n + 1)]).T)


@pytest.mark.parametrize("n", range(1, 6))
@pytest.mark.parametrize("nf", [0, 2])
def test_exact_on_polynomials_of_degree_n(n, nf):
    """f a polynomial of degree n (f^(N) = 0): once converged the default scheme is
    deadbeat (e = 0, w = 1) and only rounding is left: the rounding of f (ulp ~ 2.2e-16
    max|f|) amplified by the deadbeat gains ~ h^-i, i.e. |z_i - f^(i)| < 100 ulp / h^i;
    the same bar fails by orders of magnitude on a non-polynomial (sin t, checked too)."""
    h = 1e-2
    P, der = poly(n, seed=n)
    e = run(n, h, T=6.0, t_from=4.0, signal=P, derivs=der, filter_order=nf)
    fmax = np.abs(P(np.linspace(0, 6, 61))).max()
    floor = 100 * 2.2e-16 * fmax / h ** np.arange(n + 1)
    assert np.all(e < floor), (e, floor)
    e_sin = run(n, h, T=6.0, t_from=4.0, filter_order=nf)
    # (the derivatives: z0 of the current estimate is the sample to round-off for large n)
    assert np.all(e_sin[1:] > (10 * 100 * 2.2e-16 / h ** np.arange(n + 1))[1:]), e_sin


def test_filtering_keeps_the_order_in_h():
    hs = (2e-2, 1e-2, 5e-3)
    for nf in (1, 2):
        s = slopes(hs, np.array([run(2, h, filter_order=nf) for h in hs]))
        assert np.all(np.abs(s - (3, 2, 1)) < 0.15), (nf, s)


def test_filtering_reduces_the_error_on_noisy_signals():
    """n = 2, h = 1e-3, eps = 1e-2, rho = 1.5: RMS error of z1 and z2 with filter_order = 1
    well below that without (measured about 2.5x and 2x)."""
    plain = run(2, 1e-3, T=12, t_from=6, eps=1e-2, rho=1.5, rms=True)
    filt = run(2, 1e-3, T=12, t_from=6, eps=1e-2, rho=1.5, filter_order=1, rms=True)
    assert filt[1] < 0.6 * plain[1] and filt[2] < 0.75 * plain[2], (plain, filt)
