"""Generated model modules (core/model_code.py): only the text generated from the user's
model runs.  A planted bytecode file never runs (F1, F4), a module file with other text or
bytes that are not UTF-8 is discarded and written again with one WARN line naming it (F9),
a foreign or shared cache is not used (F1) and no predictable folder in the shared temp
directory is made, a full or read-only cache means the module lives in memory (F8)."""
from __future__ import annotations

import errno
import hashlib
import importlib.util
import os
import py_compile
import sys
import tempfile

import numpy as np
import pytest
import sympy

from cache_helpers import (cache_root, fail_writes, foreign, payload_source,  # noqa: F401
                           warnings_of)
from fto_ros.core import model_code as MC

X = sympy.symbols("q v", real=True)


def generated(tag: float):
    """A model's source and its module name (a constant of its own per test: a module no
    other test of this process loaded)."""
    source = MC._source([X[0] * tag + sympy.sin(X[1])], [X])
    name = "fto_model_" + hashlib.sha256(source.encode()).hexdigest()[:20]
    sys.modules.pop(name, None)
    return source, name


def value(fn) -> float:
    out = np.zeros(1)
    assert fn(np.array([2.0, 0.5]), np.zeros(0), np.zeros(0), out) == 0
    return out[0]


def expected(tag: float) -> float:
    return 2.0 * tag + np.sin(0.5)


def plant_pyc(models, name: str, marker) -> list:
    """Bytecode files of a payload where the import system would look for the module's,
    unchecked (run whatever the source says), as an attacker would plant them."""
    payload = models.parent / "payload.py"
    payload.write_text(payload_source(marker))
    cached = importlib.util.cache_from_source(str(models / f"{name}.py"))
    paths = [cached, str(models / f"{name}.pyc")]
    for path in paths:
        py_compile.compile(str(payload), cfile=path, doraise=True,
                           invalidation_mode=py_compile.PycInvalidationMode.UNCHECKED_HASH)
    return paths


@pytest.mark.parametrize("dont_write", [False, True])
def test_a_planted_pyc_beside_the_right_module_never_runs(cache_root, tmp_path, monkeypatch,
                                                          dont_write):
    if dont_write:
        monkeypatch.setattr(sys, "dont_write_bytecode", True)
    source, name = generated(1.25)
    models = MC.cache_dir()
    (models / f"{name}.py").write_text(source)           # the right text, in place
    os.chmod(models / f"{name}.py", 0o600)
    marker = tmp_path / "payload-ran"
    planted = plant_pyc(models, name, marker)
    fn = MC._load(source)
    assert not marker.exists()
    assert value(fn) == pytest.approx(expected(1.25))
    assert all(os.path.exists(p) for p in planted)        # there, and not run


def test_a_module_with_other_text_is_discarded_and_written_again(cache_root, tmp_path, caplog):
    source, name = generated(1.5)
    path = MC.cache_dir() / f"{name}.py"
    marker = tmp_path / "payload-ran"
    path.write_text(payload_source(marker))
    os.chmod(path, 0o600)
    fn = MC._load(source)
    assert not marker.exists() and value(fn) == pytest.approx(expected(1.5))
    assert path.read_text() == source
    (line,) = warnings_of(caplog)
    assert str(path) in line and "not the text generated" in line


def test_a_module_with_bytes_that_are_not_utf8_heals(cache_root, caplog):
    source, name = generated(1.75)
    path = MC.cache_dir() / f"{name}.py"
    path.write_bytes(source.encode()[:40] + b"\xff\xfe\x80 junk")
    os.chmod(path, 0o600)
    assert value(MC._load(source)) == pytest.approx(expected(1.75))
    assert path.read_bytes() == source.encode()
    assert len(warnings_of(caplog)) == 1 and str(path) in warnings_of(caplog)[0]
    sys.modules.pop(f"{name}", None)
    MC._load(source)                                        # healed: no second warning
    assert len(warnings_of(caplog)) == 1


def test_a_foreign_module_file_in_the_own_folder_is_replaced(cache_root, caplog):
    source, name = generated(2.25)
    path = MC.cache_dir() / f"{name}.py"
    path.write_text(source)                   # even the right text: not this user's file
    foreign(path)
    assert value(MC._load(source)) == pytest.approx(expected(2.25))
    assert os.stat(path).st_uid == os.getuid()
    assert "owned by uid" in warnings_of(caplog)[0]


@pytest.mark.parametrize("spoil", ["foreign", "world-writable"])
def test_a_shared_or_foreign_cache_is_not_used_and_no_temp_folder_is_made(
        cache_root, tmp_path, monkeypatch, caplog, spoil):
    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setenv("TMPDIR", str(temp))
    monkeypatch.setattr(tempfile, "tempdir", None)
    source, name = generated(2.5)
    models = cache_root / "models"
    models.mkdir(parents=True)
    marker = tmp_path / "payload-ran"
    (models / f"{name}.py").write_text(payload_source(marker))
    plant_pyc(models, name, marker)
    if spoil == "foreign":
        foreign(cache_root)
    else:
        os.chmod(cache_root, 0o777)
    fn = MC._load(source)
    assert not marker.exists() and value(fn) == pytest.approx(expected(2.5))
    assert fn.__code__.co_filename == f"<generated {name}>"      # held in memory
    assert list(temp.iterdir()) == []         # no fto_ros_models_<uid> to predict
    assert "refused" in warnings_of(caplog)[0]


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_a_full_or_read_only_cache_keeps_the_module_in_memory(cache_root, monkeypatch, caplog,
                                                              code):
    MC.cache_dir()
    fail_writes(monkeypatch, code, cache_root)
    source, name = generated(3.5 if code == errno.ENOSPC else 3.75)
    fn = MC._load(source)
    assert value(fn) == pytest.approx(expected(3.5 if code == errno.ENOSPC else 3.75))
    assert fn.__code__.co_filename == f"<generated {name}>"
    assert len(warnings_of(caplog)) == 1 and os.strerror(code) in warnings_of(caplog)[0]
