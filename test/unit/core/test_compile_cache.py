"""numba's compiled-code cache (core/compile_cache.py): its pickles (.nbi, .nbc) are read
only from a private folder and only when they are this user's own files (F3); a corrupt,
truncated or foreign one is discarded with one WARN line naming it and the function is
compiled again (F7); a full or read-only disk means running uncached (F8)."""
from __future__ import annotations

import errno
import importlib.util
import os
import pickle
import uuid

import pytest

from cache_helpers import (cache_root, fail_writes, foreign, payload_bytes,  # noqa: F401
                           warnings_of)
from fto_ros.core import jit

pytestmark = pytest.mark.skipif(not jit.ENABLED, reason="numba is off (FTO_ROS_NUMBA=0): "
                                "no compiled-code cache")
if jit.ENABLED:
    import numba


@pytest.fixture
def kernel_source(tmp_path):
    """The function ``twice`` in a module file of its own (numba caches beside a file)."""
    src = tmp_path / "src"
    src.mkdir()
    path = src / f"kern_{uuid.uuid4().hex[:8]}.py"
    path.write_text("def twice(x):\n    return 2.0 * x + 1.0\n")
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.twice


def compiled(fn):
    """A new dispatcher of ``fn`` (as core/jit.py makes them), called once."""
    disp = jit._njit(fn)
    assert disp(3.0) == 7.0
    return disp


def cache_files(disp):
    """(index path, [data paths]) of the dispatcher's cache."""
    file = disp._cache._cache_file
    index = file._index_path
    folder = os.path.dirname(index)
    data = sorted(os.path.join(folder, n) for n in os.listdir(folder) if n.endswith(".nbc"))
    return index, data


def hits(disp) -> int:
    return sum(disp.stats.cache_hits.values())


def test_compiled_code_is_cached_in_the_private_folder(cache_root, kernel_source):
    first = compiled(kernel_source)
    index, data = cache_files(first)
    assert index.startswith(str(cache_root / "numba")) and data
    assert hits(compiled(kernel_source)) == 1                      # read back


@pytest.mark.parametrize("damage", ["garbage index", "truncated index", "truncated data",
                                    "garbage data"])
def test_a_damaged_cache_file_is_discarded_and_compiled_again(cache_root, kernel_source,
                                                              caplog, damage):
    index, data = cache_files(compiled(kernel_source))
    path = index if "index" in damage else data[0]
    content = open(path, "rb").read()
    with open(path, "wb") as f:
        f.write(b"x" * 64 if "garbage" in damage else content[:len(content) // 2])
    again = compiled(kernel_source)                    # compiled, not a failed start
    assert hits(again) == 0
    (line,) = warnings_of(caplog)
    assert path in line and "compiling again" in line
    assert hits(compiled(kernel_source)) == 1          # healed: saved again, read back
    assert len(warnings_of(caplog)) == 1


def _payload_index(path: str, marker) -> None:
    """An index that runs the payload when numba unpickles it (the right version first)."""
    with open(path, "wb") as f:
        f.write(pickle.dumps(numba.__version__) + payload_bytes(marker))


def test_a_foreign_index_in_the_own_folder_is_never_unpickled(cache_root, kernel_source,
                                                              tmp_path, caplog):
    index, _ = cache_files(compiled(kernel_source))
    marker = tmp_path / "payload-ran"
    _payload_index(index, marker)
    foreign(index)
    assert hits(compiled(kernel_source)) == 0
    assert not marker.exists()
    assert index in warnings_of(caplog)[0] and "owned by uid" in warnings_of(caplog)[0]


@pytest.mark.parametrize("spoil", ["world-writable root", "foreign root", "group-writable leaf"])
def test_a_shared_or_foreign_cache_folder_is_never_read(cache_root, kernel_source, tmp_path,
                                                        caplog, spoil):
    index, _ = cache_files(compiled(kernel_source))
    marker = tmp_path / "payload-ran"
    _payload_index(index, marker)
    if spoil == "world-writable root":
        os.chmod(cache_root, 0o777)
    elif spoil == "foreign root":
        foreign(cache_root)
    else:
        os.chmod(os.path.dirname(index), 0o770)
    disp = jit._njit(kernel_source)
    assert disp(3.0) == 7.0 and not marker.exists()
    assert "refused" in warnings_of(caplog)[0]


def test_a_shared_numba_cache_dir_of_the_user_is_checked_too(cache_root, kernel_source,
                                                             tmp_path, monkeypatch, caplog):
    shared = tmp_path / "numba-shared"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(shared))
    index, _ = cache_files(compiled(kernel_source))
    assert index.startswith(str(shared))
    marker = tmp_path / "payload-ran"
    _payload_index(index, marker)
    os.chmod(shared, 0o757)
    assert compiled(kernel_source) and not marker.exists()
    assert str(shared) in warnings_of(caplog)[0]


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_a_full_or_read_only_disk_compiles_uncached(cache_root, kernel_source, monkeypatch,
                                                    caplog, code):
    jit._cc.numba_folder()                           # the folders exist; the disk fills up
    fail_writes(monkeypatch, code, cache_root)
    disp = compiled(kernel_source)
    assert not any(n.endswith((".nbi", ".nbc")) for _, _, names in os.walk(cache_root)
                   for n in names)
    assert hits(disp) == 0 and not jit.caching()
    (line,) = warnings_of(caplog)
    assert os.strerror(code) in line
