"""Params files, the runner settings and the parameter schema (runner/settings.py, observers/base.py)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.observers import REGISTRY, observer_class
from fto_ros.core.params import Param, matrix, resolve
from fto_ros.runner import Runner, SETTINGS, load_params_file
from fto_ros.runner import settings as S

ROOT = Path(__file__).resolve().parents[3]
LUENBERGER = ROOT / "test" / "data" / "dc_motor_explicit" / "dc_motor_luenberger.yaml"
SINGLE_DELAY = ROOT / "test" / "data" / "dc_motor_explicit" / "dc_motor_single_delay.yaml"


@pytest.fixture(scope="module")
def lu_flat():
    return load_params_file(LUENBERGER)


@pytest.fixture(scope="module")
def sd_flat():
    return load_params_file(SINGLE_DELAY)


def refused(fn, parameter, *words):
    """Call fn, expect ConfigError about ``parameter`` whose message holds ``words``."""
    with pytest.raises(ConfigError) as e:
        fn()
    assert e.value.parameter == parameter, str(e.value)
    msg = str(e.value)
    assert f"'{parameter}'" in msg
    for w in words:
        assert w in msg, msg
    return msg


def runner_with(base, **changes):
    flat = dict(base)
    for k, v in changes.items():
        k = k.replace("__", ".")
        if v is None:
            flat.pop(k, None)
        else:
            flat[k] = v
    return Runner(flat)


# -- load_params_file ----------------------------------------------------------------------------
def test_real_configs_load(lu_flat, sd_flat):
    assert lu_flat["observer.type"] == "luenberger"
    assert lu_flat["luenberger.A"][4] == -1.0
    assert lu_flat["luenberger.F"] == ["0", "-35*sin(y0)", "0"]
    assert lu_flat["estimated_joint_states.joint_names"] == ["joint1"]
    assert sd_flat["observer.type"] == "single_delay"
    assert sd_flat["single_delay.tau"] == 0.1
    # every key is flat, dotted, and no value is a mapping
    assert not any(isinstance(v, dict) for v in lu_flat.values())
    Runner(lu_flat)
    Runner(sd_flat)
    Runner(load_params_file(LUENBERGER.with_name("dc_motor_single_delay_sampled.yaml")))


def write(tmp_path, text, name="p.yaml"):
    p = tmp_path / name
    p.write_text(text)
    return p


BLOCKS = """
other_node:
  ros__parameters:
    which: other
/ns/observer_node:
  ros__parameters:
    which: named
/**:
  ros__parameters:
    which: wildcard
"""


def test_block_by_name(tmp_path):
    p = write(tmp_path, BLOCKS)
    assert load_params_file(p, "other_node") == {"which": "other"}
    assert load_params_file(p, "/other_node") == {"which": "other"}
    assert load_params_file(p, "ns/observer_node") == {"which": "named"}
    assert load_params_file(p, "/ns/observer_node") == {"which": "named"}


def test_block_wildcard(tmp_path):
    p = write(tmp_path, BLOCKS)
    assert load_params_file(p, "somebody_else") == {"which": "wildcard"}
    assert load_params_file(p) == {"which": "wildcard"}


def test_a_block_for_another_node_is_refused_as_ros_ignores_it(tmp_path):
    # rcl applies a block only to the node it names: a file whose one block names another
    # node gives that node nothing, so the replay and the node refuse it alike
    p = write(tmp_path, "my_node:\n  ros__parameters:\n    a: {b: 1, c: [1, 2]}\n")
    assert load_params_file(p, "my_node") == {"a.b": 1, "a.c": [1, 2]}
    refused(lambda: load_params_file(p), "params file", "my_node", "/observer_node")
    refused(lambda: load_params_file(p, "not_my_node"), "params file", "not_my_node")


def test_any_namespace_wildcard(tmp_path):
    p = write(tmp_path, "/**/observer_node:\n  ros__parameters: {x: 1}\n"
                        "/**:\n  ros__parameters: {x: 0, y: 2}\n")
    assert load_params_file(p) == {"x": 1, "y": 2}
    assert load_params_file(p, "/robot/observer_node") == {"x": 1, "y": 2}
    assert load_params_file(p, "/robot/other") == {"x": 0, "y": 2}


