"""Writing rosbag2 bags (MCAP storage, metadata version 9) fast: many messages of one topic
go in at once, their records built with numpy, no Python per message.

The file is laid out record for record as rosbags' writer lays it out for the same
messages in the same order (header, schema and channel records in the chunk being
filled, chunks closed past 1 MiB, a message index per channel after each chunk, the
summary section with schemas, channels, chunk indexes, the rosbag2 metadata record,
statistics and summary offsets): test/unit/bag/test_bag_fast_paths.py checks that both files are equal
byte for byte, and metadata.yaml too, given rosbags' YAML emitter (ruamel.yaml).  By
default three things differ: the library named in the MCAP header (fto_ros's),
``ros_distro`` ("jazzy") and the YAML emitter: libyaml's (0.4 ms instead of 15 ms per
dump, twice per bag), which folds long lines and quotes some strings otherwise; the
values are the same.

A block's messages are written one after the other (the file is in the caller's order;
MCAP readers and ``ros2 bag play`` order by log time through the indexes).  With
``background`` a full chunk is compressed and written by a thread of its own while the
caller fills the next one (the same bytes, in the same order).
"""
from __future__ import annotations

import io
import struct
import sys
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .mcap_scan import MSG_HEADER

if sys.version_info >= (3, 14):
    from compression import zstd as _zstd
else:
    try:
        from backports import zstd as _zstd     # what rosbags compresses with
    except ImportError:                         # pragma: no cover
        import zstandard as _zstd

import yaml

#: libyaml's emitter when PyYAML has it (40x faster than a pure-Python one)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)

_MAGIC = b"\x89MCAP0\r\n"
#: rosbags closes a chunk once its records pass this size
CHUNK_LIMIT = 1 << 20
_NO_TIME = 2 ** 63 - 1
_QOS = "[]"                # offered_qos_profiles of a connection without QoS, as dumped
_MSG_HEAD = struct.Struct("<BQHIQQ")       # a Message record's header (MSG_HEADER)


def _u16(v: int) -> bytes:
    return v.to_bytes(2, "little")


def _u32(v: int) -> bytes:
    return v.to_bytes(4, "little")


def _u64(v: int) -> bytes:
    return v.to_bytes(8, "little")


def _str(s: str) -> bytes:
    b = s.encode()
    return _u32(len(b)) + b


def _record(op: int, body: bytes) -> bytes:
    return bytes((op,)) + _u64(len(body)) + body


def dump_yaml(doc) -> str:
    """YAML text of metadata.yaml (block style, keys sorted, as rosbags writes it; libyaml
    folds and quotes some strings otherwise than rosbags' ruamel.yaml: the same values)."""
    return yaml.dump(doc, Dumper=_DUMPER, default_flow_style=False)


def dump_yaml_as_rosbags(doc) -> str:
    """YAML text exactly as rosbags writes it (ruamel.yaml's safe dumper, which rosbags
    installs): ``McapBag(..., dump=dump_yaml_as_rosbags)`` writes rosbags' bytes."""
    from ruamel.yaml import YAML
    y = YAML(typ="safe")
    y.default_flow_style = False
    out = io.StringIO()
    y.dump(doc, out)
    return out.getvalue()


