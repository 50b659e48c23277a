"""What the cache tests share: a private cache root of the test's own (FTO_ROS_CACHE in
tmp_path), a second user simulated by chown (CI runs as root, whom file modes do not stop:
the package reads owner and mode itself), and payloads that leave a marker when run."""
from __future__ import annotations

import errno
import logging
import os
import pickle
from pathlib import Path

import pytest

from fto_ros.core import private_cache as PC

#: the uid of the simulated second user
OTHER_UID = 4242


@pytest.fixture
def cache_root(tmp_path, monkeypatch):
    """FTO_ROS_CACHE = tmp_path/cache (not created yet), read afresh; restored after."""
    root = tmp_path / "cache"
    monkeypatch.setenv("FTO_ROS_CACHE", str(root))
    for name in ("NUMBA_CACHE_DIR", "FTO_ROS_CACHE_MODE", "XDG_CACHE_HOME"):
        monkeypatch.delenv(name, raising=False)
    PC.reset()
    yield root
    PC.reset()


def foreign(path: Path) -> Path:
    """``path`` owned by the second user."""
    os.chown(path, OTHER_UID, OTHER_UID)
    return path


def warnings_of(caplog, name: str = "fto_ros.cache") -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == name and r.levelno == logging.WARNING]


class Payload:
    """Unpickling it creates the folder ``marker`` (os.mkdir): proof that it ran."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def payload_bytes(marker: Path) -> bytes:
    return pickle.dumps(Payload(marker))


def payload_source(marker: Path) -> str:
    """Python that creates ``marker`` when run, and defines a harmless ``fn``."""
    return (f"import os\nos.mkdir({str(marker)!r})\n\n\ndef fn(x, y, u, out):\n"
            "    return 0\n")


def failing_calls(code: int, root) -> dict:
    """``os.open``, ``os.write`` and ``os.mkdir`` of a full disk (ENOSPC: the data does not
    fit) or a read-only one (EROFS: nothing may be created), for paths under ``root`` only
    (test/system/test_cache_commands.py installs them in a command's process)."""
    real_open, real_write, real_mkdir = os.open, os.write, os.mkdir
    ours: set[int] = set()

    def under(path) -> bool:
        return str(os.fspath(path)).startswith(str(root))

    def fake_open(path, flags, mode=0o777, *a, **k):
        if under(path) and flags & os.O_CREAT and code == errno.EROFS:
            raise OSError(code, os.strerror(code), str(path))
        fd = real_open(path, flags, mode, *a, **k)
        if under(path):
            ours.add(fd)
        return fd

    def fake_write(fd, data):
        if fd in ours:
            raise OSError(code, os.strerror(code))
        return real_write(fd, data)

    def fake_mkdir(path, mode=0o777, *a, **k):
        if under(path) and code == errno.EROFS:
            raise OSError(code, os.strerror(code), str(path))
        return real_mkdir(path, mode, *a, **k)
    return {"open": fake_open, "write": fake_write, "mkdir": fake_mkdir}


def fail_writes(monkeypatch, code: int, root) -> None:
    """The cache disk under ``root`` full or read-only for the rest of the test."""
    for name, fake in failing_calls(code, root).items():
        monkeypatch.setattr(os, name, fake)
