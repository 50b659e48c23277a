"""Every registered observer family has a naive reference: test/naive/test_naive_<type>.py,
declaring ``FAMILY = <type>`` and the ``FORMS`` it covers, with a test that compares it with
the package (named ``test_<...>_matches_its_naive_reference``).  A family whose parameters
choose between forms (another class or kernel, another design) lists every choice, so a new
form cannot go untested either.  A new family in fto_ros.observers.REGISTRY fails here until
it has its reference.
"""
from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from fto_ros.observers import REGISTRY

HERE = Path(__file__).resolve().parent
#: the parameter whose choices are forms of the family (each one needs its reference)
FORM_PARAMS = {"single_delay": "measurement", "luenberger": "design"}


@pytest.mark.parametrize("family", sorted(REGISTRY))
def test_every_registered_family_has_a_naive_reference(family):
    path = HERE / f"test_naive_{family}.py"
    assert path.is_file(), f"observer family {family!r} has no naive reference ({path.name})"
    mod = importlib.import_module(path.stem)
    assert getattr(mod, "FAMILY", None) == family, f"{path.name} must declare FAMILY = {family!r}"
    tests = [k for k in vars(mod) if k.startswith("test_") and k.endswith("matches_its_naive_reference")]
    assert tests, f"{path.name} has no test_..._matches_its_naive_reference"
    if family in FORM_PARAMS:
        param = next(p for p in REGISTRY[family].PARAMS if p.name == FORM_PARAMS[family])
        missing = set(param.choices) - set(mod.FORMS)
        assert not missing, f"{path.name} covers no {FORM_PARAMS[family]} {sorted(missing)}"