class McapBag:
    """One rosbag2 MCAP bag being written into the existing, empty directory ``path``.

    ``add_connection`` once per topic, then ``write_block`` (or ``write``) in any order,
    then ``close`` (summary and metadata.yaml) or ``abort``.
    """

    def __init__(self, path: Path, *, compress: bool = True, level: int = 3,
                 library: str = "fto_ros",
                 ros_distro: str = "jazzy", custom_data: dict[str, str] | None = None,
                 dump: Callable[[dict], str] = dump_yaml, background: bool = False):
        self.path = Path(path)
        self.dump = dump
        #: with ``background``, full chunks are compressed and written by a thread of their
        #: own (zstd releases the GIL), in order, while the caller goes on
        self._pool = ThreadPoolExecutor(1, "mcap-writer") if background else None
        self._pending: deque = deque()
        self.file = self.path / f"{self.path.name}.mcap"
        self.bio = self.file.open("xb")
        self.bio.write(_MAGIC + _record(0x01, _str("ros2") + _str(library)))
        self.compression = "zstd" if compress else ""
        self.level = level                      # zstd's (and rosbags') default: 3
        self.ros_distro = ros_distro
        self.custom_data = dict(custom_data or {})
        self.schemas: list[tuple[int, str, bytes]] = []     # (id, msgtype, record body)
        self.channels: list[tuple[int, str, str, str, bytes]] = []  # id, topic, type, hash, body
        self.counts: dict[int, int] = {}
        self.t_min, self.t_max = _NO_TIME, 0
        self.chunk_indexes: list[bytes] = []
        self._new_chunk()

    # -- connections ------------------------------------------------------------------
    def add_connection(self, topic: str, msgtype: str, msgdef: str, rihs01: str) -> int:
        """The channel id of a new topic (its schema added with the first of its type)."""
        if msgtype not in {s[1] for s in self.schemas}:
            fmt = "ros2idl" if msgdef.startswith("=" * 80 + "\nIDL: ") else "ros2msg"
            sid = len(self.schemas) + 1
            body = _u16(sid) + _str(msgtype) + _str(fmt) + _str(msgdef)
            self.schemas.append((sid, msgtype, body))
            self._append(_record(0x03, body))
        sid = next(s[0] for s in self.schemas if s[1] == msgtype)
        cid = len(self.channels) + 1
        meta = _str("offered_qos_profiles") + _str(_QOS)
        body = _u16(cid) + _u16(sid) + _str(topic) + _str("cdr") + _u32(len(meta)) + meta
        self.channels.append((cid, topic, msgtype, rihs01, body))
        self.counts[cid] = 0
        self._append(_record(0x04, body))
        return cid

    # -- messages ---------------------------------------------------------------------
    def write(self, cid: int, t_ns: int, data: bytes) -> None:
        """One message (log time = publish time = ``t_ns``)."""
        self._index_one(cid, t_ns, self._size)
        self._append(_MSG_HEAD.pack(0x05, len(data) + 22, cid, 0, t_ns, t_ns) + data)
        self.counts[cid] += 1
        self._t0, self._t1 = min(self._t0, t_ns), max(self._t1, t_ns)
        self.t_min, self.t_max = min(self.t_min, t_ns), max(self.t_max, t_ns)
        if self._size > CHUNK_LIMIT:
            self._close_chunk()

    def write_block(self, cid: int, t_ns, payloads) -> None:
        """Messages of one channel in this order: ``t_ns`` (n,) log times, ``payloads`` an
        (n, L) uint8 matrix (every payload L bytes: no Python per message) or a sequence
        of n bytes objects."""
        t = np.ascontiguousarray(t_ns, dtype=np.uint64).reshape(-1)
        n = t.size
        if not n:
            return
        if isinstance(payloads, np.ndarray):
            lengths = np.full(n, payloads.shape[1], np.int64)
        else:
            lengths = np.fromiter((len(p) for p in payloads), np.int64, n)
        hdr = np.empty(n, MSG_HEADER)
        hdr["op"], hdr["len"], hdr["cid"], hdr["seq"] = 0x05, lengths + 22, cid, 0
        hdr["log"] = hdr["pub"] = t
        hdr = hdr.view(np.uint8).reshape(n, MSG_HEADER.itemsize)
        if isinstance(payloads, np.ndarray):
            records = np.concatenate([hdr, payloads.astype(np.uint8, copy=False)], axis=1)
            parts: Sequence = records
        else:
            parts = [hdr[k].tobytes() + bytes(p) for k, p in enumerate(payloads)]
        sizes = lengths + 31
        ends = np.cumsum(sizes)
        first = 0
        while first < n:
            # rosbags closes the chunk after the first message that takes it past the limit
            room = CHUNK_LIMIT - self._size
            base = ends[first - 1] if first else 0
            over = np.flatnonzero(ends[first:] - base > room)
            last = first + int(over[0]) if over.size else n - 1
            offsets = self._size + np.concatenate(([0], ends[first:last] - base))
            self._index(cid, t[first:last + 1], offsets)
            if isinstance(parts, np.ndarray):
                self._append(parts[first:last + 1])
            else:
                for p in parts[first:last + 1]:
                    self._append(p)
            self.counts[cid] += last + 1 - first
            lo, hi = int(t[first:last + 1].min()), int(t[first:last + 1].max())
            self._t0, self._t1 = min(self._t0, lo), max(self._t1, hi)
            self.t_min, self.t_max = min(self.t_min, lo), max(self.t_max, hi)
            if over.size:
                self._close_chunk()
            first = last + 1

    # -- chunks -----------------------------------------------------------------------
    def _new_chunk(self) -> None:
        self._parts: list = []
        self._size = 0
        self._t0, self._t1 = _NO_TIME, 0
        self._msgs: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}

    def _append(self, part) -> None:
        self._parts.append(part)
        self._size += part.nbytes if isinstance(part, np.ndarray) else len(part)

    def _index(self, cid: int, t: np.ndarray, offsets: np.ndarray) -> None:
        self._msgs.setdefault(cid, []).append([t, offsets])     # arrays: a block

    def _index_one(self, cid: int, t: int, offset: int) -> None:
        pieces = self._msgs.setdefault(cid, [])
        if not pieces or isinstance(pieces[-1][0], np.ndarray):
            pieces.append([[], []])                     # lists: single messages
        pieces[-1][0].append(t)
        pieces[-1][1].append(offset)

    def _close_chunk(self) -> None:
        """Hand the filled chunk to the writer (its thread, with ``background``) and start
        a new one; a write that failed before raises here."""
        job = (self._parts, self._size, self._t0, self._t1, self._msgs)
        self._new_chunk()
        if self._pool is None:
            self._write_chunk(*job)
            return
        self._pending.append(self._pool.submit(self._write_chunk, *job))
        while len(self._pending) > 2 or (self._pending and self._pending[0].done()):
            self._pending.popleft().result()             # bounded memory; errors surface

    def _write_chunk(self, parts: list, size: int, t0: int, t1: int, msgs: dict) -> None:
        """Compress and write one chunk and its message indexes (the file's only writer
        until ``close``)."""
        records = b"".join(parts)
        data = _zstd.compress(records, self.level) if self.compression else records
        head = _u64(t0) + _u64(t1) + _u64(size) + _u32(0)
        tail = _str(self.compression) + _u64(len(data))
        bio = self.bio
        start = bio.tell()
        bio.write(bytes((0x06,)) + _u64(len(head) + len(tail) + len(data)) + head + tail)
        bio.write(data)
        end = bio.tell()
        offsets = b""
        for cid, pieces in msgs.items():
            offsets += _u16(cid) + _u64(bio.tell())
            pairs = np.column_stack([
                np.concatenate([np.asarray(p[0], np.uint64) for p in pieces]),
                np.concatenate([np.asarray(p[1], np.uint64) for p in pieces])]).astype("<u8")
            bio.write(_record(0x07, _u16(cid) + _u32(pairs.nbytes) + pairs.tobytes()))
        self.chunk_indexes.append(
            _u64(t0) + _u64(t1) + _u64(start) + _u64(end - start)
            + _u32(len(offsets)) + offsets + _u64(bio.tell() - end)
            + _str(self.compression) + _u64(len(data)) + _u64(size))

    def _drain(self) -> None:
        """Wait for the chunks being written; the first error they had, raised."""
        while self._pending:
            self._pending.popleft().result()

    # -- finishing --------------------------------------------------------------------
    def metadata(self) -> dict:
        """The ``rosbag2_bagfile_information`` of the bag as written so far."""
        count = sum(self.counts.values())
        duration = max(0, self.t_max - self.t_min)
        start = self.t_min
        return {
            "version": 9, "storage_identifier": "mcap",
            "relative_file_paths": [self.file.name],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": topic, "type": msgtype,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": [],
                                    "type_description_hash": rihs01},
                 "message_count": self.counts[cid]}
                for cid, topic, msgtype, rihs01, _ in self.channels],
            "compression_format": "", "compression_mode": "",
            "files": [{"path": self.file.name,
                       "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": count}],
            "custom_data": self.custom_data or None,
            "ros_distro": self.ros_distro,
        }

    def close(self) -> None:
        """Write the last chunk, the summary section and metadata.yaml."""
        if self._size:
            self._close_chunk()
        self._drain()
        self._shutdown()
        info = self.metadata()
        bio = self.bio
        meta_start = bio.tell()
        entry = _str("serialized_metadata") + _str(self.dump(info).strip())
        bio.write(_record(0x0C, _str("rosbag2") + _u32(len(entry)) + entry))
        meta_end = bio.tell()
        bio.write(_record(0x0F, _u32(0)))
        schema_start = bio.tell()
        for _, _, body in self.schemas:
            bio.write(_record(0x03, body))
        channel_start = bio.tell()
        for *_, body in self.channels:
            bio.write(_record(0x04, body))
        chunk_start = bio.tell()
        for body in self.chunk_indexes:
            bio.write(_record(0x08, body))
        meta_index_start = bio.tell()
        bio.write(_record(0x0D, _u64(meta_start) + _u64(meta_end - meta_start) + _str("rosbag2")))
        stats_start = bio.tell()
        stats = b"".join(_u16(cid) + _u64(n) for cid, n in sorted(self.counts.items()))
        bio.write(_record(0x0B, _u64(sum(self.counts.values())) + _u16(len(self.schemas))
                          + _u32(len(self.channels)) + _u32(0) + _u32(1)
                          + _u32(len(self.chunk_indexes)) + _u64(self.t_min)
                          + _u64(self.t_max) + _u32(len(stats)) + stats))
        offsets_start = bio.tell()
        for op, a, b in ((0x03, schema_start, channel_start), (0x04, channel_start, chunk_start),
                         (0x08, chunk_start, meta_index_start)):
            if a != b:
                bio.write(_record(0x0E, bytes((op,)) + _u64(a) + _u64(b - a)))
        for op, a, b in ((0x0D, meta_index_start, stats_start), (0x0B, stats_start, offsets_start)):
            bio.write(_record(0x0E, bytes((op,)) + _u64(a) + _u64(b - a)))
        bio.write(_record(0x02, _u64(schema_start) + _u64(offsets_start) + _u32(0)) + _MAGIC)
        bio.close()
        meta = self.path / "metadata.yaml"
        tmp = meta.with_suffix(".yaml.tmp")
        tmp.write_text(self.dump({"rosbag2_bagfile_information": info}), "utf8")
        tmp.replace(meta)

    def abort(self) -> None:
        """Stop writing (the caller removes the directory)."""
        self._shutdown(cancel=True)
        self.bio.close()

    def _shutdown(self, cancel: bool = False) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=cancel)
            self._pool = None
            self._pending.clear()


__all__ = ["CHUNK_LIMIT", "McapBag", "dump_yaml", "dump_yaml_as_rosbags"]
