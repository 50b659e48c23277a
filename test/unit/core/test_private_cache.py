"""The private cache folder (core/private_cache.py): made 0700, owner and mode read and
checked on every use for the folder and every folder up to the root, refused with one WARN
line; files read only when they are this user's private regular files, written through an
exclusive temp file; a full or read-only disk stops the writes, never the run (issue 28:
F1, F2, F8)."""
from __future__ import annotations

import errno
import os
import stat

import pytest

from cache_helpers import (OTHER_UID, cache_root, fail_writes, foreign,  # noqa: F401
                           warnings_of)
from fto_ros.core import private_cache as PC
from fto_ros.core.errors import CacheError


def mode_of(path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


def test_a_new_cache_folder_is_made_private(cache_root):
    models = PC.folder("models")
    assert models == cache_root / "models"
    assert mode_of(cache_root) == 0o700 and mode_of(models) == 0o700
    assert PC.why_not_private(models, cache_root) is None


def test_a_foreign_root_is_refused_once_and_nothing_is_made_in_it(cache_root, caplog):
    cache_root.mkdir(mode=0o700)
    foreign(cache_root)
    assert PC.folder("models") is None
    assert PC.folder("models") is None                 # checked again, warned once
    assert not (cache_root / "models").exists()
    (line,) = warnings_of(caplog)
    assert str(cache_root) in line and f"uid {OTHER_UID}" in line and "uncached" in line


@pytest.mark.parametrize("where", ["root", "sub"])
@pytest.mark.parametrize("mode", [0o777, 0o775, 0o722, 0o1777])
def test_a_folder_others_may_write_is_refused(cache_root, caplog, where, mode):
    assert PC.folder("models") is not None
    target = cache_root if where == "root" else cache_root / "models"
    os.chmod(target, mode)
    PC.reset()
    assert PC.folder("models") is None
    (line,) = warnings_of(caplog)
    assert f"{target} is writable by" in line


def test_a_foreign_sub_folder_is_refused(cache_root, caplog):
    assert PC.folder("models") is not None
    foreign(cache_root / "models")
    assert PC.folder("models") is None
    assert f"{cache_root / 'models'} is owned by uid {OTHER_UID}" in warnings_of(caplog)[0]


def test_a_symlink_in_the_chain_is_refused(cache_root, tmp_path, caplog):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir(mode=0o700)
    cache_root.mkdir(mode=0o700)
    (cache_root / "models").symlink_to(elsewhere)
    assert PC.folder("models") is None
    assert "is a symlink" in warnings_of(caplog)[0]


def test_the_check_runs_on_every_use(cache_root):
    assert PC.folder("models") is not None
    os.chmod(cache_root / "models", 0o777)            # made shared while the process runs
    assert PC.folder("models") is None


def test_a_symlink_planted_at_the_temp_name_is_not_followed(cache_root, tmp_path):
    models = PC.folder("models")
    victim = tmp_path / "victim.txt"
    victim.write_text("the victim's own text\n")
    target = models / "fto_model_x.py"
    PC.temp_name(target).symlink_to(victim)
    assert PC.write_file(target, b"generated\n")
    assert victim.read_text() == "the victim's own text\n"
    assert target.read_bytes() == b"generated\n" and mode_of(target) == 0o600
    assert not os.path.lexists(PC.temp_name(target))


@pytest.mark.parametrize("spoil", ["foreign", "group-writable", "symlink", "folder"])
def test_only_own_private_regular_files_are_read(cache_root, tmp_path, spoil):
    models = PC.folder("models")
    path = models / "f.py"
    assert PC.write_file(path, b"mine")
    assert PC.read_file(path) == b"mine"
    if spoil == "foreign":
        foreign(path)
    elif spoil == "group-writable":
        os.chmod(path, 0o620)
    elif spoil == "symlink":
        path.unlink()
        (tmp_path / "real").write_bytes(b"elsewhere")
        path.symlink_to(tmp_path / "real")
    else:
        path.unlink()
        path.mkdir()
    with pytest.raises(CacheError):
        PC.read_file(path)
    assert PC.read_file(models / "absent.py") is None


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_a_full_or_read_only_disk_stops_the_writes_with_one_warning(cache_root, monkeypatch,
                                                                    caplog, code):
    models = PC.folder("models")
    fail_writes(monkeypatch, code, cache_root)
    assert not PC.write_file(models / "a.py", b"x")
    assert not PC.write_file(models / "b.py", b"y")
    assert not PC.writable()
    (line,) = warnings_of(caplog)
    assert os.strerror(code) in line and "running uncached" in line
    assert sorted(p.name for p in models.iterdir()) == []        # no temp file left


def test_a_read_only_disk_before_the_folder_exists(cache_root, monkeypatch, caplog):
    fail_writes(monkeypatch, errno.EROFS, cache_root)
    assert PC.folder("models") is None
    assert not cache_root.exists()
    assert any(os.strerror(errno.EROFS) in line for line in warnings_of(caplog))


def test_read_only_mode_makes_and_writes_nothing(cache_root, monkeypatch, caplog):
    monkeypatch.setenv("FTO_ROS_CACHE_MODE", "readonly")
    PC.reset()
    assert PC.folder("models") is None and not cache_root.exists()
    cache_root.mkdir(mode=0o700)
    (cache_root / "models").mkdir(mode=0o700)
    models = PC.folder("models")
    assert models is not None
    assert not PC.write_file(models / "a.py", b"x") and not (models / "a.py").exists()
    assert all("fto-warm-cache" in line for line in warnings_of(caplog))


def test_mode_off_uses_no_folder(cache_root, monkeypatch):
    monkeypatch.setenv("FTO_ROS_CACHE_MODE", "off")
    PC.reset()
    assert PC.folder("models") is None and not cache_root.exists()
