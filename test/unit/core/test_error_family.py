"""One error family (fto_ros/core/errors.py): every ``raise`` in the package raises an
FtoRosError subclass declared there.

Parsed from the sources (ast), every module of fto_ros:
- no ``raise`` of a builtin exception class (``raise ValueError(...)``, ``raise KeyError``,
  ``raise SystemExit(...)``); a bare ``raise`` (re-raising what was caught) and ``raise
  err`` of a caught exception are fine;
- a raised class that can be looked up in its module (a module-level name or a dotted
  name such as ``argparse.ArgumentTypeError``) is an FtoRosError from core/errors.py;
- every exception class the package defines is defined in core/errors.py.

EXCLUDED lists the files other work owns while this rule lands; they follow the same
rule, and the list shrinks to empty when that work is merged.
"""
from __future__ import annotations

import ast
import builtins
import fnmatch
import importlib
from pathlib import Path

import pytest

from fto_ros.core import errors
from fto_ros.core.errors import FtoRosError

ROOT = Path(__file__).resolve().parents[3]
PKG = ROOT / "fto_ros"

#: files owned by work in progress elsewhere (see the module doc): repository paths, globs
EXCLUDED = (
    "fto_ros/arm/*", "fto_ros/runner/torque_*.py", "fto_ros/nodes/torque_node.py",
    "fto_ros/models/arm*.py", "fto_ros/cli/simulate_arm.py",
)

BUILTIN_EXCEPTIONS = frozenset(
    name for name in dir(builtins)
    if isinstance(getattr(builtins, name), type) and issubclass(getattr(builtins, name), BaseException))


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if any(fnmatch.fnmatch(rel, pattern) for pattern in EXCLUDED):
            continue
        yield rel, path, ast.parse(path.read_text())


def _raised(node: ast.Raise):
    """The expression naming what a raise raises: the callee of ``raise X(...)``, else X."""
    return node.exc.func if isinstance(node.exc, ast.Call) else node.exc


def builtin_raises(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, name) of every raise of a builtin exception class in ``tree``."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and node.exc is not None:
            what = _raised(node)
            if isinstance(what, ast.Name) and what.id in BUILTIN_EXCEPTIONS:
                out.append((node.lineno, what.id))
    return out


def _module(rel: str, tree: ast.AST):
    """The imported module, or None for one that needs ROS (rclpy) to import."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] + [getattr(node, "module", None) or ""]
            if any(n.split(".")[0] == "rclpy" for n in names):
                return None
    return importlib.import_module(rel[:-3].replace("/", ".").removesuffix(".__init__"))


def _lookup(module, expr: ast.expr):
    """The object a module-level name or dotted name refers to in ``module`` (None: not
    one, e.g. a local variable holding a caught exception)."""
    parts = []
    while isinstance(expr, ast.Attribute):
        parts.append(expr.attr)
        expr = expr.value
    if not isinstance(expr, ast.Name):
        return None
    obj = getattr(module, expr.id, None)
    for attr in reversed(parts):
        obj = getattr(obj, attr, None)
    return obj


def test_no_raise_of_a_builtin_exception():
    bad = [f"{rel}:{line}: raise {name}" for rel, _, tree in _modules()
           for line, name in builtin_raises(tree)]
    assert not bad, "raise an FtoRosError subclass from core/errors.py instead:\n" + "\n".join(bad)


def test_every_raised_class_is_of_the_family():
    bad = []
    for rel, _, tree in _modules():
        module = _module(rel, tree)
        if module is None:
            continue
        for node in ast.walk(tree):
            if not isinstance(node, ast.Raise) or node.exc is None:
                continue
            obj = _lookup(module, _raised(node))
            if isinstance(obj, type) and not (issubclass(obj, FtoRosError)
                                              and obj.__module__ == errors.__name__):
                bad.append(f"{rel}:{node.lineno}: raise {obj.__module__}.{obj.__qualname__}")
    assert not bad, "\n".join(bad)


def test_every_exception_class_is_declared_in_core_errors():
    bad = []
    for rel, _, tree in _modules():
        if rel == "fto_ros/core/errors.py":
            continue
        module = _module(rel, tree)
        if module is None:
            continue
        for node in tree.body:
            if isinstance(node, ast.ClassDef):
                cls = getattr(module, node.name, None)
                if isinstance(cls, type) and issubclass(cls, BaseException) \
                        and not issubclass(cls, Warning):
                    bad.append(f"{rel}: class {node.name}")
    assert not bad, "declare error classes in fto_ros/core/errors.py:\n" + "\n".join(bad)


@pytest.mark.parametrize("source, found", [
    ("raise ValueError('x')", [(1, "ValueError")]),
    ("raise KeyError", [(1, "KeyError")]),
    ("def f():\n    raise SystemExit(f())", [(2, "SystemExit")]),
    ("try:\n    pass\nexcept ValueError:\n    raise", []),
    ("try:\n    pass\nexcept ValueError as err:\n    raise err", []),
    ("raise ConfigError('a', 'b') from None", []),
])
def test_the_check_sees_what_it_must(source, found):
    """The AST check itself: builtin raises found, re-raises and the family's not."""
    assert builtin_raises(ast.parse(source)) == found


def test_the_family_keeps_the_builtin_callers_catch():
    """A class that replaced a builtin raise is still caught as that builtin."""
    assert issubclass(errors.BadArgument, ValueError)
    assert issubclass(errors.DecodeError, ValueError)
    assert issubclass(errors.SimulationFailed, ValueError)
    assert issubclass(errors.SampleRejected, ValueError)
    assert issubclass(errors.UsageError, TypeError)
    assert issubclass(errors.NotReady, RuntimeError)
    assert issubclass(errors.UnknownName, KeyError)
    assert str(errors.UnknownName("unknown model 'x'")) == "unknown model 'x'"
