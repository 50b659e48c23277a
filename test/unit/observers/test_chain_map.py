"""``global_norm.chain_map`` / ``high_gain.chain_map`` (observers/chain_map.py): the map to
the observability form's coordinates, derived by the plant block or given explicitly.

What is checked: the plant block derives T (and nothing for a plant that is already a
chain); the explicit parameter runs bit for bit as the derived one; a map that is not an
invertible n x n matrix is refused naming the parameter, and so is a map given both ways.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.plant import expand
from fto_ros.runner import Output, Runner

#: y = 2 p: the chain z = (2 p, 2 v), T = 2 I
PLANT = {"plant.states": ["p", "v"], "plant.inputs": ["F"],
         "plant.f": ["v", "-p - p**3 - v + F"], "plant.h": ["2*p"]}
TUNING = {"global_norm": {"global_norm.conditions": "warn", "global_norm.gamma_hat": "10 + 10*w"},
          "high_gain": {"high_gain.L": 20.0}}


def _flat(type_name: str, **extra) -> dict:
    return dict(PLANT, **{"observer.type": type_name, "observer.initial_estimate": [0.1, -0.5]},
                **TUNING[type_name], **extra)


def _explicit(type_name: str) -> dict:
    """The same observer without the plant block: its derived parameters given by hand."""
    derived = expand(_flat(type_name))
    return {k: v for k, v in derived.items() if not k.startswith("plant.")}


def _run(runner: Runner, n: int = 2000) -> np.ndarray:
    t = np.arange(n) * 1e-3
    out = []
    for k in range(n):
        runner.set_input(t[k], [math.sin(2 * t[k])])
        res = runner.process(t[k], [2 * 0.5 * math.cos(t[k])])
        assert isinstance(res, Output), (k, res)
        out.append(res.estimate.copy())
    return np.array(out)


@pytest.mark.parametrize("type_name", ["global_norm", "high_gain"])
def test_the_plant_block_derives_the_map(type_name):
    assert expand(_flat(type_name))[f"{type_name}.chain_map"] == [2.0, 0.0, 0.0, 2.0]
    chain = dict(_flat(type_name), **{"plant.h": ["p"]})
    assert expand(chain)[f"{type_name}.chain_map"] == []


@pytest.mark.parametrize("type_name", ["global_norm", "high_gain"])
def test_the_explicit_map_runs_as_the_derived_one(type_name):
    explicit = _explicit(type_name)
    assert explicit[f"{type_name}.chain_map"] == [2.0, 0.0, 0.0, 2.0]
    a, b = _run(Runner(_flat(type_name))), _run(Runner(explicit))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[0], [0.1, -0.5])      # x0 taken in plant coordinates
    without = dict(explicit, **{f"{type_name}.chain_map": []})
    assert not np.array_equal(_run(Runner(without)), a)   # the map is what makes the difference


@pytest.mark.parametrize("value, says", [
    ([1.0, 2.0, 2.0, 4.0], "invertible"),
    ([1.0, 0.0, 0.0, math.inf], "only finite numbers"),
    ([2.0, 0.0, 2.0], "2x2 matrix"),
])
def test_a_bad_map_is_refused_naming_it(value, says):
    flat = dict(_explicit("global_norm"), **{"global_norm.chain_map": value})
    with pytest.raises(ConfigError) as err:
        Runner(flat)
    assert err.value.parameter == "global_norm.chain_map" and says in err.value.problem


def test_a_map_given_both_ways_is_refused():
    with pytest.raises(ConfigError) as err:
        Runner(_flat("high_gain", **{"high_gain.chain_map": [2.0, 0.0, 0.0, 2.0]}))
    assert err.value.parameter == "high_gain.chain_map"
    assert "given explicitly and derived" in err.value.problem
