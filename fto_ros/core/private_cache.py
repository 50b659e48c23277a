"""The private cache folder: the one place where generated model modules (core/model_code.py)
and numba's compiled code (core/compile_cache.py) are kept, and the rules that make what is
read from it trustworthy (docs/security.md).

The root is the user's choice: ``$FTO_ROS_CACHE``, else ``$XDG_CACHE_HOME/fto_ros``, else
``~/.cache/fto_ros`` (resolved once: a symlink the user made is followed there, and nowhere
below).  Below it, :func:`folder` gives a sub-folder, creating what is missing with mode
0700, and checks it **on every call**, together with every folder between it and the root
(both included): a real folder (not a symlink), owned by this process's uid, writable by
nobody else (no group or other write bit).  The check reads owner and mode itself, so it
holds for root as well, whom file modes do not stop.  A folder that fails is refused with
one WARN line and bypassed: the process runs uncached (generated modules live in memory
only, numba compiles without its disk cache).  There is no fallback folder in the shared
temporary directory.

Files are read with :func:`read_file` (no symlink followed; a regular file of this uid that
nobody else may write, else :class:`~.errors.CacheError`) and written with :func:`write_file` (a temp
file created exclusively, ``O_CREAT | O_EXCL | O_NOFOLLOW``, mode 0600, then renamed into
place).  A write that fails (a full or read-only disk) stops every later write of the
process, with one WARN line: the run goes on uncached, never fails for it.

``$FTO_ROS_CACHE_MODE``: ``readwrite`` (the default), ``readonly`` (read what is there,
create and write nothing: a cache built once, e.g. by ``fto-warm-cache``, and only read
afterwards) or ``off`` (no cache).  ROS-free.
"""
from __future__ import annotations

import contextlib
import logging
import os
import stat
from pathlib import Path

from .errors import CacheError

LOG = logging.getLogger("fto_ros.cache")

ENV_ROOT, ENV_MODE = "FTO_ROS_CACHE", "FTO_ROS_CACHE_MODE"
READWRITE, READONLY, OFF = "readwrite", "readonly", "off"
MODES = (READWRITE, READONLY, OFF)
#: largest cache file read (bytes): numba's data files are tens of kB
MAX_FILE_BYTES = 64 << 20


class _State:
    def __init__(self):
        text = os.environ.get(ENV_MODE, READWRITE).strip().lower() or READWRITE
        self.mode = text if text in MODES else READWRITE
        self.bad_mode = None if text in MODES else text
        self.root: Path | None = None
        self.why_no_root: str | None = None
        self.writes = self.mode == READWRITE      # off after a failed write
        self.warned: set[str] = set()
        if self.mode == OFF:
            return
        try:
            chosen = os.environ.get(ENV_ROOT) or os.path.join(
                os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache"),
                "fto_ros")
            self.root = Path(os.path.realpath(chosen))
        except (RuntimeError, KeyError, OSError) as err:    # no home folder
            self.why_no_root = f"no cache folder ({err}); set {ENV_ROOT}"


_state: _State | None = None


def _st() -> _State:
    global _state
    if _state is None:
        _state = _State()
        if _state.bad_mode is not None:
            warn_once(f"fto_ros: {ENV_MODE}={_state.bad_mode!r} is not one of "
                      f"{', '.join(MODES)}: using {READWRITE}")
    return _state


def reset() -> None:
    """Forget everything decided (the environment is read again at the next use): tests."""
    global _state
    _state = None


def warn_once(text: str) -> None:
    """One WARN line per distinct text per process."""
    st = _st()
    if text not in st.warned:
        st.warned.add(text)
        LOG.warning(text)


def mode() -> str:
    return _st().mode


def root() -> Path | None:
    """The cache root the user chose (resolved), or None (mode off, no home folder)."""
    return _st().root


def writable() -> bool:
    """Whether this process may still write into the cache."""
    return _st().writes


def why_not_private(path: Path, top: Path) -> str | None:
    """None when ``path`` and every folder from it up to ``top`` (both included) is a real
    folder owned by this uid that no one else may write; otherwise why not (one phrase)."""
    uid = os.getuid()
    p = Path(path)
    while True:
        try:
            st = os.lstat(p)
        except OSError as err:
            return f"{p}: {err.strerror or err}"
        if stat.S_ISLNK(st.st_mode):
            return f"{p} is a symlink"
        if not stat.S_ISDIR(st.st_mode):
            return f"{p} is not a folder"
        if st.st_uid != uid:
            return f"{p} is owned by uid {st.st_uid}, not by this user (uid {uid})"
        if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            return f"{p} is writable by {'group' if st.st_mode & stat.S_IWGRP else 'others'} " \
                   f"(mode {stat.S_IMODE(st.st_mode):04o})"
        if p == top or p.parent == p:
            return None
        p = p.parent


