"""numba's on-disk cache of compiled code, kept in the private cache folder and trusted
only there (imported by core/jit.py when numba is on; docs/security.md).

numba caches a function as an index file (``*.nbi``) and data files (``*.nbc``), both
pickles: loading them runs whatever they say, so they must come from nowhere but this
user's private folder.  numba's own cache looks in several places (``NUMBA_CACHE_DIR``, a
``__pycache__`` beside the source, a user-wide folder) and stops a start on a damaged file
(``UnpicklingError: invalid load key``, naming no file).  :class:`PrivateCache` replaces it
for every function core/jit.py compiles:

- one place: ``<cache root>/numba/<version of the sources>`` (or ``NUMBA_CACHE_DIR`` where
  the user set it), the folders checked by core/private_cache.py (owner, mode, no symlink)
  at every load and save; a function whose source is no file (a generated module held in
  memory) is not cached;
- each file read is this user's own regular file that nobody else may write (else it is
  foreign: discarded, never unpickled);
- a file that cannot be read or unpickled, or whose contents numba cannot rebuild, is
  discarded with one WARN line naming it, and the function is compiled again (and saved);
- a save that fails (a full or read-only disk) stops the cache's writes for the process
  (one WARN line): the run goes on, uncached.

Written against numba.core.caching's documented structure (a ``Cache`` with an
implementation class choosing a locator, an ``IndexDataCacheFile`` reading the index and
the data); the dispatcher's cache is set by :func:`attach`.
"""
from __future__ import annotations

import contextlib
import inspect
import io
import os
import pickle
import sys
from pathlib import Path

import numba
from numba.core import caching as _nc

from . import private_cache as PC
from .errors import CacheError


class _Locator(_nc._SourceFileBackedLocatorMixin, _nc._CacheLocator):
    """The function's cache folder: one sub-folder of the private folder per source folder
    (as numba names them), created 0700 and checked by private_cache."""

    def __init__(self, py_func, py_file: str, top: Path):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._top = top
        self._sub = self.get_suitable_cache_subpath(py_file)

    def get_cache_path(self) -> str:
        return str(self._top / self._sub)

    def ensure_cache_path(self) -> None:
        if PC.folder(self._sub, top=self._top) is None:
            raise CacheError(f"the cache folder {self.get_cache_path()} is not usable")


class _Impl(_nc.CompileResultCacheImpl):
    """numba's compile-result cache with one locator: the private folder."""

    def __init__(self, py_func):          # numba's would try its other places too
        top = numba_folder()
        py_file = inspect.getfile(py_func)
        if top is None or not os.path.isfile(py_file):
            raise CacheError(f"no disk cache for {py_file}")
        self._lineno = py_func.__code__.co_firstlineno
        self._locator = _Locator(py_func, py_file, top)
        module = os.path.splitext(os.path.basename(py_file))[0]
        qualname = getattr(py_func, "__qualname__", py_func.__name__)
        self._filename_base = self.get_filename_base(f"{module}.{qualname}",
                                                     getattr(sys, "abiflags", ""))


class _CheckedFile(_nc.IndexDataCacheFile):
    """The index and data files, read only when trusted, written exclusively."""

    def _read(self, path: str):
        try:
            data = PC.read_file(Path(path))
        except CacheError as err:
            raise CacheError(err.why, path) from None
        return data

    def _load_index(self):
        data = self._read(self._index_path)
        if data is None:
            return {}
        try:
            stream = io.BytesIO(data)
            version = pickle.load(stream)
            if version != self._version:
                return {}           # another numba's: overwritten at the next save
            stamp, overloads = pickle.loads(stream.read())
        except Exception as err:    # noqa: BLE001  any unreadable index is damaged
            raise CacheError(f"{type(err).__name__}: {err}", self._index_path) from None
        if not isinstance(overloads, dict):
            raise CacheError(f"an index of {type(overloads).__name__}", self._index_path)
        return overloads if stamp == self._source_stamp else {}

    def _load_data(self, name):
        path = self._data_path(name)
        data = self._read(path)
        if data is None:
            return None                         # numba's load: not there, compile
        self.last_data = path
        try:
            return pickle.loads(data)
        except Exception as err:    # noqa: BLE001
            raise CacheError(f"{type(err).__name__}: {err}", path) from None

    @contextlib.contextmanager
    def _open_for_write(self, filepath):
        with PC.open_for_write(Path(filepath)) as f:
            yield f


class PrivateCache(_nc.FunctionCache):
    """A function's cache in the private folder (see the module doc)."""

    _impl_class = _Impl

    def __init__(self, py_func):
        super().__init__(py_func)
        self._cache_file = _CheckedFile(self._cache_path, self._impl.filename_base,
                                        self._impl.locator.get_source_stamp())

    def _usable(self) -> bool:
        """The function's folder and every folder up to the cache root, checked now."""
        locator = self._impl.locator
        return numba_folder() == locator._top and \
            PC.folder(locator._sub, top=locator._top) is not None

    def load_overload(self, sig, target_context):
        if not self._usable():
            return None
        self._cache_file.last_data = None
        try:
            return super().load_overload(sig, target_context)
        except CacheError as err:
            PC.discard(Path(err.path), err.why, "compiling again")
        except Exception as err:    # noqa: BLE001  numba could not rebuild what it read
            path = self._cache_file.last_data or self._cache_file._index_path
            PC.discard(Path(path), f"{type(err).__name__}: {err}", "compiling again")
        return None

    def save_overload(self, sig, data):
        if not PC.writable() or not self._usable():
            return
        try:
            super().save_overload(sig, data)
        except CacheError as err:       # the index read before the save, or no folder
            if err.path is not None:
                PC.discard(Path(err.path), err.why, "compiling again")
        except OSError as err:
            PC.stop_writing(f"cannot write numba's cache in {self._cache_path}: "
                            f"{err.strerror or err}")


def numba_folder() -> Path | None:
    """The folder of numba's cache files (checked now), or None: no disk cache."""
    from .jit import sources_digest
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        return PC.folder(top=Path(os.path.realpath(user)))
    return PC.folder("numba", sources_digest())


def attach(dispatcher) -> bool:
    """Give ``dispatcher`` (a numba dispatcher not compiled yet) the private cache; False
    (the dispatcher keeps no disk cache) where there is none for its function."""
    try:
        dispatcher._cache = PrivateCache(dispatcher.py_func)
    except (CacheError, OSError):
        return False
    return True
