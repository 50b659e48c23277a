"""A fast reader of MCAP rosbag2 files: raw CDR payloads per topic, no deserialisation.

``read_raw(bag, topics)`` gives ``topic -> (log times ns, payloads)`` or raises ``NotFast``
when it cannot read this bag (SQLite3 storage, file-level compression, an unknown chunk
compression, a damaged record...): the caller then reads with ``BagReader`` (rosbags), and
checks the counts either way (a reader never drops messages silently).  Whole files are
read into memory, up to FAST_PATH_MAX_BYTES.

Two ways through a file, the first that works:

- **indexed** (what every finished rosbag2/rosbags/mcap file has): the summary section's
  Channel, Statistics and ChunkIndex records, and each chunk's MessageIndex records, give
  every message's offset in its decompressed chunk; the 31-byte message headers are then
  gathered and checked (opcode, channel, log time, length, each once) and the payloads
  cut out with numpy, a whole topic at once, no Python per message.  Payloads that share
  one length (one publisher, a fixed layout) come as one ``(N, L)`` uint8 matrix.
- **scanned**: every record of every chunk walked with ``struct`` (files without a
  summary or indexes).
"""
from __future__ import annotations

import functools
import struct
import zlib
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
import yaml
from numpy.lib.stride_tricks import as_strided

from ..core.errors import NotFast

_MAGIC = b"\x89MCAP0\r\n"
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQ")          # channel id, sequence, log time (publish time follows)
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_FOOTER = struct.Struct("<BQQQI")     # opcode, length (20), summary start, offsets start, crc
_CHUNK_INDEX = struct.Struct("<QQQQI")  # start/end time, chunk offset, chunk length, map bytes
#: a Message record's header: opcode, record length, channel, sequence, log and publish time
MSG_HEADER = np.dtype([("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"),
                       ("log", "<u8"), ("pub", "<u8")])
_HDR = MSG_HEADER.itemsize                  # 31
_HDR_RANGE = np.arange(_HDR)
#: the fast path reads whole files into memory; larger bags go through BagReader
FAST_PATH_MAX_BYTES = 1 << 30


class Payloads(Sequence):
    """The raw CDR payloads of one topic, in log-time order: ``matrix`` (N, L) uint8 when
    they all have one length L (then no per-message objects exist), else a list of bytes.
    Indexing gives one payload's bytes either way."""

    def __init__(self, matrix: np.ndarray | None = None, items: list | None = None):
        self.matrix = matrix
        self.items = items if matrix is None else None

    def __len__(self) -> int:
        return len(self.matrix) if self.matrix is not None else len(self.items)

    def __getitem__(self, k):
        if self.matrix is not None:
            return self.matrix[k].tobytes()
        return bytes(self.items[k])

    def __iter__(self) -> Iterator[bytes]:
        return (self[k] for k in range(len(self)))

    @classmethod
    def join(cls, parts: list) -> "Payloads":
        """One Payloads of consecutive parts (matrices and lists of bytes)."""
        mats = [p for p in parts if isinstance(p, np.ndarray)]
        if len(mats) == len(parts) and len({m.shape[1] for m in mats}) <= 1:
            return cls(matrix=np.concatenate(mats) if mats else np.zeros((0, 0), np.uint8))
        items = []
        for p in parts:
            items.extend([row.tobytes() for row in p] if isinstance(p, np.ndarray) else p)
        return cls(items=items)

    def take(self, order: np.ndarray) -> "Payloads":
        if self.matrix is not None:
            return Payloads(matrix=self.matrix[order])
        return Payloads(items=[self.items[i] for i in order.tolist()])


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


#: libyaml's loader when PyYAML has it (10x faster on a bag's metadata.yaml)
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def metadata(bag: Path) -> dict:
    """The ``rosbag2_bagfile_information`` mapping of a bag directory's metadata.yaml."""
    return yaml.load((bag / "metadata.yaml").read_text(), Loader=_YAML_LOADER)[
        "rosbag2_bagfile_information"]


def fast_info(bag: Path) -> tuple:
    """(the :class:`~fto_ros.bag.reader.BagInfo` of a bag directory from its metadata.yaml
    alone: what ``BagReader(bag).info()`` gives, without opening the storage; its MCAP
    files), or NotFast for anything the fast path does not read (the caller then opens a
    BagReader, which reports what is wrong)."""
    from .reader import BagInfo, TopicInfo
    try:
        meta = metadata(bag)
        topics: dict[str, TopicInfo] = {}
        entries = sorted(meta["topics_with_message_count"],
                         key=lambda e: e["topic_metadata"]["name"])
        for e in entries:
            tm = e["topic_metadata"]
            if tm["serialization_format"] != "cdr":
                raise NotFast("not CDR")
            prev = topics.get(tm["name"])
            topics[str(tm["name"])] = TopicInfo(str(tm["type"]), int(e["message_count"])
                                                + (prev.count if prev else 0))
        count = int(meta["message_count"])
        start = int(meta["starting_time"]["nanoseconds_since_epoch"]) if count else 0
        duration = int(meta["duration"]["nanoseconds"]) if count else 0
        custom = dict(meta.get("custom_data") or {})
    except NotFast:
        raise
    except Exception as err:            # missing keys, wrong types: BagReader says which
        raise NotFast(f"metadata.yaml: {type(err).__name__}: {err}") from None
    return BagInfo(path=str(bag), topics=topics, message_count=count, start_ns=start,
                   end_ns=start + duration, duration_ns=duration, storage="mcap",
                   custom_data=custom), _mcap_files(bag, meta)