def _refuse(path: Path, why: str) -> None:
    warn_once(f"fto_ros: cache folder {path} refused ({why}): running uncached")


def _mkdir(path: Path) -> None:
    with contextlib.suppress(FileExistsError):
        os.mkdir(path, 0o700)


def folder(*parts: str, top: Path | None = None) -> Path | None:
    """``<root>/<parts...>`` (or ``top/<parts...>``), created 0700 where missing (mode
    readwrite only) and checked now (see the module doc); None, with one WARN line, when it
    is refused or cannot be made: the caller runs uncached."""
    st = _st()
    base = top if top is not None else st.root
    if st.mode == OFF:
        return None
    if base is None:
        if st.why_no_root:
            warn_once(f"fto_ros: {st.why_no_root}: running uncached")
        return None
    path = base.joinpath(*parts)
    made = base
    try:
        if st.writes and not os.path.lexists(base):
            os.makedirs(base.parent, mode=0o700, exist_ok=True)
            _mkdir(base)
        why = why_not_private(base, base) if os.path.lexists(base) else None
        if why is not None:                 # nothing is made inside a refused root
            _refuse(base, why)
            return None
        if st.writes:
            for part in parts:
                made = made / part
                _mkdir(made)
    except OSError as err:
        stop_writing(f"cannot create the cache folder {made}: {err.strerror or err}")
    if not os.path.lexists(path):
        if st.mode == READONLY:
            warn_once(f"fto_ros: the read-only cache has no folder {path}: compiling in memory "
                      "(build it with fto-warm-cache)")
        return None
    why = why_not_private(path, base)
    if why is not None:
        _refuse(path, why)
        return None
    return path


def stop_writing(why: str) -> None:
    """No more cache writes in this process (a full or read-only disk): one WARN line."""
    st = _st()
    if st.writes:
        st.writes = False
        warn_once(f"fto_ros: {why}: running uncached from here on")


def read_file(path: Path) -> bytes | None:
    """The bytes of the cache file ``path``; None when there is none.  :class:`~.errors.CacheError`
    for anything but a regular file of this uid that nobody else may write (a symlink is
    never followed), or one that cannot be read."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        return None
    except OSError as err:
        raise CacheError(f"cannot open it: {err.strerror or err}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise CacheError("not a regular file")
        if st.st_uid != os.getuid():
            raise CacheError(f"owned by uid {st.st_uid}")
        if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
            raise CacheError(f"writable by others (mode {stat.S_IMODE(st.st_mode):04o})")
        if st.st_size > MAX_FILE_BYTES:
            raise CacheError(f"larger than {MAX_FILE_BYTES >> 20} MB")
        chunks = []
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                return b"".join(chunks)
            chunks.append(chunk)
    except CacheError:
        raise
    except OSError as err:
        raise CacheError(f"cannot read it: {err.strerror or err}") from None
    finally:
        os.close(fd)


def temp_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


class _Writer:
    """The write end of a cache temp file: every byte through ``os.write``."""

    def __init__(self, fd: int):
        self.fd = fd

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        while view:
            view = view[os.write(self.fd, view):]
        return len(data)


@contextlib.contextmanager
def open_for_write(path: Path):
    """A binary writer whose contents replace ``path`` when the block ends without an
    error: written to a temp file created exclusively (no symlink followed, mode 0600) and
    renamed into place.  An entry already at the temp name (a crashed run's, or planted) is
    unlinked, never followed, and the exclusive create tried once more.  On an error the
    temp file is removed and the error raised."""
    tmp = temp_name(path)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(tmp, flags, 0o600)
    except FileExistsError:
        os.unlink(tmp)
        fd = os.open(tmp, flags, 0o600)
    try:
        try:
            yield _Writer(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_file(path: Path, data: bytes) -> bool:
    """Write ``data`` to the cache file ``path`` (:func:`open_for_write`); False, after
    :func:`stop_writing`, when the cache may not be written or the write fails."""
    if not writable():
        return False
    try:
        with open_for_write(path) as f:
            f.write(data)
        return True
    except OSError as err:
        stop_writing(f"cannot write the cache file {path}: {err.strerror or err}")
        return False


def discard(path: Path, why: str, what: str = "rebuilt") -> None:
    """Remove a damaged or foreign cache file (when the cache may be written), with one
    WARN line naming it."""
    removed = False
    if writable():
        with contextlib.suppress(OSError):
            os.unlink(path)
            removed = True
    warn_once(f"fto_ros: {'discarded' if removed else 'ignored'} the cache file {path} "
              f"({why}): {what}{'' if removed else ' in memory'}")