def test_several_files_merge_in_order_then_overrides(tmp_path):
    a = write(tmp_path, "observer_node:\n  ros__parameters: {p: {x: 1, y: [1.0, 2.0]}}\n", "a.yaml")
    b = write(tmp_path, "observer_node:\n  ros__parameters: {p: {y: [3.0]}, q: s}\n", "b.yaml")
    assert S.load_params_files([a, b]) == {"p.x": 1, "p.y": [3.0], "q": "s"}
    assert S.load_params_files([b, a]) == {"p.x": 1, "p.y": [1.0, 2.0], "q": "s"}
    assert S.load_params_files([a, b], overrides={"p.x": 5}) == {"p.x": 5, "p.y": [3.0], "q": "s"}
    refused(lambda: S.load_params_files([]), "params file")


@pytest.mark.parametrize("text,expected", [
    ("single_delay.tau=0.05", ("single_delay.tau", 0.05)),
    ("a.b:=[1.0, 2.0]", ("a.b", [1.0, 2.0])),
    ("x=true", ("x", True)),
    ("s=hello", ("s", "hello")),
])
def test_parse_override(text, expected):
    from fto_ros.runner.params_file import parse_override
    assert parse_override(text) == expected


@pytest.mark.parametrize("text", ["novalue", "=3", "a=[1, 2.0]", "a={b: 1}", "a=[1"])
def test_parse_override_refused(text):
    from fto_ros.runner.params_file import parse_override
    with pytest.raises(ConfigError):
        parse_override(text)


def test_yaml_aliases_deep_nesting_and_mixed_lists_are_refused(tmp_path):
    bomb = ("a: &a [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]\n"
            + "".join(f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n"
                      for p, c in zip("abcdefgh", "bcdefghi"))
            + "observer_node:\n  ros__parameters:\n    luenberger: {A: *i}\n")
    refused(lambda: load_params_file(write(tmp_path, bomb, "bomb.yaml")), "params file", "aliases")
    deep = "observer_node:\n  ros__parameters:\n    a: " + "[" * 10000 + "]" * 10000 + "\n"
    refused(lambda: load_params_file(write(tmp_path, deep, "deep.yaml")), "params file", "deeper")
    mixed = "observer_node:\n  ros__parameters:\n    luenberger: {A: [1, 2.0]}\n"
    refused(lambda: load_params_file(write(tmp_path, mixed, "mixed.yaml")), "luenberger.A", "decimal")


def test_several_blocks_none_matching(tmp_path):
    p = write(tmp_path, "a:\n  ros__parameters: {x: 1}\nb:\n  ros__parameters: {x: 2}\n")
    refused(lambda: load_params_file(p, "c"), "params file", "'c'")
    refused(lambda: load_params_file(p), "params file")


def test_missing_file(tmp_path):
    refused(lambda: load_params_file(tmp_path / "nope.yaml"), "params file", "nope.yaml", "does not exist")
    refused(lambda: load_params_file(tmp_path), "params file")       # a directory


def test_invalid_yaml(tmp_path):
    p = write(tmp_path, "node:\n  ros__parameters:\n    a: [1, 2\n   b: }\n")
    refused(lambda: load_params_file(p), "params file", "not valid YAML")


@pytest.mark.parametrize("text", [
    "node:\n  parameters:\n    a: 1\n",             # typo in ros__parameters
    "node:\n  ros__parameters: 3\n",
    "node:\n  ros__parameters:\n",
    "node: 5\n",
    "",                                            # empty file
    "- a\n- b\n",                                  # not a mapping
    "42\n",
])
def test_no_ros_parameters(tmp_path, text):
    refused(lambda: load_params_file(write(tmp_path, text)), "params file")


def test_flatten():
    tree = {"a": {"b": {"c": 1, "d": [1.0, 2.0]}, "e": "x"}, "f": True, "g": {}}
    assert S.flatten(tree) == {"a.b.c": 1, "a.b.d": [1.0, 2.0], "a.e": "x", "f": True}
    assert S.flatten({}) == {}
    assert S.flatten({"x": 1}, "pre.") == {"pre.x": 1}