def _mcap_files(bag: Path, meta: dict | None = None) -> list[Path]:
    """The MCAP files of a bag (``meta``: its metadata, when read already), or NotFast
    (SQLite3, file-compressed bags ...)."""
    if bag.is_file():
        if bag.suffix != ".mcap":
            raise NotFast("not an .mcap file")
        return [bag]
    try:
        meta = metadata(bag) if meta is None else meta
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


def _chunk_records(buf, body: int) -> bytes:
    """The decompressed records of the Chunk record whose body starts at ``body``
    (checked against the uncompressed size and, when the writer set one, its CRC)."""
    p = body + 16
    (size,) = _U64.unpack_from(buf, p)
    (crc,) = _U32.unpack_from(buf, p + 8)
    compression, p = _string(buf, p + 12)
    (n,) = _U64.unpack_from(buf, p)
    records = _decompressor(compression)(buf[p + 8:p + 8 + n], size)
    if len(records) != size:
        raise NotFast("chunk size mismatch")
    if crc and zlib.crc32(records) != crc:
        raise NotFast("chunk CRC mismatch")
    return records


# ------------------------------------------------------------------ indexed (vectorised)
def _summary(data: bytes) -> tuple[dict[int, str], dict[int, int] | None, list[tuple]]:
    """(channel id -> topic, channel id -> message count or None, chunk indexes) from the
    summary section, or NotFast when the file has none."""
    fpos = len(data) - len(_MAGIC) - _FOOTER.size
    if fpos < len(_MAGIC) or data[-len(_MAGIC):] != _MAGIC:
        raise NotFast("no footer")
    op, length, start, _offsets, _crc = _FOOTER.unpack_from(data, fpos)
    if op != 0x02 or length != 20 or not len(_MAGIC) <= start < fpos:
        raise NotFast("no summary section")
    channels: dict[int, str] = {}
    counts: dict[int, int] | None = None
    chunks = []
    pos = start
    while pos < fpos:
        op, length = _REC.unpack_from(data, pos)
        body, pos = pos + 9, pos + 9 + length
        if op == 0x04:                                   # Channel
            (cid,) = _U16.unpack_from(data, body)
            channels[cid], _ = _string(data, body + 4)
        elif op == 0x0B:                                 # Statistics
            (n,) = _U32.unpack_from(data, body + 42)
            pairs = struct.unpack_from("<" + "HQ" * (n // 10), data, body + 46)
            counts = dict(zip(pairs[0::2], pairs[1::2]))
        elif op == 0x08:                                 # ChunkIndex
            _t0, _t1, offset, _length, n = _CHUNK_INDEX.unpack_from(data, body)
            pairs = struct.unpack_from("<" + "HQ" * (n // 10), data, body + 36)
            chunks.append((offset, dict(zip(pairs[0::2], pairs[1::2]))))
    if pos != fpos:
        raise NotFast("summary section overruns the footer")
    return channels, counts, chunks


def _rows(chunk: np.ndarray, start: np.ndarray, width: int) -> np.ndarray:
    """``chunk[s:s + width]`` for every s of ``start`` (increasing, in bounds) as one
    (n, width) array: strided copies of the runs of evenly spaced starts (one record per
    sample on every topic: the usual layout, broken where a writer put other records), a
    gather when there are many runs."""
    n = start.size
    d = np.diff(start)
    cut = np.flatnonzero(d[1:] != d[:-1]) + 1 if n > 2 else np.zeros(0, np.int64)
    if n < 2 or cut.size > 16:
        return chunk[start[:, None] + np.arange(width)]
    bounds = [0, *cut.tolist(), n]
    return np.concatenate([
        as_strided(chunk[int(start[a]):], shape=(c - a, width),
                   strides=(int(d[a]) if c - a > 1 else 1, 1))
        for a, c in zip(bounds[:-1], bounds[1:])])


def _indexed_messages(records: bytes, data: bytes, index_offsets: dict[int, int],
                      wanted: set[int]) -> dict[int, tuple[np.ndarray, object]]:
    """channel id -> (log times, payloads: (n, L) matrix or list of bytes) of one chunk,
    in file order, from its MessageIndex records; every header checked."""
    chunk = np.frombuffer(records, np.uint8)
    size = chunk.size
    out = {}
    for cid, at in index_offsets.items():
        if cid not in wanted:
            continue
        op, length = _REC.unpack_from(data, at)
        (icid,) = _U16.unpack_from(data, at + 9)
        (nbytes,) = _U32.unpack_from(data, at + 11)
        if op != 0x07 or icid != cid or nbytes % 16 or nbytes + 6 != length:
            raise NotFast("bad message index")
        pairs = np.frombuffer(data, "<u8", count=nbytes // 8, offset=at + 15).reshape(-1, 2)
        order = np.argsort(pairs[:, 1], kind="stable")          # file (write) order
        t, off = pairs[order, 0], pairs[order, 1].astype(np.int64)
        if off.size and (off[0] < 0 or off[-1] > size - _HDR or np.any(np.diff(off) <= 0)):
            raise NotFast("message index points outside its chunk or twice at one record")
        hdr = _rows(chunk, off, _HDR).view(MSG_HEADER).ravel()
        length = hdr["len"].astype(np.int64)
        if not (np.all(hdr["op"] == 0x05) and np.all(hdr["cid"] == cid)
                and np.array_equal(hdr["log"], t) and np.all(length >= 22)
                and np.all(off + 9 + length <= size)):
            raise NotFast("message index does not match the chunk's records")
        start, length = off + _HDR, length - 22
        t = t.astype(np.int64)
        if length.size and np.all(length == length[0]):
            out[cid] = (t, _rows(chunk, start, int(length[0])))
        else:
            out[cid] = (t, [records[s:s + n] for s, n in zip(start.tolist(), length.tolist())])
    return out


def _read_indexed(data: bytes, topics: list[str]) -> dict[str, list[tuple]]:
    """topic -> [(log times, payloads) per chunk] of one file via its indexes, or NotFast."""
    channels, counts, chunks = _summary(data)
    wanted = {cid for cid, topic in channels.items() if topic in topics}
    parts: dict[str, list[tuple]] = {t: [] for t in topics}
    seen: dict[int, int] = {}
    for offset, index_offsets in chunks:
        op, length = _REC.unpack_from(data, offset)
        if op != 0x06 or offset + 9 + length > len(data):
            raise NotFast("chunk index does not point at a chunk")
        if not index_offsets and length:
            raise NotFast("a chunk without message indexes")
        records = _chunk_records(data, offset + 9)
        for cid, (t, payloads) in _indexed_messages(records, data, index_offsets,
                                                    wanted).items():
            parts[channels[cid]].append((t, payloads))
            seen[cid] = seen.get(cid, 0) + len(t)
        for cid in index_offsets:
            if cid not in channels:
                raise NotFast(f"message index for undeclared channel {cid}")
    if counts is not None and any(counts.get(cid, 0) != seen.get(cid, 0) for cid in wanted):
        raise NotFast("message indexes and statistics disagree")
    return parts


# ------------------------------------------------------------------ scanned (per record)
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
            records = _chunk_records(buf, body)
            _scan_records(records, 0, len(records), channels, wanted, top=False)
            by_channel = {cid: wanted.get(topic) for cid, topic in channels.items()}
        elif op in (0x0F, 0x02) and top:  # DataEnd, Footer: the summary section follows
            return


def _read_scanned(data: bytes, topics: list[str]) -> dict[str, list[tuple]]:
    wanted: dict[str, tuple[list, list]] = {t: ([], []) for t in topics}
    _scan_records(data, len(_MAGIC), len(data) - len(_MAGIC), {}, wanted, top=True)
    return {topic: [(times, payloads)] for topic, (times, payloads) in wanted.items()}


def read_raw(bag: Path, topics: list[str], files: list[Path] | None = None, *,
             indexed: bool = True) -> dict[str, tuple[np.ndarray, Payloads]]:
    """``topic -> (log times ns (int64, sorted, stable), raw CDR payloads)`` via the fast
    path (``files``: the bag's MCAP files from :func:`fast_info`; ``indexed=False``: the
    per-record scan only, for comparisons)."""
    parts: dict[str, list[tuple]] = {t: [] for t in topics}
    for path in files if files is not None else _mcap_files(bag):
        data = path.read_bytes()
        if not data.startswith(_MAGIC):
            raise NotFast("bad magic")
        try:
            try:
                if not indexed:
                    raise NotFast("not asked for")
                got = _read_indexed(data, topics)
            except NotFast:
                got = _read_scanned(data, topics)
        except NotFast:
            raise
        except Exception as err:  # struct.error, decompression errors ...
            raise NotFast(f"{type(err).__name__}: {err}") from None
        for topic, pieces in got.items():
            parts[topic].extend(pieces)
    out = {}
    for topic, pieces in parts.items():
        try:
            t = np.concatenate([np.asarray(p[0], dtype=np.int64) for p in pieces]) \
                if pieces else np.zeros(0, np.int64)
        except OverflowError:       # a log time no ROS time can be: a damaged record
            raise NotFast(f"topic {topic}: a log time beyond 2^63 ns") from None
        if t.size and t.min() < 0:
            raise NotFast(f"topic {topic}: a log time beyond 2^63 ns")
        payloads = Payloads.join([p[1] for p in pieces])
        if t.size > 1 and np.any(np.diff(t) < 0):
            order = np.argsort(t, kind="stable")
            t, payloads = t[order], payloads.take(order)
        out[topic] = (t, payloads)
    return out
