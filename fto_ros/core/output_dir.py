"""Output folders: the one place that decides whether a command may write (or replace) its
``--out``, and that creates it.

Every command that writes (``fto-replay``, ``fto-simulate``, ``fto-report``, ``fto-sweep``)
and the bag writer go through here, so one rule holds everywhere:

- ``--out`` must be a non-empty path that is not the input (a bag, a params file), not
  inside an input and not a folder holding one;
- a path that does not exist is created, with a marker file (:data:`MARKER`) naming the
  kind of output, so that a later run recognises it;
- an existing path is replaced only with ``overwrite`` and only if it is an output of the
  same kind that fto_ros wrote: a real folder (not a symlink) carrying a valid marker (or,
  for outputs written before markers existed, a ``metadata.yaml`` whose ``custom_data``
  has an ``fto_ros.`` key, a ``report.md`` with fto-report's title), holding nothing but
  what that kind of output holds (regular files of the expected names, and sub-folders
  that are themselves such outputs) and no input.
  An empty folder holds nothing and may be replaced too.  Never a file, a device node, a
  FIFO, a socket, a symlink (to anything), or a folder holding anything else.

An output that could not be completed (a full disk mid-write) is given up with
:func:`abandon`: removed, or renamed to ``<out>.incomplete-<pid>`` with its marker saying
so, so that no reader takes it for a finished one.

Refusals raise :class:`OutputError` (a bad argument: exit code 2); an existing output
without ``overwrite`` raises :class:`OutputExists` (what each command did before: the
replay and the simulator exit 1, the sweep 2).  Everything is checked before anything is
removed.  ROS-free and below every layer that writes (``bag/``, ``replay/``, ``sweep/``,
``cli/`` all import ``core``), so no import points up.
"""
from __future__ import annotations

import fnmatch
import json
import os
import shutil
import stat
from pathlib import Path
from typing import Iterable

import yaml

from .errors import BadArgument, OutputError, OutputExists, OutputIncomplete  # noqa: F401

#: the marker file every output folder gets when it is created
MARKER = ".fto_ros_output"

#: kind -> (file-name patterns it may hold, kinds of the marked sub-folders it may hold,
#: unmarked sub-folders it may hold -> the kinds of the outputs in them)
KINDS: dict[str, tuple[tuple[str, ...], tuple[str, ...], dict[str, tuple[str, ...]]]] = {
    # a rosbag2 bag (fto-simulate), plus the replay's metrics and figure (fto-replay)
    "bag": (("metadata.yaml", "*.mcap", "metrics.json", "replay.png"), (), {}),
    # fto-report: report.md and one replay output per (bag, config) pair
    "report": (("report.md",), ("bag",), {}),
    # fto-sweep: the table, the summary, the figures, and with --keep-runs runs/, the
    # replay outputs of the runs
    "sweep": (("results.csv", "summary.txt", "*.png"), (), {"runs": ("bag",)}),
}

#: the first line of every report.md fto-report writes
REPORT_TITLE = "# fto_ros: observer comparison"
_MAX_MARKER_BYTES = 4096
_MAX_METADATA_BYTES = 1 << 20


def _text(path) -> str:
    if isinstance(path, bytes):
        raise OutputError(f"output path must be text, got {path!r}")
    try:
        text = os.fspath(path)
    except TypeError:
        raise OutputError(f"output path must be a path, got {type(path).__name__}") from None
    if not text.strip():
        raise OutputError("the output path is empty (give --out a folder name)")
    if "\0" in text:
        raise OutputError(f"output path {text!r} contains a NUL character")
    return text


def _protected(inputs: Iterable) -> list[str]:
    """The real paths of the inputs; a file in a bag folder protects the whole bag folder."""
    out = []
    for item in inputs:
        real = os.path.realpath(os.fspath(item))
        parent = os.path.dirname(real)
        if os.path.isfile(real) and os.path.isfile(os.path.join(parent, "metadata.yaml")):
            real = parent
        out.append(real)
    return out


def _inside(path: str, folder: str) -> bool:
    return os.path.commonpath([path, folder]) == folder


def _check_inputs(real: str, shown: str, inputs: list[str]) -> None:
    for item in inputs:
        if real == item:
            raise OutputError(f"refusing to write to {shown}: it is an input ({item})")
        if _inside(real, item):
            raise OutputError(f"refusing to write to {shown}: it is inside the input {item}")
        if _inside(item, real):
            raise OutputError(f"refusing to replace {shown}: it holds the input {item}")