# -- split ---------------------------------------------------------------------------------------
def test_split_types_and_defaults(lu_flat):
    settings, cls, cfg = S.split(lu_flat)
    assert cls is observer_class("luenberger")
    assert settings["observer.type"] == "luenberger"
    assert settings["input.timeout"] == 0.5                        # default
    assert settings["diagnostics.expected_rate"] == 1000.0
    assert isinstance(settings["diagnostics.expected_rate"], float)
    assert settings["time.reset_on_jump"] is True
    assert set(settings) == {p.name for p in SETTINGS}
    assert cfg["n_states"] == 3 and isinstance(cfg["n_states"], int)
    assert cfg["A"] == [0.0, 1.0, 0.0, 0.0, -1.0, 15.0, 0.0, -36.4, -200.0]
    assert all(isinstance(v, float) for v in cfg["A"])
    assert cfg["input_hold"] == "zoh"                               # default
    assert set(cfg) == {p.name for p in cls.PARAMS}


def test_split_refuses_unknown_keys(lu_flat):
    for key in ("observer.typo", "topic.input", "luenberger.polse", "inputs.timeout", "foo"):
        flat = dict(lu_flat)
        flat[key] = 1
        refused(lambda: S.split(flat), key, "unknown parameter")


def test_split_accepts_ros_builtins(lu_flat):
    flat = dict(lu_flat, use_sim_time=True, start_type_description_service=False)
    settings, _, _ = S.split(flat)
    assert "use_sim_time" not in settings
    Runner(flat)


def test_split_ignores_other_observers_sections(lu_flat, sd_flat):
    both = dict(sd_flat)
    both.update({k: v for k, v in lu_flat.items() if k.startswith("luenberger.")})
    assert set(REGISTRY) >= {"luenberger", "single_delay"}
    _, cls, cfg = S.split(both)
    assert cls.TYPE == "single_delay"
    assert cfg["tau"] == 0.1
    # and the other way round, even with a bad value in the ignored section
    both["observer.type"] = "luenberger"
    both["single_delay.tau"] = -1.0
    _, cls, cfg = S.split(both)
    assert cls.TYPE == "luenberger"
    Runner(both)


def test_split_requires_observer_type(lu_flat):
    flat = {k: v for k, v in lu_flat.items() if k != "observer.type"}
    refused(lambda: S.split(flat), "observer.type", "missing", "luenberger", "single_delay")
    refused(lambda: S.split(dict(lu_flat, **{"observer.type": "kalman"})), "observer.type",
            "unknown observer", "'kalman'")
    refused(lambda: S.split(dict(lu_flat, **{"observer.type": 3})), "observer.type")


# -- types, via the real config --------------------------------------------------------------------
def test_ints_accepted_for_doubles(lu_flat, sd_flat):
    r = runner_with(sd_flat, single_delay__k=100, input__timeout=1, time__max_gap=2,
                    diagnostics__expected_rate=1000)
    assert r.observer.k == 100.0 and isinstance(r.observer.k, float)
    assert r.settings["time.max_gap"] == 2.0 and isinstance(r.settings["time.max_gap"], float)
    assert r.settings["input.timeout"] == 1.0 and isinstance(r.settings["input.timeout"], float)
    # ints inside double arrays
    r = runner_with(lu_flat, luenberger__A=[0, 1, 0, 0, -1, 15, 0, -36.4, -200],
                    luenberger__poles=[-50, -60, -70], luenberger__C=[1, 0, 0])
    np.testing.assert_array_equal(r.observer.A[1], [0.0, -1.0, 15.0])


@pytest.mark.parametrize("key,value", [
    ("single_delay.tau", True),
    ("single_delay.k", False),
    ("input.timeout", True),
    ("single_delay.n_unmeasured", True),
])
def test_bools_refused_for_numbers(sd_flat, key, value):
    refused(lambda: Runner(dict(sd_flat, **{key: value})), key, repr(value))


