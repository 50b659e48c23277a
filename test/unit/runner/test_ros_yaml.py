"""The params-file reader (runner/ros_yaml.py) against rcl's own parser: every spelling of a
value gets the type and the value a node started on the same file gets (the node reads it
with rcl_yaml_param_parser, in C), and a file rcl refuses is refused.  Its strtoll/strtod
are checked against the C library's too (ctypes), on the spellings and around the limits."""
from __future__ import annotations

import ctypes
import ctypes.util
import json
import math
import os
import sys
from pathlib import Path

import pytest

import domains
import processes
from fto_ros.core.errors import ConfigError
from fto_ros.runner.params_file import load_params_file, parse_override
from fto_ros.runner.ros_yaml import MAX_ITEMS, _strtod, _strtoll, read_text

ROOT = Path(__file__).resolve().parents[3]

#: scalar spellings (each a parameter of its own in one file)
SCALARS = [
    "1", "+1", "-1", "0", "-0", "00", "010", "08", "0x1F", "0X1f", "-0x1", "0x", "0xg",
    "0x7FFFFFFFFFFFFFFF", "9223372036854775807", "9223372036854775808", "-9223372036854775808",
    "-9223372036854775809", "1_000", "0o17", "0b101", "1:30",
    "1.0", "1.", ".5", "+.5", "-.5", "1.0e4", "1e4", "1E5", "1e+5", "1e-300", "1.0e-300",
    "1e300", "1.0e+300", "1e308", "1.7976931348623157e308", "1.7976931348623159e308", "1e309",
    "1e400", "1e-310", "1e-320", "5e-324", "2e-324", "1e-400", "0e-400", "12e-400", "1e", "1e5e",
    "1.5e", "0x1p3", "0x1.8p3", "0x1p-1074", "0x1p-1075", "0x.8",
    ".nan", ".NaN", ".NAN", "nan", "NaN", "nan(1)", ".inf", ".Inf", ".INF", "+.inf", "-.inf",
    "-.INF", "inf", "+inf", "-inf", "Infinity", "-infinity", "INF", ".inF",
    "y", "Y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON", "n", "N", "no",
    "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF", "tRUE", "yES", "t", "f",
    "~", "null", "Null", "NULL", "abc", "1.0.0", "'1.5'", '"2"', "''", "!!str 3", "!!str 1.5",
    "!!float 1", "!!int '5'", "'  7'", "1 # a comment", "'%'",
]
#: list spellings
LISTS = ["[]", "[1.0, 2.5]", "[1, 2]", "[a, b]", "['1', '2']", "[y, n]", "[true, false]",
         "[1e-300, 1e300]", "[.nan, .inf, -.inf]", "[0x10, 010, 10]", "[1.0, ]", "!!str [1, 2]",
         "[~, null]"]
#: files rcl refuses (a parameter's value)
REFUSED = ["", "[1.0, 'a']", "[1, 2.0]", "[1, 9223372036854775808]", "[1e-310, 1.0]",
           "[.nan, 1e400]", "[[1.0], [2.0]]", "[true, 1]"]

_RCL = r"""
import json, math, sys, rclpy
from rclpy.node import Node
ctx = rclpy.Context()
try:
    rclpy.init(args=["x", "--ros-args", "--params-file", sys.argv[1]], context=ctx)
except Exception as exc:
    print(json.dumps({"__error__": str(exc)})); sys.exit(0)
node = Node("observer_node", context=ctx)
def enc(v):
    if isinstance(v, float):
        return "float:" + repr(v)
    if isinstance(v, (list, tuple)) or hasattr(v, "tolist"):
        return [enc(x) for x in (v.tolist() if hasattr(v, "tolist") else v)]
    return v
print(json.dumps({k: [p.type_.name, enc(p.value)] for k, p in node._parameter_overrides.items()}))
node.destroy_node()
rclpy.shutdown(context=ctx)
"""


def rcl_read(path: Path) -> dict:
    """What a node started with ``--params-file path`` gets: {name: (type, value)}."""
    pytest.importorskip("rclpy")
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(domains.take()),
               ROS_LOG_DIR=str(path.parent / "roslog"))
    res = processes.run([sys.executable, "-c", _RCL, str(path)], capture_output=True,
                        timeout=60, env=env)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def ours(value) -> list:
    """Our value in rclpy's terms: [type name, value encoded as rcl_read encodes it]."""
    def enc(v):
        return "float:" + repr(v) if isinstance(v, float) else v
    if value is None:
        return ["NOT_SET", None]
    if isinstance(value, list):
        kind = {bool: "BOOL", int: "INTEGER", float: "DOUBLE", str: "STRING"}[type(value[0])]
        return [kind + "_ARRAY", [enc(v) for v in value]]
    kind = {bool: "BOOL", int: "INTEGER", float: "DOUBLE", str: "STRING"}[type(value)]
    return [kind, enc(value)]


def _file(tmp_path: Path, name: str, values: list[str]) -> Path:
    body = "".join(f"    p{i}: {v}\n" for i, v in enumerate(values))
    path = tmp_path / name
    path.write_text("observer_node:\n  ros__parameters:\n" + body)
    return path


def _nan_safe(x):
    return "float:nan" if x in ("float:nan", "float:-nan") else x