def _marker_kind(folder: Path) -> str | None:
    """The kind named by ``folder``'s marker, or None when there is no valid one."""
    try:
        st = os.lstat(folder / MARKER)
    except OSError:
        return None
    if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_MARKER_BYTES:
        return None
    try:
        doc = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("written_by") != "fto_ros":
        return None
    kind = doc.get("kind")
    return kind if kind in KINDS else None


def _small_text(path: Path) -> str | None:
    """The text of a regular file (not a symlink) of at most 1 MiB, else None."""
    try:
        st = os.lstat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_METADATA_BYTES:
            return None
        return path.read_text()
    except (OSError, ValueError):
        return None


def _legacy_kind(folder: Path) -> str | None:
    """The kind of an output fto_ros wrote before markers existed, recognised by what it
    wrote into it: a bag whose metadata.yaml has an ``fto_ros.`` key under custom_data
    (every bag fto-simulate and fto-replay wrote, the committed ones included), a report
    whose report.md starts with fto-report's title; else None."""
    text = _small_text(folder / "metadata.yaml")
    if text is not None:
        try:
            doc = yaml.safe_load(text)
        except yaml.YAMLError:
            return None
        info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
        custom = info.get("custom_data") if isinstance(info, dict) else None
        if isinstance(custom, dict) and any(str(k).startswith("fto_ros.") for k in custom):
            return "bag"
        return None
    text = _small_text(folder / "report.md")
    if text is not None and text.startswith(REPORT_TITLE):
        return "report"
    return None


def _why_not_output(folder: Path, kinds: tuple[str, ...]) -> str | None:
    """None if ``folder`` (a real directory) is an fto_ros output of one of ``kinds``, with
    nothing in it that such an output does not hold; otherwise why not."""
    kind = _marker_kind(folder) or _legacy_kind(folder)
    if kind is None:
        return f"{folder} is not an output fto_ros wrote (no valid {MARKER} marker)"
    if kind not in kinds:
        return f"{folder} is an fto_ros '{kind}' output, not a {' or '.join(kinds)} output"
    patterns, sub_kinds, containers = KINDS[kind]
    return _why_not_held(folder, f"a {kind} output", (MARKER, *patterns), sub_kinds, containers)


def _why_not_held(folder: Path, what_it_is: str, patterns, sub_kinds, containers) -> str | None:
    """None if every entry of ``folder`` is a regular file matching one of ``patterns``, an
    output of one of ``sub_kinds``, or a container folder (name in ``containers``) holding
    only outputs of its kinds; otherwise why not."""
    for entry in os.scandir(folder):
        mode = entry.stat(follow_symlinks=False).st_mode
        if stat.S_ISREG(mode) and any(fnmatch.fnmatchcase(entry.name, p) for p in patterns):
            continue
        if stat.S_ISDIR(mode) and entry.name in containers:
            why = _why_not_held(Path(entry.path), f"the {entry.name} folder of an output", (),
                                containers[entry.name], {})
        elif stat.S_ISDIR(mode) and sub_kinds:
            why = _why_not_output(Path(entry.path), sub_kinds)
        else:
            what = ("a symlink" if stat.S_ISLNK(mode) else "a folder" if stat.S_ISDIR(mode)
                    else "a file" if stat.S_ISREG(mode) else "a special file")
            return f"{folder} holds {entry.name} ({what} {what_it_is} does not hold)"
        if why is not None:
            return why
    return None


def check_output(path, kind: str, *, overwrite: bool = False, inputs: Iterable = ()) -> Path:
    """Raise unless ``path`` may be written as a ``kind`` output; touch nothing.

    Returns ``Path(path)``.  Raises :class:`OutputError` for a refused path and
    :class:`OutputExists` when it exists and ``overwrite`` is false.
    """
    if kind not in KINDS:
        raise BadArgument(f"unknown output kind {kind!r}")
    text = _text(path)
    out = Path(text)
    real = os.path.realpath(text)
    _check_inputs(real, text, _protected(inputs))
    try:
        st = os.lstat(out)
    except FileNotFoundError:
        return out
    except OSError as err:
        raise OutputError(f"cannot use {text} as the output: {err.strerror}") from None
    if not overwrite:
        raise OutputExists(f"{text}: output exists already (remove it or pass --overwrite)")
    if stat.S_ISLNK(st.st_mode):
        raise OutputError(f"refusing to replace {text}: it is a symlink")
    if not stat.S_ISDIR(st.st_mode):
        what = "a file" if stat.S_ISREG(st.st_mode) else "a device or special file"
        raise OutputError(f"refusing to replace {text}: it is {what}, not an output folder")
    try:
        why = None if not any(os.scandir(out)) else _why_not_output(out, (kind,))
    except OSError as err:
        raise OutputError(f"refusing to replace {text}: cannot look inside: {err}") from None
    if why is not None:
        raise OutputError(f"refusing to replace {text}: {why}")
    return out


