"""A fast reader of MCAP rosbag2 files: the records scanned with ``struct``, chunks
decompressed, raw CDR payloads returned per topic (no deserialisation).

``read_raw(bag, topics)`` gives ``topic -> (log times ns, payloads)`` or raises
``NotFast`` when it cannot read this bag (SQLite3 storage, file-level compression, an
unknown chunk compression, a damaged record...): the caller then reads with
``BagReader`` (rosbags), and checks the counts either way (a reader never drops
messages silently).  Whole files are read into memory, up to FAST_PATH_MAX_BYTES.
"""
from __future__ import annotations

import functools
import struct
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

_MAGIC = b"\x89MCAP0\r\n"
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQ")          # channel id, sequence, log time (publish time follows)
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
#: the fast path reads whole files into memory; larger bags go through BagReader
FAST_PATH_MAX_BYTES = 1 << 30


class NotFast(Exception):
    """The fast MCAP path cannot read this bag; use BagReader."""


@functools.lru_cache(maxsize=None)
def _decompressor(name: str) -> Callable[[bytes, int], bytes]:
    if name == "":
        return lambda data, size: data
    if name == "zstd":
        try:
            from compression import zstd  # Python >= 3.14
            return lambda data, size: zstd.decompress(data)
        except ImportError:
            pass
        try:
            from backports import zstd  # what rosbags uses
            return lambda data, size: zstd.decompress(data)
        except ImportError:
            pass
        try:
            import zstandard
            dctx = zstandard.ZstdDecompressor()
            return lambda data, size: dctx.decompress(data, max_output_size=size)
        except ImportError:
            raise NotFast("no zstd module") from None
    if name == "lz4":
        try:
            from lz4.frame import decompress
        except ImportError:
            raise NotFast("no lz4 module") from None
        return lambda data, size: decompress(data)
    raise NotFast(f"unknown MCAP compression {name!r}")


def _mcap_files(bag: Path) -> list[Path]:
    """The MCAP files of a bag, or NotFast (SQLite3, file-compressed bags ...)."""
    if bag.is_file():
        if bag.suffix != ".mcap":
            raise NotFast("not an .mcap file")
        return [bag]
    try:
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except Exception as err:
        raise NotFast(f"metadata.yaml: {err}") from None
    if meta.get("storage_identifier") != "mcap" or meta.get("compression_mode") not in ("", None):
        raise NotFast("not an uncompressed-file MCAP bag")
    files = [bag / p for p in meta.get("relative_file_paths") or []]
    if not files or any(p.suffix != ".mcap" or not p.is_file() for p in files):
        raise NotFast("unexpected file list")
    if sum(p.stat().st_size for p in files) > FAST_PATH_MAX_BYTES:
        raise NotFast("bag too large to read into memory")
    return files


def _string(buf, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(buf, pos)
    return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def _scan_records(buf, pos: int, end: int, channels: dict[int, str], wanted: dict[str, tuple],
                  top: bool) -> None:
    """Collect the wanted messages of the records in ``buf[pos:end]``.

    ``wanted`` maps a topic to ``(times, payloads)`` lists to append to;
    ``channels`` maps MCAP channel ids to topics (filled from Channel records).
    """
    unpack_rec, unpack_msg = _REC.unpack_from, _MSG.unpack_from
    by_channel = {cid: wanted.get(topic) for cid, topic in channels.items()}
    while pos < end:
        op, length = unpack_rec(buf, pos)
        body = pos + 9
        pos = body + length
        if pos > end:
            raise NotFast("truncated record")
        if op == 0x05:  # Message
            cid, _seq, log_time = unpack_msg(buf, body)
            try:
                sink = by_channel[cid]
            except KeyError:
                raise NotFast(f"message on undeclared channel {cid}") from None
            if sink is not None:
                sink[0].append(log_time)
                sink[1].append(buf[body + 22:pos])
        elif op == 0x04:  # Channel
            (cid,) = _U16.unpack_from(buf, body)
            topic, _ = _string(buf, body + 4)
            channels[cid] = topic
            by_channel[cid] = wanted.get(topic)
        elif op == 0x06 and top:  # Chunk
            p = body + 16
            (size,) = _U64.unpack_from(buf, p)
            compression, p = _string(buf, p + 12)
            (n,) = _U64.unpack_from(buf, p)
            data = buf[p + 8:p + 8 + n]
            records = _decompressor(compression)(data, size)
            if len(records) != size:
                raise NotFast("chunk size mismatch")
            _scan_records(records, 0, len(records), channels, wanted, top=False)
            by_channel = {cid: wanted.get(topic) for cid, topic in channels.items()}
        elif op in (0x0F, 0x02) and top:  # DataEnd, Footer: the summary section follows
            return


def read_raw(bag: Path, topics: list[str]) -> dict[str, tuple[np.ndarray, list[bytes]]]:
    """``topic -> (log times ns (int64, sorted, stable), raw CDR payloads)`` via the fast path."""
    wanted: dict[str, tuple[list, list]] = {t: ([], []) for t in topics}
    for path in _mcap_files(bag):
        data = path.read_bytes()
        if not data.startswith(_MAGIC):
            raise NotFast("bad magic")
        try:
            _scan_records(data, len(_MAGIC), len(data) - len(_MAGIC), {}, wanted, top=True)
        except NotFast:
            raise
        except Exception as err:  # struct.error, decompression errors ...
            raise NotFast(f"{type(err).__name__}: {err}") from None
    out = {}
    for topic, (times, payloads) in wanted.items():
        try:
            t = np.asarray(times, dtype=np.int64)
        except OverflowError:       # a log time no ROS time can be: a damaged record
            raise NotFast(f"topic {topic}: a log time beyond 2^63 ns") from None
        if t.size > 1 and np.any(np.diff(t) < 0):
            order = np.argsort(t, kind="stable")
            t = t[order]
            payloads = [payloads[i] for i in order.tolist()]
        out[topic] = (t, payloads)
    return out