def test_every_spelling_reads_as_rcl_reads_it(tmp_path):
    values = SCALARS + LISTS
    path = _file(tmp_path, "spellings.yaml", values)
    theirs = rcl_read(path)
    mine = load_params_file(path)
    wrong = []
    for i, text in enumerate(values):
        a, b = ours(mine[f"p{i}"]), theirs[f"p{i}"]
        a[1] = [_nan_safe(x) for x in a[1]] if isinstance(a[1], list) else _nan_safe(a[1])
        b[1] = [_nan_safe(x) for x in b[1]] if isinstance(b[1], list) else _nan_safe(b[1])
        if a != b:
            wrong.append((text, a, b))
    assert not wrong, wrong


@pytest.mark.parametrize("value", REFUSED)
def test_what_rcl_refuses_is_refused(tmp_path, value):
    path = _file(tmp_path, "bad.yaml", [value])
    assert "__error__" in rcl_read(path)
    with pytest.raises(ConfigError):
        load_params_file(path)


def test_the_issue_spellings():
    """PyYAML (YAML 1.1) read 1.0e4 and 1e-300 as strings, 1_000 as 1000, 0x1F as 31 (which
    rcl does too), ~ as None: the replay refused what the node accepted."""
    for text, want in [("1.0e4", 1.0e4), ("1e-300", 1e-300), (".inf", math.inf), ("1_000", "1_000"),
                       ("0x1F", 31), ("+1", 1), ("1.", 1.0), (".5", 0.5), ("1E5", 1e5),
                       ("~", "~"), ("9223372036854775808", 9.223372036854775808e18)]:
        value = parse_override(f"x={text}")[1]
        assert value == want and type(value) is type(want), (text, value)


def test_a_refused_list_names_the_element():
    with pytest.raises(ConfigError) as err:
        parse_override("single_delay.A1=[" + ", ".join(["1.0"] * 500) + ", 2, 3.0]")
    msg = str(err.value)
    assert err.value.parameter == "single_delay.A1"
    assert "element 500 (2)" in msg and "element 0 (1.0)" in msg and "..." not in msg, msg


def test_sizes_are_refused_before_anything_is_built(tmp_path):
    big = "[" + ", ".join(["1.0"] * (MAX_ITEMS + 1)) + "]"
    with pytest.raises(ConfigError, match=f"over {MAX_ITEMS} elements: at most"):
        read_text(f"a:\n  b: {big}\n", "f.yaml")
    many = "".join(f"k{i}: 1\n" for i in range(MAX_ITEMS + 1))
    with pytest.raises(ConfigError, match=f"over {MAX_ITEMS} keys: at most"):
        read_text(many, "f.yaml")
    with pytest.raises(ConfigError, match="given twice"):
        read_text("a: 1\na: 2\n", "f.yaml")
    with pytest.raises(ConfigError, match="more than one YAML document"):
        read_text("a: 1\n---\nb: 2\n", "f.yaml")


# -- the C library's strtoll and strtod ------------------------------------------------------------
_libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
_libc.strtod.restype = ctypes.c_double
_libc.strtod.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p)]
_libc.strtoll.restype = ctypes.c_longlong
_libc.strtoll.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p), ctypes.c_int]


def _c(fn, text: str, *extra):
    """fn's value when it reads all of text without errno, else None (rcl's test)."""
    buf = ctypes.create_string_buffer(text.encode())
    end = ctypes.c_char_p()
    ctypes.set_errno(0)
    value = fn(buf, ctypes.byref(end), *extra)
    used = ctypes.cast(end, ctypes.c_void_p).value - ctypes.addressof(buf)
    ok = ctypes.get_errno() == 0 and text and used == len(text.encode())
    return value if ok else None


EDGES = ["1e-308", "2.2250738585072014e-308", "2.2250738585072011e-308", "4.9406564584124654e-324",
         "2.4703282292062327e-324", "2.4703282292062328e-324", "0x1p-1022", "0x1.0000000000001p-1022",
         "0x0.0000000000001p-1022", "0x1p1023", "0x1p1024", "0x1.fffffffffffffp1023",
         "1.7976931348623158e308", "1.79769313486231580793e308", "0.000", "-0.0e-999", " 1",
         "\t2", "1 ", "+", "-", ".", "e5", "0x1p", "0x1p+", "nan()", "nan(a_b)", "infinit",
         # sizes that must not cost time or memory
         "1e999999999", "1e-999999999", "0e999999999", "-0.0e-999999999", "0x1p9999999",
         "0x1p-9999999", "0x0p99999999", "9" * 50, "-" + "9" * 50, "0x" + "f" * 40, "0" * 40,
         "1" + "0" * 5000 + "e-5310", "1" + "0" * 400 + "e-720"]


@pytest.mark.parametrize("text", [s for s in SCALARS + EDGES if not s.startswith(("'", '"', "!"))])
def test_strtoll_and_strtod_are_the_c_librarys(text):
    assert _strtoll(text) == _c(_libc.strtoll, text, 0)
    c = _c(_libc.strtod, text)
    mine = _strtod(text)
    if c is not None and math.isnan(c):
        assert mine is not None and math.isnan(mine)
    else:
        assert mine == c and (mine is None or math.copysign(1, mine) == math.copysign(1, c)), (mine, c)