def clear_output(path, kind: str, *, overwrite: bool = False, inputs: Iterable = ()) -> Path:
    """:func:`check_output`, then remove the old output: ``path`` no longer exists after."""
    out = check_output(path, kind, overwrite=overwrite, inputs=inputs)
    if os.path.lexists(out):
        try:
            shutil.rmtree(out)
        except OSError as err:
            raise OutputError(f"cannot remove the old output {out}: {err.strerror}") from None
    return out


def mark_output(folder, kind: str) -> None:
    """Write the marker into ``folder`` (just created by the caller)."""
    if kind not in KINDS:
        raise BadArgument(f"unknown output kind {kind!r}")
    (Path(folder) / MARKER).write_text(json.dumps({"written_by": "fto_ros", "kind": kind}) + "\n")


def create_output(path, kind: str, *, overwrite: bool = False, inputs: Iterable = ()) -> Path:
    """:func:`clear_output`, then create ``path`` (and missing parents) with its marker."""
    out = clear_output(path, kind, overwrite=overwrite, inputs=inputs)
    try:
        out.mkdir(parents=True)
        mark_output(out, kind)
    except OSError as err:
        raise OutputError(f"cannot create the output {out}: {err.strerror or err}") from None
    return out


def abandon(path, kind: str, why: str, *, keep: bool = False) -> str:
    """Give up the output ``path`` that could not be completed (``why``, e.g. a full disk):
    remove it, or with ``keep`` (the results of many runs, worth salvaging) or when it
    cannot be removed, rename it to ``<path>.incomplete-<pid>`` and rewrite its marker to
    say so.  Returns what became of it, a phrase for the command's one error line."""
    out = Path(path)
    if not os.path.lexists(out):
        return f"nothing was left at {out}"
    if not keep:
        try:
            shutil.rmtree(out)
            return f"the incomplete output {out} was removed"
        except OSError:
            pass
    target = out.with_name(f"{out.name}.incomplete-{os.getpid()}")
    try:
        os.rename(out, target)
    except OSError as err:
        return f"the incomplete output {out} could be neither removed nor renamed " \
               f"({err.strerror or err})"
    try:
        (target / MARKER).write_text(json.dumps({"written_by": "fto_ros", "kind": kind,
                                                 "incomplete": why}) + "\n")
    except OSError:
        pass                        # the name says it too
    return f"the incomplete output was renamed {target}"


def check_output_file(path, marker: str, *, overwrite: bool = False,
                      inputs: Iterable = ()) -> Path:
    """Raise unless ``path`` may be written as a single-file output (a params file a command
    writes) whose first line is ``marker``; touch nothing.

    Refused (:class:`OutputError`): an empty path, an input or a path inside one (a bag
    folder counts whole), a parent folder that does not exist, an existing path that is not
    a regular file (a symlink, a folder, a device) or whose first line is not ``marker``
    (the command did not write it). An existing file without ``overwrite``:
    :class:`OutputExists`."""
    text = _text(path)
    real = os.path.realpath(text)
    for item in _protected(inputs):
        if real == item or _inside(real, item):
            raise OutputError(f"refusing to write {text}: it is the input {item} or inside it")
    parent = os.path.dirname(os.path.abspath(text))
    if not os.path.isdir(parent):
        raise OutputError(f"{text}: the folder {parent} does not exist")
    try:
        st = os.lstat(text)
    except FileNotFoundError:
        return Path(text)
    except OSError as err:
        raise OutputError(f"cannot use {text} as the output: {err.strerror}") from None
    if not overwrite:
        raise OutputExists(f"{text}: output exists already (remove it or pass --overwrite)")
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(f"refusing to replace {text}: not a regular file (a symlink, a "
                          f"folder or a special file)")
    try:
        with open(text, encoding="utf-8", errors="replace") as fh:
            first = fh.readline(len(marker) + 2).rstrip("\n")
    except OSError as err:
        raise OutputError(f"refusing to replace {text}: cannot read it ({err.strerror})") \
            from None
    if first != marker:
        raise OutputError(f"refusing to replace {text}: the command did not write it (its "
                          f"first line is not {marker!r})")
    return Path(text)
