"""Non-finite values inside the runner: an observer kernel that lets a NaN through is never
published and restarts; a model term that overflows rejects its sample without poisoning
the observer.

On test_runner.py's simulated DC motor (test/support/runner_streams.py).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.core import jit
from fto_ros.observers import kernel as kernel_protocol
from fto_ros.observers.luenberger import kernel as luenberger_kernel
from fto_ros.runner import ERROR, Output
from runner_streams import CONTINUOUS, check_finite, drive, make, same_output
from runner_streams import uniform, sparse  # noqa: F401 (fixtures)


_LUENBERGER = jit.kernel(luenberger_kernel.kernel, jit.KERNEL)


def _nan_kernel(op, st, nx, c, ic, wk, a, b, y, u, models):
    """The Luenberger kernel with a bug: from the 101st step on it commits a NaN estimate."""
    code = _LUENBERGER(op, st, nx, c, ic, wk, a, b, y, u, models)
    if op == jit.STEP and wk[wk.shape[0] - 1] > 0.0:
        nx[ic[kernel_protocol.EST] + 1] = math.nan
    return code


def test_observer_letting_nan_through_is_never_published(uniform):
    r = make("luenberger")
    drive(r, uniform, 0, 100)
    obs = r.observer
    broken = jit.function_list([jit.kernel(_nan_kernel, jit.KERNEL)], jit.KERNELS)
    good = r._prog[0]
    obs._wk = np.append(obs._wk, 1.0)             # the bug's switch, in the work memory
    obs._kernels = broken
    r._stack()
    r.set_input(uniform.t[100], uniform.u[100])
    assert r.process(uniform.t[100], uniform.y[100]) == "non_finite_estimate"
    assert r.rejected == {"non_finite_estimate": 1}
    assert r.resets == {"non_finite_state": 1}
    st = r.status(uniform.t[100])
    assert st.level == ERROR
    assert "non-finite" in st.message
    obs._kernels = good                                       # fixed: restarts at the next sample
    r._stack()
    out = drive(r, uniform, 101, 110)
    assert out[101].convergence[0] == 0.0
    for o in out.values():
        check_finite(o)


# -- non-finite values from the model terms ----------------------------------------------------------------
# 1e-300 exp(y0) is nothing for |y0| < 600 and overflows for y0 > 709.8: the plant is unchanged.
OVERFLOW = {
    "luenberger": dict(luenberger__F=["0", "-35*sin(y0) + 1e-300*exp(y0)", "0"]),
    "single_delay": dict(single_delay__F1=["-35*sin(y0) + 1e-300*exp(y0)", "40*u0"]),
    "single_delay_sampled": dict(single_delay__F1=["-35*sin(y0) + 1e-300*exp(y0)", "40*u0"]),
}
OVERFLOW_REASON = {"luenberger": "non_finite_estimate", "single_delay": "non_finite_model_term"}


@pytest.mark.parametrize("name", CONTINUOUS)
def test_overflowing_model_term_rejects_the_sample(name, uniform):
    ref = drive(make(name, **OVERFLOW[name]), uniform, 0, 400)
    r = make(name, outlier__threshold=0.0, **OVERFLOW[name])  # y = 1000 is also an outlier
    drive(r, uniform, 0, 200)
    before = np.array(r.observer.estimate, copy=True)
    got = r.process(uniform.t[199] + 5e-4, [1000.0])
    assert got == OVERFLOW_REASON[name]
    assert r.rejected == {got: 1}
    assert not r.resets
    np.testing.assert_array_equal(r.observer.estimate, before)
    for i, out in drive(r, uniform, 200, 400).items():
        check_finite(out)
        same_output(out, ref[i])


def test_exp_1000_y_is_rejected_and_nothing_non_finite_is_published():
    # the model itself grows to 1e17 (within limits.estimate); y jumps are no outliers here
    r = make("luenberger", luenberger__F=["0", "exp(1000*y0)", "0"], limits__estimate=1e300,
             outlier__threshold=0.0)
    outs = []
    t = 0.0
    for k in range(40):
        t = k * 1e-3
        r.set_input(t, [1.0])
        y = 1.0 if k in (20, 21, 30) else 1e-3 * k             # exp(1000) overflows
        out = r.process(t, [y])
        if k in (20, 21, 30):
            assert out == "non_finite_estimate"
            np.testing.assert_array_equal(r.observer.estimate, outs[-1].estimate)
        else:
            assert isinstance(out, Output)
            check_finite(out)
            outs.append(out)
    assert r.rejected == {"non_finite_estimate": 3}
    assert r.accepted == 37
    assert not r.resets


def test_luenberger_first_sample_with_non_finite_model_term(uniform):
    r = make("luenberger", **OVERFLOW["luenberger"])
    r.set_input(uniform.t[0], uniform.u[0])
    r.process(uniform.t[0], [1000.0])
    outs = drive(r, uniform, 1, 50)                           # asserts every sample is accepted
    assert len(outs) == 49


def test_sampled_overflowing_measurement_does_not_poison_the_predictor(sparse):
    s = sparse
    r = make("single_delay_sampled", **OVERFLOW["single_delay_sampled"])
    drive(r, s, 0, 150)
    r.process(s.t[149] + 2e-4, [1000.0])
    outs = drive(r, s, 150, 200)                              # asserts every sample is accepted
    assert len(outs) == 50
