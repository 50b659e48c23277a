"""The replay's metrics (fto_ros/replay/metrics.py): matching the truth (exact, interpolated,
outside) and the convergence time's definition."""
from __future__ import annotations

import numpy as np

from fto_ros.replay import metrics as M


# ------------------------------------------------------------------ metrics
def test_match_truth_exact_interpolated_and_outside():
    t_truth = np.array([10, 20, 30], dtype=np.int64)
    x_truth = np.array([[0.0], [1.0], [3.0]])
    mask, x = M.match_truth(np.array([5, 10, 15, 30, 31]), t_truth, x_truth)
    assert mask.tolist() == [False, True, True, True, False]
    assert x[1, 0] == 0.0 and x[2, 0] == 0.5 and x[3, 0] == 3.0
    assert np.isnan(x[0, 0]) and np.isnan(x[4, 0])


def test_convergence_time_definition():
    t = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    assert M.convergence_time(t, np.array([1, 0.001, 1, 0.001, 0.001]), 0.01) == 0.3
    assert M.convergence_time(t, np.full(5, 0.001), 0.01) == 0.0
    assert M.convergence_time(t, np.array([1, 0, 0, 0, 1.0]), 0.01) is None
    assert M.convergence_time(t, np.array([1, 0, 0, np.nan, 0]), 0.01) == 0.4