@pytest.mark.parametrize("key,value", [
    ("single_delay.tau", "0.1"),
    ("single_delay.k", "fast"),
    ("time.max_gap", "0.5"),
    ("single_delay.A1", "[-1, 15, -36.4, -200]"),
    ("single_delay.A1", [-1.0, "15", -36.4, -200.0]),
    ("single_delay.A1", [-1.0, True, -36.4, -200.0]),
    ("single_delay.F1", "-35*sin(y0)"),            # a string where a list is expected
    ("single_delay.F1", ["-35*sin(y0)", 40]),
    ("observer.initial_estimate", 0.0),
    ("single_delay.measurement", 1),
    ("single_delay.allow_unstable_internal", 1),
    ("single_delay.allow_unstable_internal", "true"),
])
def test_wrong_types_refused(sd_flat, key, value):
    refused(lambda: Runner(dict(sd_flat, **{key: value})), key)


@pytest.mark.parametrize("key,value", [
    ("single_delay.tau", float("nan")),
    ("single_delay.tau", float("inf")),
    ("input.timeout", float("nan")),
    ("single_delay.A1", [-1.0, float("nan"), -36.4, -200.0]),
    ("observer.initial_estimate", [0.0, float("inf"), 0.0]),
])
def test_non_finite_refused(sd_flat, key, value):
    refused(lambda: Runner(dict(sd_flat, **{key: value})), key, "finite")


@pytest.mark.parametrize("key,value,words", [
    ("input.timeout", 0.0, ("> 0.0", "got 0.0")),
    ("time.max_gap", -1.0, ("> 0.0",)),
    ("time.max_gap", 1e7, ("<= 1000000.0",)),
    ("limits.measurement", [0.0], ("> 0.0",)),
    ("outlier.confirm", 2, (">= 3",)),
    ("diagnostics.window", 0.0, ("> 0.0",)),
    ("time.jump_threshold", -0.1, (">= 0.0",)),
    ("qos.depth", 0, (">= 1",)),
    ("qos.depth", 100001, ("<= 100000",)),
    ("diagnostics.expected_rate", -5.0, (">= 0.0",)),
    ("estimated_joint_states.position_states", [-2], (">= -1",)),
    ("single_delay.n_unmeasured", 0, (">= 1",)),
    ("single_delay.n_unmeasured", 33, ("<= 32",)),
    ("single_delay.lipschitz_K1", -1.0, (">= 0.0",)),
    ("single_delay.substep", 2.0, ("<= 1.0",)),
    ("single_delay.tau", -0.1, (">= 0.0",)),
    ("single_delay.tau", 0.0, ("> 0",)),              # the observer's own check
    ("single_delay.k", 0, ("> 0",)),
    ("single_delay.measurement", "sometimes", ("continuous", "sampled", "'sometimes'")),
    ("source", "serial", ("topics", "joint_states")),
    ("joint_states.output_field", "torque", ("position", "velocity", "effort")),
])
def test_ranges_and_choices_enforced(sd_flat, key, value, words):
    refused(lambda: Runner(dict(sd_flat, **{key: value})), key, *words)


def test_ints_refused_when_fractional(sd_flat, lu_flat):
    refused(lambda: Runner(dict(sd_flat, **{"single_delay.n_unmeasured": 2.5})),
            "single_delay.n_unmeasured", "integer")
    refused(lambda: Runner(dict(lu_flat, **{"estimated_joint_states.position_states": [0.5]})),
            "estimated_joint_states.position_states", "integer")
    # a whole float is an int
    assert runner_with(sd_flat, qos__depth=10.0).settings["qos.depth"] == 10


# BUG (reported): Param.coerce for 'int' and 'int_array' reads strings with float(), so "3" is
# accepted where the double kinds refuse "3.0"; one-line fix in observers/base.py: add str to the
# isinstance(value, bool) check (and to the int_array element check).
@pytest.mark.parametrize("key,value", [("qos.depth", "10"),
                                       ("estimated_joint_states.position_states", ["0"])])
def test_strings_refused_for_ints(lu_flat, key, value):
    refused(lambda: Runner(dict(lu_flat, **{key: value})), key)


