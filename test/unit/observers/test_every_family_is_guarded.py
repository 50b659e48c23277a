"""Every registered observer family (fto_ros.observers.REGISTRY) is under the suite's checks
that cut across families, so a new family cannot go untested:
- a committed (bag, config) pair of the golden master (test/data/runner_reference.npz,
  test_kernel_reference.py) runs it (its config's observer.type);
- a test compares its compiled kernels with its numpy path (NUMPY_PATH: the test file,
  which must name the family);
(test/naive/ holds each family's naive reference to the registry the same way.)
A registered family missing from a table fails here, saying which table; a table entry for
a family that is not registered fails too."""
from __future__ import annotations

from pathlib import Path

import pytest

import reference_runs as RR
from fto_ros.observers import REGISTRY
from fto_ros.runner.params_file import load_params_files
from registry_tables import expected

HERE = Path(__file__).resolve().parent
#: family -> the test (in test/unit/observers/) that compares its compiled kernels with the
#: numpy path (FTO_ROS_NUMBA=0) on its committed configs
NUMPY_PATH = {
    "single_delay": "test_single_delay_paths.py",
    "prescribed_time": "test_compiled_paths.py",
    "global_norm": "test_compiled_paths.py",
    "high_gain": "test_compiled_paths.py",
    "luenberger": "test_compiled_paths.py",
    "hosm": "test_hosm_newton_numpy_path.py",
    "newton_inversion": "test_hosm_newton_numpy_path.py",
    "ekf": "test_ekf.py",
    "track": "test_ekf.py",          # its acquire_track configs, tracker and all
    "joint_kalman": "test_joint_kalman.py",
}


def _reference_families() -> dict[str, list[str]]:
    """observer.type -> the golden master's pairs that run it."""
    out: dict[str, list[str]] = {}
    for pair in RR.load_reference()[1]["pairs"]:
        flat = load_params_files([RR.ROOT / f for f in pair["params"]])
        out.setdefault(flat["observer.type"], []).append(f"{pair['bag']}: {pair['params'][-1]}")
    return out


@pytest.fixture(scope="module")
def reference_families():
    return _reference_families()


@pytest.mark.parametrize("family", sorted(REGISTRY))
def test_the_golden_master_runs_every_family(family, reference_families):
    assert reference_families.get(family), (
        f"observer family {family!r} is registered but no pair of the golden master runs it: "
        "add a committed (bag, config) pair to test/data/runner_reference.npz "
        "(test/support/reference_runs.py)")


@pytest.mark.parametrize("family", sorted(REGISTRY))
def test_every_family_has_its_compiled_kernels_compared_with_the_numpy_path(family):
    path = HERE / expected(NUMPY_PATH, family, "NUMPY_PATH (test_every_family_is_guarded.py)",
                           "the test that compares its compiled kernels with the numpy path")
    assert path.is_file(), f"{family}: {path} does not exist"
    assert family in path.read_text(), f"{path.name} does not name {family}"


def test_the_tables_name_registered_families_only(reference_families):
    assert set(NUMPY_PATH) <= set(REGISTRY), set(NUMPY_PATH) - set(REGISTRY)
    assert set(reference_families) <= set(REGISTRY), set(reference_families) - set(REGISTRY)