# -- Param.coerce / resolve / matrix directly -----------------------------------------------------
def test_coerce_each_kind():
    assert Param("a", "bool", False, "").coerce(np.bool_(True)) is True
    assert Param("a", "int", 0, "").coerce(np.int64(7)) == 7
    assert Param("a", "double", 0.0, "").coerce(np.float32(0.5)) == 0.5
    assert Param("a", "double_array", [], "").coerce(np.array([1, 2])) == [1.0, 2.0]
    assert Param("a", "double_array", [], "").coerce((1, 2.5)) == [1.0, 2.5]
    assert Param("a", "int_array", [], "").coerce([1, 2.0]) == [1, 2]
    assert Param("a", "string_array", [], "").coerce(("x", "y")) == ["x", "y"]
    assert Param("a", "string", "", "", choices=("x", "y")).coerce("y") == "y"
    with pytest.raises(TypeError):
        Param("a", "float", 0.0, "")
    refused(lambda: Param("a", "string_array", [], "").coerce(["x", 1]), "a", "list of strings")
    refused(lambda: Param("a", "double_array", [], "").coerce(5.0), "a", "expected a list")
    refused(lambda: Param("a", "double_array", [], "").coerce({"x": 1}), "a")
    refused(lambda: Param("a", "double_array", [], "").coerce([[1.0], [2.0]]), "a")
    refused(lambda: Param("a", "int", 0, "").coerce(None), "a")
    refused(lambda: Param("a", "double", 0, "").coerce(None), "a")
    refused(lambda: Param("a", "double", 0, "").coerce([1.0]), "a")
    refused(lambda: Param("a", "string", "", "").coerce(3), "a", "expected a string")
    refused(lambda: Param("a", "double_array", [], "", min=0.0).coerce([1.0, -1.0]), "a", ">= 0.0")
    # the full ROS name is the one reported
    refused(lambda: Param("a", "double", 0.0, "", max=1.0).coerce(2, "sec.a"), "sec.a", "<= 1.0")


def test_resolve():
    params = (Param("x", "double", 1.0, ""), Param("y", "double_array", None, "the ys"),
              Param("z", "int", 3, "", min=0))
    out = resolve(params, {"x": 2, "y": [1]})
    assert out == {"x": 2.0, "y": [1.0], "z": 3}
    # the schema owns required-ness: nothing reaches an observer as None
    refused(lambda: resolve(params, {"x": 2}, prefix="sec."), "sec.y", "required", "the ys")
    refused(lambda: resolve(params, {"y": None}, prefix="sec."), "sec.y", "required")
    # null (YAML ~) for a parameter with a default is the default, not a None
    assert resolve(params, {"x": None, "y": [], "z": None}) == {"x": 1.0, "y": [], "z": 3}
    refused(lambda: resolve(params, {"w": 1}, prefix="sec."), "sec.w", "unknown parameter", "x, y, z")
    refused(lambda: resolve(params, {"y": [], "z": -1}, prefix="sec."), "sec.z", ">= 0")


def test_matrix():
    cfg = {"M": [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], "N": None}
    M = matrix(cfg, "M", 2, 3)
    np.testing.assert_array_equal(M, [[1, 2, 3], [4, 5, 6]])                 # row-major
    refused(lambda: matrix(cfg, "M", 3, 3, "sec."), "sec.M", "3x3", "9 values", "got 6 values")
    refused(lambda: matrix(cfg, "N", 1, 1, "sec."), "sec.N", "got nothing")


def test_observer_matrix_shapes_refused(lu_flat, sd_flat):
    refused(lambda: Runner(dict(lu_flat, **{"luenberger.A": [1.0, 2.0]})), "luenberger.A", "3x3")
    refused(lambda: Runner(dict(lu_flat, **{"luenberger.C": [1.0, 0.0]})), "luenberger.C", "1x3")
    refused(lambda: Runner({k: v for k, v in sd_flat.items() if k != "single_delay.A1"}),
            "single_delay.A1", "required")


# -- check_settings -------------------------------------------------------------------------------
def test_initial_estimate_length(lu_flat, sd_flat):
    assert runner_with(lu_flat, observer__initial_estimate=[0.1, 0.0, 0.0]).settings[
        "observer.initial_estimate"] == [0.1, 0.0, 0.0]
    refused(lambda: runner_with(lu_flat, observer__initial_estimate=[0.1, 0.0]),
            "observer.initial_estimate", "expected 3 values, got 2")
    refused(lambda: runner_with(sd_flat, observer__initial_estimate=[0.0] * 4),
            "observer.initial_estimate", "expected 3 values, got 4")


def test_joint_lists_checked_only_for_joint_states_source(lu_flat):
    # the config has output_joints but no input_joints: fine with topics ...
    runner_with(lu_flat)
    # ... refused when the joints are the source
    refused(lambda: runner_with(lu_flat, source="joint_states"), "joint_states.input_joints",
            "expected 1 joint name", "one per input")
    r = runner_with(lu_flat, source="joint_states", joint_states__input_joints=["joint1"])
    assert r.settings["source"] == "joint_states"
    refused(lambda: runner_with(lu_flat, source="joint_states", joint_states__input_joints=["joint1"],
                                joint_states__output_joints=["joint1", "joint2"]),
            "joint_states.output_joints", "expected 1 joint name", "one per output")
    refused(lambda: runner_with(lu_flat, source="joint_states", joint_states__input_joints=["joint1"],
                                joint_states__output_joints=[]),
            "joint_states.output_joints")


@pytest.mark.parametrize("field", ["position", "velocity", "effort"])
def test_estimated_joint_states_indices(lu_flat, field):
    key = f"estimated_joint_states.{field}_states"
    refused(lambda: Runner(dict(lu_flat, **{key: [0, 1]})), key, "one index per joint (1)", "got 2")
    refused(lambda: Runner(dict(lu_flat, **{key: [3]})), key, "state index 3 out of range", "n = 3")
    # -1 = none, and an empty list = none
    for ok in ([-1], [], [2]):
        Runner(dict(lu_flat, **{key: ok}))


def test_estimated_joint_states_two_joints(lu_flat):
    flat = dict(lu_flat, **{"estimated_joint_states.joint_names": ["a", "b"],
                            "estimated_joint_states.position_states": [0, 1],
                            "estimated_joint_states.velocity_states": [1, 2],
                            "estimated_joint_states.effort_states": []})
    Runner(flat)
    # a mix of -1 and indices: JointState fields are all-or-nothing
    refused(lambda: Runner(dict(flat, **{"estimated_joint_states.velocity_states": [1, -1]})),
            "estimated_joint_states.velocity_states", "all-or-nothing")
    # indices without names: one index per joint (0)
    refused(lambda: Runner(dict(flat, **{"estimated_joint_states.joint_names": []})),
            "estimated_joint_states.position_states", "(0)")


def test_check_settings_direct():
    base = {p.name: p.default for p in SETTINGS}
    base["observer.type"] = "luenberger"
    S.check_settings(base, 2, 1, 0)
    js = dict(base, source="joint_states")
    refused(lambda: S.check_settings(js, 2, 1, 0), "joint_states.output_joints")
    S.check_settings(dict(js, **{"joint_states.output_joints": ["j"]}), 2, 1, 0)


# -- the fault audit's parameter findings (each raised TypeError/OverflowError before) ----------
def test_missing_required_parameter_is_one_line_not_a_type_error(sd_flat):
    flat = {k: v for k, v in sd_flat.items() if k != "single_delay.n_unmeasured"}
    refused(lambda: Runner(flat), "single_delay.n_unmeasured", "required")


@pytest.mark.parametrize("key", ["diagnostics.expected_rate", "single_delay.lipschitz_K1",
                                 "time.max_gap", "outlier.threshold"])
def test_null_means_the_default(sd_flat, key):
    r = Runner(dict(sd_flat, **{key: None}))
    default = next(p.default for p in (*SETTINGS, *r.observer_class.PARAMS)
                   if key.endswith(p.name))
    assert r.settings.get(key, r.observer_config.get(key.split(".", 1)[1])) == default


@pytest.mark.parametrize("key,value", [("single_delay.k", 10 ** 400), ("qos.depth", 10 ** 400),
                                       ("single_delay.A1", [10 ** 400, 0, 0, 0]),
                                       ("estimated_joint_states.position_states", [10 ** 400])])
def test_integers_beyond_double_range_are_refused(sd_flat, key, value):
    refused(lambda: Runner(dict(sd_flat, **{key: value})), key)
