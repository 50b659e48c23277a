"""Offline replay: run a recorded bag through the runner, exactly as the live node would.

``replay(bag, params, out)`` reads the bag, feeds the messages in log-time
order to :class:`~fto_ros.runner.runner.Runner` (the very adapter the live node
uses), writes the node's outputs to ``out`` as a rosbag2 MCAP bag, and
compares the estimate with the bag's ground truth: ``out/metrics.json`` and
``out/replay.png``.  No rclpy, no DDS; deterministic.

How the messages drive the runner (what the node does on live topics):

- ``source: topics``: a message on ``topics.input`` calls
  ``runner.set_input(t, msg.data)``, one on ``topics.measured_output`` calls
  ``runner.process(t, msg.data)``; ``t`` is the message's log time in seconds
  (the node stamps Float64MultiArray on receipt; a bag's log time is the
  receipt time).  At equal log times inputs go first: an input stamped t
  applies from t on.
- ``source: joint_states``: each JointState is turned into ``(t, y, u)`` by
  :func:`~fto_ros.runner.messages.joint_state_sample` (``t`` = header stamp);
  a stamp more than ``time.future_tolerance`` ahead of the log time (the sim
  clock) is rejected as ``future_stamp``; ``u`` (when input joints are
  configured) is set before ``y`` is processed, and a rejected ``u`` drops the
  sample.
- Every accepted sample publishes ``state_estimate`` and ``convergence``
  (Float64MultiArray with one labelled layout dimension, like the node; a
  non-finite value, i.e. guaranteed_time = inf, is published as -1),
  ``unknown_input_estimate`` (observers that have one) and
  ``estimated_joint_states`` (when configured) under ``/<node name>/``, with
  log time = sample time.  ``/diagnostics`` gets ``runner.status(t)`` every
  ``diagnostics.period`` seconds of bag time (1 s by default), plus a final one.

Speed: the bag is read with a small MCAP fast path (chunks decompressed and
scanned with ``struct``, Float64MultiArray payloads decoded in bulk with
numpy; anything unusual falls back to :class:`~fto_ros.bag.BagReader`), and
outputs are serialised from byte templates checked once against the rosbags
serialiser.  ``metrics.json`` reports the measured speed and where the time
went.
"""
from __future__ import annotations

import functools
import gc
import json
import math
import struct
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

from ..bag import BagError, BagReader, BagWriter
from ..bag.reader import jazzy_typestore
from ..core.errors import short
from ..observers.base import Observer
from ..runner.messages import joint_state_sample
from ..runner.runner import CONVERGENCE_FIELDS, LEVEL_NAMES, Runner
from ..runner.params_file import load_params_files
from . import metrics as M

F64_ARRAY = "std_msgs/msg/Float64MultiArray"
JOINT_STATE = "sensor_msgs/msg/JointState"
DEFAULT_NODE_NAME = "observer_node"
DEFAULT_TOLERANCE = 1e-2
METRICS_SCHEMA = "fto_ros/replay-metrics/1"
#: log times from here on cannot be header stamps (int32 seconds)
MAX_STAMP_NS = 2 ** 31 * 1_000_000_000
#: a replay that accepts fewer than this fraction of its measurement samples fails (exit 1)
DEFAULT_MIN_ACCEPTED = 0.5

# event kinds; at equal log times they are processed in this order
K_INPUT, K_MEAS, K_JOINT, K_TRUTH = 0, 1, 1, 2
_KIND_INPUT, _KIND_MEAS, _KIND_JOINT, _KIND_TRUTH = 0, 1, 2, 3


_ROLE_NAMES = {"meas": "measured_output", "inputs": "input", "joints": "joint_states",
               "truth": "true_state", "truth_ui": "true_unknown_input"}


class ReplayError(Exception):
    """The replay cannot run (e.g. the bag lacks a topic the configuration needs)."""


# --------------------------------------------------------------------------------------
# names
# --------------------------------------------------------------------------------------
def node_fqn(node_name: str | None) -> str:
    """Fully qualified node name, ``/observer_node`` by default."""
    name = (node_name or DEFAULT_NODE_NAME).strip("/")
    if not name:
        raise ReplayError(f"invalid node name {node_name!r}")
    return "/" + name


def resolve_topic(name: str, fqn: str) -> str:
    """ROS 2 name resolution of a topic name for the node ``fqn`` (no remapping).

    ``/abs`` stays; ``~/x`` is ``<fqn>/x``; a relative ``x`` is ``<namespace>/x``.
    """
    if name.startswith("/"):
        return name
    if name.startswith("~"):
        return fqn + "/" + name[1:].lstrip("/")
    ns = fqn.rsplit("/", 1)[0]
    return f"{ns}/{name}"


# --------------------------------------------------------------------------------------
# reading: MCAP fast path
# --------------------------------------------------------------------------------------
_MAGIC = b"\x89MCAP0\r\n"
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQ")          # channel id, sequence, log time (publish time follows)
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
#: the fast path reads whole files into memory; larger bags go through BagReader
FAST_PATH_MAX_BYTES = 1 << 30


class _NotFast(Exception):
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
            raise _NotFast("no zstd module") from None
    if name == "lz4":
        try:
            from lz4.frame import decompress
        except ImportError:
            raise _NotFast("no lz4 module") from None
        return lambda data, size: decompress(data)
    raise _NotFast(f"unknown MCAP compression {name!r}")


def _mcap_files(bag: Path) -> list[Path]:
    """The MCAP files of a bag, or _NotFast (SQLite3, file-compressed bags ...)."""
    if bag.is_file():
        if bag.suffix != ".mcap":
            raise _NotFast("not an .mcap file")
        return [bag]
    try:
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except Exception as err:
        raise _NotFast(f"metadata.yaml: {err}") from None
    if meta.get("storage_identifier") != "mcap" or meta.get("compression_mode") not in ("", None):
        raise _NotFast("not an uncompressed-file MCAP bag")
    files = [bag / p for p in meta.get("relative_file_paths") or []]
    if not files or any(p.suffix != ".mcap" or not p.is_file() for p in files):
        raise _NotFast("unexpected file list")
    if sum(p.stat().st_size for p in files) > FAST_PATH_MAX_BYTES:
        raise _NotFast("bag too large to read into memory")
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
            raise _NotFast("truncated record")
        if op == 0x05:  # Message
            cid, _seq, log_time = unpack_msg(buf, body)
            try:
                sink = by_channel[cid]
            except KeyError:
                raise _NotFast(f"message on undeclared channel {cid}") from None
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
                raise _NotFast("chunk size mismatch")
            _scan_records(records, 0, len(records), channels, wanted, top=False)
            by_channel = {cid: wanted.get(topic) for cid, topic in channels.items()}
        elif op in (0x0F, 0x02) and top:  # DataEnd, Footer: the summary section follows
            return


def _read_fast(bag: Path, topics: list[str]) -> dict[str, tuple[np.ndarray, list[bytes]]]:
    """``topic -> (log times ns (int64, sorted, stable), raw CDR payloads)`` via the fast path."""
    wanted: dict[str, tuple[list, list]] = {t: ([], []) for t in topics}
    for path in _mcap_files(bag):
        data = path.read_bytes()
        if not data.startswith(_MAGIC):
            raise _NotFast("bad magic")
        try:
            _scan_records(data, len(_MAGIC), len(data) - len(_MAGIC), {}, wanted, top=True)
        except _NotFast:
            raise
        except Exception as err:  # struct.error, decompression errors ...
            raise _NotFast(f"{type(err).__name__}: {err}") from None
    out = {}
    for topic, (times, payloads) in wanted.items():
        t = _log_times(times, bag, topic)
        if t.size > 1 and np.any(np.diff(t) < 0):
            order = np.argsort(t, kind="stable")
            t = t[order]
            payloads = [payloads[i] for i in order.tolist()]
        out[topic] = (t, payloads)
    return out


# --------------------------------------------------------------------------------------
# CDR: decoding Float64MultiArray, encoding outputs
# --------------------------------------------------------------------------------------
_CDR_LE = b"\x00\x01\x00\x00"  # CDR, little endian


class _Cdr:
    """Little-endian XCDR1 bytes; alignment counts from the end of the 4-byte header."""

    def __init__(self):
        self.buf = bytearray(_CDR_LE)

    def align(self, a: int) -> None:
        self.buf += b"\x00" * ((4 - len(self.buf)) % a)

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += _U32.pack(v)

    def string(self, s: str) -> None:
        b = s.encode() + b"\x00"
        self.u32(len(b))
        self.buf += b


def f64_prefix(n: int, label: str | None = None) -> bytes:
    """CDR bytes of a Float64MultiArray of n values up to its first double.

    ``label`` None: empty layout; else one dimension ``(label, n, n)`` (what
    the live node publishes).
    """
    c = _Cdr()
    if label is None:
        c.u32(0)
    else:
        c.u32(1)
        c.string(label)
        c.u32(n)
        c.u32(n)
    c.u32(0)  # data_offset
    c.u32(n)
    if n:
        c.align(8)
    return bytes(c.buf)


def _f64_data_at(p) -> tuple[int, int]:
    """(offset of the first double, count) of a little-endian CDR Float64MultiArray."""
    if bytes(p[:4]) != _CDR_LE:
        raise ValueError("not little-endian CDR")
    pos = 4
    (ndims,) = _U32.unpack_from(p, pos)
    pos += 4
    for _ in range(ndims):
        pos += (4 - pos) % 4
        (slen,) = _U32.unpack_from(p, pos)
        pos += 4 + slen
        pos += (4 - pos) % 4
        pos += 8  # size, stride
    pos += (4 - pos) % 4
    _offset, count = struct.unpack_from("<II", p, pos)
    pos += 8
    if count:
        pos += (4 - pos) % 8
    if pos + 8 * count > len(p):
        raise ValueError("truncated")
    return pos, count


def decode_float_arrays(payloads: list, typestore, where: str = "Float64MultiArray") -> list:
    """The ``data`` of raw CDR Float64MultiArray payloads, as lists of floats.

    In bulk with numpy when every payload has the same length and the same
    bytes before its data (the usual case: one publisher, fixed layout); per
    message otherwise, with the rosbags deserialiser for anything unusual
    (big-endian CDR).  A payload nothing can decode raises BagError naming
    ``where`` (the bag and the topic) and the message.
    """
    if not payloads:
        return []
    try:
        off, count = _f64_data_at(payloads[0])
        length = len(payloads[0])
        if all(len(p) == length for p in payloads):
            raw = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(len(payloads), length)
            if np.array_equal(raw[:, :off], np.broadcast_to(raw[0, :off], (len(payloads), off))):
                if count == 0:
                    return [[] for _ in payloads]
                return raw[:, off:off + 8 * count].copy().view("<f8").tolist()
    except (ValueError, struct.error):
        pass
    out = []
    for k, p in enumerate(payloads):
        try:
            off, count = _f64_data_at(p)
            out.append(list(struct.unpack_from(f"<{count}d", p, off)))
        except (ValueError, struct.error):
            out.append(_deserialize(typestore, p, F64_ARRAY, where, k).data.tolist())
    return out


def _deserialize(typestore, payload, msgtype: str, where: str, k: int):
    """One raw CDR message, or BagError naming where it is."""
    try:
        return typestore.deserialize_cdr(bytes(payload), msgtype)
    except Exception as exc:  # rosbags raises SerdeError, struct.error, IndexError ...
        raise BagError(f"{where}: cannot decode message {k} as {msgtype}: "
                       f"{type(exc).__name__}: {short(exc)}") from None


class _Encoders:
    """Byte-template serialisers for the published messages, each checked once against rosbags.

    A template that does not reproduce ``typestore.serialize_cdr`` byte for
    byte is not used: that message type then goes through rosbags.
    """

    def __init__(self, typestore):
        self.ts = typestore
        T = typestore.types
        self._F64 = T[F64_ARRAY]
        self._Layout = T["std_msgs/msg/MultiArrayLayout"]
        self._Dim = T["std_msgs/msg/MultiArrayDimension"]
        self._JS = T[JOINT_STATE]
        self._Header = T["std_msgs/msg/Header"]
        self._Time = T["builtin_interfaces/msg/Time"]
        self._f64: dict[tuple, Callable[[np.ndarray], bytes]] = {}
        self._js: dict[tuple, Callable] = {}
        self.fallbacks: list[str] = []

    def _rosbags_f64(self, x: np.ndarray, label: str | None) -> bytes:
        n = len(x)
        dims = [] if label is None else [self._Dim(label=label, size=n, stride=n)]
        msg = self._F64(layout=self._Layout(dim=dims, data_offset=0),
                        data=np.ascontiguousarray(x, dtype=np.float64))
        return bytes(self.ts.serialize_cdr(msg, F64_ARRAY))

    def float_array(self, n: int, label: str | None = None,
                    values: str = "array") -> Callable[[Any], bytes]:
        """``x (length n) -> CDR bytes`` (layout: see :func:`f64_prefix`).

        ``values``: "array" for a float64 numpy array, "list" for a list of floats.
        """
        key = (n, label, values)
        enc = self._f64.get(key)
        if enc is None:
            prefix = f64_prefix(n, label)
            if values == "array":
                def enc(x, _p=prefix):
                    return _p + x.tobytes()
            else:
                def enc(x, _p=prefix, _pack=struct.Struct(f"<{n}d").pack):
                    return _p + _pack(*x)
            probe = np.arange(n, dtype=np.float64) * 1.25 - 0.5
            if enc(probe if values == "array" else probe.tolist()) != self._rosbags_f64(probe, label):
                self.fallbacks.append(f"Float64MultiArray[{n}]")

                def enc(x, _label=label):
                    return self._rosbags_f64(np.asarray(x, dtype=np.float64), _label)
            self._f64[key] = enc
        return enc

    def _rosbags_js(self, names, sec, nsec, pos, vel, eff) -> bytes:
        msg = self._JS(header=self._Header(stamp=self._Time(sec=sec, nanosec=nsec), frame_id=""),
                       name=list(names), position=np.asarray(pos, dtype=np.float64),
                       velocity=np.asarray(vel, dtype=np.float64),
                       effort=np.asarray(eff, dtype=np.float64))
        return bytes(self.ts.serialize_cdr(msg, JOINT_STATE))

    def joint_state(self, names: list[str], sizes: tuple[int, int, int]) -> Callable:
        """``(sec, nanosec, position, velocity, effort) -> CDR bytes`` for fixed names and sizes."""
        key = (tuple(names), sizes)
        enc = self._js.get(key)
        if enc is not None:
            return enc
        # XCDR1 little endian; alignment relative to the end of the 4-byte header
        fmt, consts, off = ["<4siI"], [_CDR_LE], 8
        pending = bytearray()

        def const(b: bytes) -> None:
            nonlocal off
            pending.extend(b)
            off += len(b)

        def align(a: int) -> None:
            const(b"\x00" * ((-off) % a))

        def flush() -> None:
            fmt.append(f"{len(pending)}s")
            consts.append(bytes(pending))
            pending.clear()

        def string(s: str) -> None:
            b = s.encode() + b"\x00"
            align(4)
            const(struct.pack("<I", len(b)) + b)

        string("")  # frame_id
        align(4)
        const(struct.pack("<I", len(names)))
        for nm in names:
            string(nm)
        arrays = []
        for k in sizes:
            align(4)
            const(struct.pack("<I", k))
            if k:
                align(8)
                flush()
                fmt.append(f"{k}d")
                off += 8 * k
                arrays.append(True)
            else:
                arrays.append(False)
        flush()
        packer = struct.Struct("".join(fmt)).pack
        c = consts  # c[0] header, c[1] up to the first array, then one per array

        def enc(sec, nsec, pos, vel, eff):
            args = [c[0], sec, nsec, c[1]]
            j = 2
            for present, vals in zip(arrays, (pos, vel, eff)):
                if present:
                    args.extend(vals)
                    args.append(c[j])
                    j += 1
            return packer(*args)

        probe = [[0.5 + i + 10 * f for i in range(k)] for f, k in enumerate(sizes)]
        try:
            ok = enc(12, 345, *probe) == self._rosbags_js(names, 12, 345, *probe)
        except struct.error:
            ok = False
        if not ok:
            self.fallbacks.append(f"JointState{sizes}")

            def enc(sec, nsec, pos, vel, eff, _n=list(names)):
                return self._rosbags_js(_n, sec, nsec, pos, vel, eff)
        self._js[key] = enc
        return enc


# --------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------
def _raw_writer(bag: BagWriter, topic: str, msgtype: str) -> Callable[[int, bytes], None]:
    """A ``write(t_ns, cdr_bytes)`` function for ``topic`` of an open BagWriter."""
    return bag.raw_writer(topic, msgtype)


# --------------------------------------------------------------------------------------
# progress
# --------------------------------------------------------------------------------------
class _Progress:
    """A plain ``\\r`` progress bar on stderr, drawn only for replays that take a while."""

    WIDTH = 30

    def __init__(self, enabled: bool, t0_ns: int, t1_ns: int, delay: float = 0.5):
        self.enabled = enabled and sys.stderr.isatty()
        self.t0, self.span = t0_ns, max(t1_ns - t0_ns, 1)
        self.start = time.perf_counter()
        self.delay = delay
        self.drawn = False

    def update(self, t_ns: int) -> None:
        if not self.enabled or time.perf_counter() - self.start < self.delay:
            return
        frac = min(max((t_ns - self.t0) / self.span, 0.0), 1.0)
        fill = int(frac * self.WIDTH)
        sys.stderr.write(f"\rfto-replay [{'#' * fill}{'.' * (self.WIDTH - fill)}] "
                         f"{frac * 100:5.1f}%  {(t_ns - self.t0) / 1e9:.1f} / "
                         f"{self.span / 1e9:.1f} s of bag")
        sys.stderr.flush()
        self.drawn = True

    def done(self) -> None:
        if self.drawn:
            self.update(self.t0 + self.span)
            sys.stderr.write("\n")
            sys.stderr.flush()


# --------------------------------------------------------------------------------------
# reading the bag into streams
# --------------------------------------------------------------------------------------
_EMPTY = (np.zeros(0, np.int64), [])


@dataclass
class _Streams:
    """The messages of one replay by role: ``(log times ns, values or messages)``."""

    inputs: tuple = _EMPTY
    meas: tuple = _EMPTY
    joints: tuple = _EMPTY
    truth: tuple = _EMPTY
    truth_ui: tuple = _EMPTY                          # true unknown input, when the bag has it
    truth_copy: list = field(default_factory=list)  # raw CDR (fast path) or messages
    truth_raw: bool = True
    reader: str = ""


def _read_streams(bag_path: Path, reader: BagReader, roles: dict[str, str],
                  typestore, listed: dict) -> _Streams:
    """Read and decode the topics of ``roles`` (role -> topic).  Every message the bag
    lists is read or BagError says which topic lost some: never a silent drop."""
    topics = sorted(set(roles.values()))
    s = _Streams()
    try:
        raw = _read_fast(bag_path, topics)
        s.reader = "MCAP fast path"
        _check_counts(bag_path, listed, {t: len(raw[t][1]) for t in topics})
    except _NotFast as why:
        raw = None
        s.reader = f"rosbags BagReader ({why})"
    except BagError as err:     # the fast path read fewer: let rosbags try, it must do better
        raw = None
        s.reader = f"rosbags BagReader ({err})"
    if raw is not None:
        for role, topic in roles.items():
            t, payloads = raw[topic]
            where = f"{bag_path}: topic {topic}"
            if role == "joints":
                s.joints = (t, [_deserialize(typestore, p, JOINT_STATE, where, k)
                                for k, p in enumerate(payloads)])
            else:
                setattr(s, role, (t, decode_float_arrays(payloads, typestore, where)))
                if role == "truth":
                    s.truth_copy = payloads
        return s
    lists: dict[str, tuple[list, list]] = {topic: ([], []) for topic in topics}
    for topic, t_ns, msg in reader.messages(topics):
        lists[topic][0].append(t_ns)
        lists[topic][1].append(msg)
    _check_counts(bag_path, listed, {t: len(lists[t][0]) for t in topics})
    for role, topic in roles.items():
        t = _log_times(lists[topic][0], bag_path, topic)
        msgs = lists[topic][1]
        if role == "joints":
            s.joints = (t, msgs)
        else:
            setattr(s, role, (t, [np.asarray(m.data, dtype=float).tolist() for m in msgs]))
            if role == "truth":
                s.truth_copy, s.truth_raw = msgs, False
    return s


def _log_times(times: list, bag_path: Path, topic: str) -> np.ndarray:
    """Log times (ns) as int64, or BagError for one no ROS time can be (>= 2^63 ns)."""
    try:
        return np.asarray(times, dtype=np.int64)
    except OverflowError:
        raise BagError(f"{bag_path}: topic {topic}: a log time beyond 2^63 ns (a corrupt "
                       "file?)") from None


def _check_counts(bag_path: Path, listed: dict, got: dict[str, int]) -> None:
    """BagError unless every topic gave as many messages as the bag lists for it."""
    for topic, n in got.items():
        want = listed[topic].count
        if n != want:
            raise BagError(f"{bag_path}: topic {topic}: read {n} of the {want} messages the bag "
                           "lists (a truncated or corrupt file?)")


def _check_topic(topics: dict, topic: str, msgtype: str, what: str, bag_path: Path) -> None:
    if topic not in topics:
        listing = ", ".join(f"{k} ({v.msgtype})" for k, v in topics.items()) or "none"
        raise ReplayError(f"{bag_path}: the bag has no {what} topic {topic} (from the params "
                          f"file); the bag's topics: {listing}")
    if topics[topic].msgtype != msgtype:
        raise ReplayError(f"{bag_path}: topic {topic} has type {topics[topic].msgtype}; "
                          f"the {what} topic must be {msgtype}")


# --------------------------------------------------------------------------------------
# the replay
# --------------------------------------------------------------------------------------
@dataclass
class _Run:
    """What the replay loop produced."""

    info: Any = None
    roles: dict = field(default_factory=dict)
    truth_topic: str = ""
    truth_note: str | None = None
    truth_ui_topic: str = ""
    truth_ui_note: str | None = None
    est_ui_idx: list = field(default_factory=list)    # index into est_* of each unknown-input estimate
    est_ui: list = field(default_factory=list)
    streams: _Streams | None = None
    est_t: list = field(default_factory=list)
    est_x: list = field(default_factory=list)
    est_conv: list = field(default_factory=list)
    proc_s: list = field(default_factory=list)
    runner_s: float = 0.0
    counts: dict = field(default_factory=dict)
    status_levels: dict = field(default_factory=dict)
    final_status: Any = None
    fallbacks: list = field(default_factory=list)
    timing: dict = field(default_factory=dict)


def _run(runner: Runner, bag_path: Path, out_dir: Path, fqn: str, overwrite: bool,
         progress: bool, custom: dict[str, str]) -> _Run:
    """Read the bag, drive the runner, write the output bag (the timed part)."""
    settings, obs = runner.settings, runner.observer
    r = _Run()
    wall0 = time.perf_counter()
    with BagReader(bag_path) as reader:
        r.info = info = reader.info()
        topics = info.topics
        roles = r.roles
        if settings["source"] == "topics":
            roles["meas"] = resolve_topic(settings["topics.measured_output"], fqn)
            _check_topic(topics, roles["meas"], F64_ARRAY, "measured_output", bag_path)
            if obs.n_inputs:
                roles["inputs"] = resolve_topic(settings["topics.input"], fqn)
                _check_topic(topics, roles["inputs"], F64_ARRAY,
                             f"input (the observer has {obs.n_inputs} known input(s))", bag_path)
        else:
            roles["joints"] = resolve_topic(settings["topics.joint_states"], fqn)
            _check_topic(topics, roles["joints"], JOINT_STATE, "joint_states", bag_path)
        r.truth_topic = truth_topic = resolve_topic(settings["topics.true_state"], fqn)
        if truth_topic not in topics:
            r.truth_note = f"no ground truth: the bag has no topic {truth_topic}"
        elif topics[truth_topic].msgtype != F64_ARRAY:
            r.truth_note = (f"no ground truth: {truth_topic} is {topics[truth_topic].msgtype}, "
                            f"not {F64_ARRAY}")
        else:
            roles["truth"] = truth_topic
        r.truth_ui_topic = ui_topic = resolve_topic(
            settings.get("topics.true_unknown_input", "true_unknown_input"), fqn)
        if ui_topic in topics and topics[ui_topic].msgtype == F64_ARRAY:
            roles["truth_ui"] = ui_topic
        else:
            r.truth_ui_note = (f"no unknown-input ground truth: the bag has no {F64_ARRAY} "
                               f"topic {ui_topic}")
        typestore = getattr(reader, "typestore", None) or jazzy_typestore()
        r.streams = streams = _read_streams(bag_path, reader, roles, typestore, topics)
    wall_read = time.perf_counter()

    # events in log-time order; at equal times inputs, then samples, then truth (stable)
    parts = [(streams.inputs[0], K_INPUT, _KIND_INPUT), (streams.meas[0], K_MEAS, _KIND_MEAS),
             (streams.joints[0], K_JOINT, _KIND_JOINT), (streams.truth[0], K_TRUTH, _KIND_TRUTH)]
    t_all = np.concatenate([p[0] for p in parts])
    order = np.lexsort((np.concatenate([np.full(p[0].size, p[1], np.int8) for p in parts]), t_all))
    ev_t = t_all[order].tolist()
    ev_kind = np.concatenate([np.full(p[0].size, p[2], np.int8) for p in parts])[order].tolist()
    ev_idx = np.concatenate([np.arange(p[0].size) for p in parts])[order].tolist()
    wall_order = time.perf_counter()

    enc = _Encoders(typestore)
    period_ns = max(int(round(settings["diagnostics.period"] * 1e9)), 1)
    # as the node: status name "<node name>: observer", hardware_id defaults to the observer type
    diag_name = f"{fqn.rsplit('/', 1)[-1]}: observer"
    hw_id = settings["diagnostics.hardware_id"] or runner.observer_type
    future_tol_ns = int(round(settings["time.future_tolerance"] * 1e9))
    reject = runner.reject  # as the node does
    received = {"measured_output": streams.meas[0], "input": streams.inputs[0],
                "joint_states": streams.joints[0]}
    t_first = ev_t[0] if ev_t else info.start_ns
    t_last = ev_t[-1] if ev_t else info.end_ns
    tick_ns = max((t_last - t_first) // 200, 1)
    bar = _Progress(progress, t_first, t_last)
    est_t, est_x, est_conv, proc_s = r.est_t, r.est_x, r.est_conv, r.proc_s
    est_ui_idx, est_ui = r.est_ui_idx, r.est_ui
    counts = r.counts
    inputs, meas, joints = streams.inputs[1], streams.meas[1], streams.joints[1]
    truth_copy = streams.truth_copy
    set_input, process = runner.set_input, runner.process
    perf = time.perf_counter
    inf = math.inf
    runner_s = 0.0
    Path(out_dir).parent.mkdir(parents=True, exist_ok=True)   # --out a/b/c: make a/b
    wall_loop0 = time.perf_counter()
    with BagWriter(out_dir, overwrite=overwrite, custom_data=custom) as bag:
        topic_est, topic_conv = f"{fqn}/state_estimate", f"{fqn}/convergence"
        topic_ui, topic_js = f"{fqn}/unknown_input_estimate", f"{fqn}/estimated_joint_states"
        w_est = _raw_writer(bag, topic_est, F64_ARRAY)
        w_conv = _raw_writer(bag, topic_conv, F64_ARRAY)
        # the node's layouts: one labelled dimension on state_estimate and convergence
        enc_est = enc.float_array(obs.n_states, ",".join(obs.state_names))
        enc_conv = enc.float_array(len(CONVERGENCE_FIELDS), ",".join(CONVERGENCE_FIELDS), "list")
        w_ui = w_js = enc_js = None
        if type(obs).unknown_input is not Observer.unknown_input:  # the class identifies one
            w_ui = _raw_writer(bag, topic_ui, F64_ARRAY)
        if settings["estimated_joint_states.joint_names"]:
            w_js = _raw_writer(bag, topic_js, JOINT_STATE)
        n_ui = n_js = 0
        w_truth = None
        if "truth" in roles:
            if streams.truth_raw:
                w_truth = _raw_writer(bag, truth_topic, F64_ARRAY)
            else:
                w_truth = functools.partial(bag.write_message, truth_topic)

        def diagnostics(t_ns: int, side: str = "left"):
            st = runner.status(t_ns / 1e9)
            if t_ns >= MAX_STAMP_NS:            # no header stamp can say that time
                return st
            # the node adds its own counters; the replay's equivalents (no wall-clock rates)
            values = list(st.values) + [
                ("enabled", "true"), ("source", settings["source"]),
                *((f"messages received: {k}", str(int(np.searchsorted(v, t_ns, side))))
                  for k, v in received.items()),
                ("estimates published", str(len(est_t))), ("sim time", "true (offline replay)")]
            bag.diagnostics("/diagnostics", t_ns, [{
                "level": st.level, "name": diag_name, "message": st.message,
                "hardware_id": hw_id, "values": values}])
            counts["/diagnostics"] = counts.get("/diagnostics", 0) + 1
            level = LEVEL_NAMES.get(st.level, str(st.level))
            r.status_levels[level] = r.status_levels.get(level, 0) + 1
            return st

        next_diag = t_first + period_ns
        next_tick = min(next_diag, t_first + tick_ns)
        for t_ns, kind, i in zip(ev_t, ev_kind, ev_idx):
            if t_ns >= next_tick:
                if t_ns >= next_diag:
                    # one status per period of bag time; across a forward jump of the log time
                    # one at the first boundary, then the next boundary after the jump: O(1)
                    diagnostics(next_diag)
                    next_diag += period_ns
                    if t_ns >= next_diag:
                        next_diag += (t_ns - next_diag) // period_ns * period_ns + period_ns
                bar.update(t_ns)
                next_tick = min(next_diag, t_ns + tick_ns)
            if kind == _KIND_MEAS:
                c0 = perf()
                out = process(t_ns / 1e9, meas[i])
                c1 = perf()
                runner_s += c1 - c0
                if out.__class__ is str:
                    continue
                proc_s.append(c1 - c0)
                s_ns = t_ns
            elif kind == _KIND_INPUT:
                c0 = perf()
                set_input(t_ns / 1e9, inputs[i])
                runner_s += perf() - c0
                continue
            elif kind == _KIND_TRUTH:
                w_truth(t_ns, truth_copy[i])
                continue
            else:  # a JointState (source: joint_states); its sample time is the header stamp
                msg = joints[i]
                c0 = perf()
                sample = joint_state_sample(msg, settings)
                if sample.__class__ is str:
                    reject(sample)
                    runner_s += perf() - c0
                    continue
                t, y, u = sample
                s_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                if s_ns - t_ns > future_tol_ns:  # ahead of the (sim) clock = the log time
                    reject("future_stamp")
                    runner_s += perf() - c0
                    continue
                if u is not None and set_input(t, u) is not None:
                    runner_s += perf() - c0
                    continue  # counted by the runner; never pair y with a bad u
                c1 = perf()
                out = process(t, y)
                c2 = perf()
                runner_s += c2 - c0
                if out.__class__ is str:
                    continue
                proc_s.append(c2 - c1)
            # publish what the node publishes, log time = sample time
            x = out.estimate
            est_t.append(s_ns)
            est_x.append(x)
            est_conv.append(out.convergence)
            w_est(s_ns, enc_est(x))
            # as the node: non-finite (guaranteed_time = inf: no guarantee) published as -1.0
            w_conv(s_ns, enc_conv([v if -inf < v < inf else -1.0
                                   for v in out.convergence.tolist()]))
            if out.unknown_input is not None and w_ui is not None:
                ui = np.asarray(out.unknown_input, dtype=np.float64)
                w_ui(s_ns, enc.float_array(ui.size)(ui))
                n_ui += 1
                est_ui_idx.append(len(est_t) - 1)
                est_ui.append(ui)
            if out.joint_state is not None and w_js is not None:
                names, pos, vel, eff = out.joint_state
                if enc_js is None:
                    enc_js = enc.joint_state(names, (len(pos), len(vel), len(eff)))
                w_js(s_ns, enc_js(s_ns // 1_000_000_000, s_ns % 1_000_000_000, pos, vel, eff))
                n_js += 1
        r.final_status = diagnostics(t_last, "right")
        bar.done()
        wall_loop1 = time.perf_counter()
        counts[topic_est] = counts[topic_conv] = len(est_t)
        if w_ui is not None:
            counts[topic_ui] = n_ui
        if w_js is not None:
            counts[topic_js] = n_js
        if w_truth is not None:
            counts[truth_topic] = len(truth_copy)
    wall_end = time.perf_counter()
    r.runner_s = runner_s
    r.fallbacks = enc.fallbacks
    r.timing = {
        "read_decode": wall_read - wall0,
        "order_events": wall_order - wall_read,
        "runner": runner_s,
        "serialize_write": (wall_loop1 - wall_loop0) - runner_s,
        "close_output": wall_end - wall_loop1,
        "replay_total": wall_end - wall0,
    }
    return r


def replay(bag_path, params_path, out_dir, *, node_name: str | None = None,
           overwrite: bool = False, progress: bool = True, after: float | None = None,
           tolerance: float = DEFAULT_TOLERANCE, plot: bool = True,
           overrides: dict[str, Any] | None = None,
           min_accepted: float = DEFAULT_MIN_ACCEPTED) -> dict[str, Any]:
    """Replay ``bag_path`` through the observer of ``params_path``; write ``out_dir``.

    Args:
        bag_path: rosbag2 bag (directory or .mcap file).
        params_path: ROS 2 params file, or a list of them merged in order (later
            files override earlier ones, as several ``--params-file`` do); the
            blocks for ``node_name`` (and ``/**``) are used.
        out_dir: output bag directory; also receives ``metrics.json`` and
            ``replay.png``.  Must not exist unless ``overwrite``.
        node_name: node name for the params block and the output topic
            namespace (default ``observer_node``).
        progress: draw a progress bar on stderr (only on a terminal, and only
            once the replay has taken half a second).
        after: settle time (s after the observer's (re)start) for the
            "after settling" errors; default guaranteed_time + 0.01 s, or
            0.11 s for observers without a guarantee.
        tolerance: error bound (state units) for the measured convergence time.
        plot: write ``replay.png``.
        overrides: ``{full parameter name: value}`` applied after the files
            (``-p NAME:=VALUE``; ``fto-sweep --set``).
        min_accepted: the replay fails (ReplayError, after writing its outputs
            and metrics) when it accepts fewer than this fraction of the bag's
            measurement samples, or none at all: a bag of junk is not a result.

    Returns the metrics (also written to ``metrics.json``).
    Raises ConfigError (params), BagError (bags, existing output), ReplayError
    (anything else that stops the replay), each with a one-line message.
    """
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) \
            or not (math.isfinite(tolerance) and tolerance > 0):
        raise ReplayError(f"tolerance must be a positive number, got {tolerance!r}")
    if after is not None and not (isinstance(after, (int, float)) and math.isfinite(after)
                                  and after >= 0):
        raise ReplayError(f"after must be a finite number >= 0, got {after!r}")
    if not (isinstance(min_accepted, (int, float)) and 0.0 <= min_accepted <= 1.0):
        raise ReplayError(f"min_accepted must be a fraction in [0, 1], got {min_accepted!r}")
    params_paths = ([Path(p) for p in params_path] if isinstance(params_path, (list, tuple))
                    else [Path(params_path)])
    bag_path, out_dir = Path(bag_path), Path(out_dir)
    params_path = params_paths[-1]          # the tuning file, in titles and names
    fqn = node_fqn(node_name)
    runner = Runner(load_params_files(params_paths, node_name, overrides))
    jazzy_typestore()  # one-time library set-up (~50 ms on first use), not part of the replay
    obs = runner.observer
    if (out_dir.exists() or out_dir.is_symlink()) and not overwrite:
        raise BagError(f"{out_dir}: output exists already (remove it or pass --overwrite)")
    custom = {"fto_ros.replay.bag": str(bag_path),
              "fto_ros.replay.params": ", ".join(str(p) for p in params_paths),
              "fto_ros.replay.observer": obs.TYPE}
    # the replay allocates many small objects and frees none: the cyclic GC would only
    # rescan them again and again (it cost up to 2x in the read phase)
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        run = _run(runner, bag_path, out_dir, fqn, overwrite, progress, custom)
    finally:
        if gc_was_enabled:
            gc.enable()
    m0 = time.perf_counter()
    metrics, plot_data = _metrics(runner, run, bag_path, params_path, out_dir, fqn, after,
                                  tolerance)
    metrics["params_files"] = [str(p) for p in params_paths]
    metrics["overrides"] = dict(overrides or {})
    metrics["timing_s"]["metrics"] = time.perf_counter() - m0
    if plot:
        p0 = time.perf_counter()
        from .plot import plot_replay
        plot_replay(out_dir / "replay.png", **plot_data,
                    title=f"{obs.TYPE}: {params_path.name} on {bag_path.name}")
        metrics["plot"] = "replay.png"
        metrics["timing_s"]["plot"] = time.perf_counter() - p0
    (out_dir / "metrics.json").write_text(
        json.dumps(M.json_safe(metrics), indent=2, allow_nan=False) + "\n")
    _check_accepted(metrics, min_accepted)
    return metrics


def _check_accepted(m: dict, min_accepted: float) -> None:
    """ReplayError when the replay accepted no sample, or fewer than ``min_accepted`` of them."""
    total, accepted = m["sample_count"], m["samples_accepted"]
    reasons = ", ".join(f"{k}: {v}" for k, v in sorted(m["rejected_by_reason"].items(),
                                                       key=lambda kv: -kv[1])[:4])
    why = f" (rejected: {reasons})" if reasons else ""
    if accepted == 0:
        raise ReplayError(f"{m['bag']}: no sample accepted of {total}{why}; outputs in "
                          f"{m['output_bag']}")
    if accepted < min_accepted * total:
        raise ReplayError(f"{m['bag']}: only {accepted} of {total} samples accepted "
                          f"({accepted / total:.1%} < {min_accepted:.0%}){why}; outputs in "
                          f"{m['output_bag']}")


def _metrics(runner: Runner, run: _Run, bag_path: Path, params_path: Path, out_dir: Path,
             fqn: str, after: float | None, tolerance: float) -> tuple[dict, dict]:
    """(metrics dict, plot arguments) of a finished run."""
    obs, settings, info, streams = runner.observer, runner.settings, run.info, run.streams
    names = list(obs.state_names)
    n = obs.n_states
    t_est_ns = np.asarray(run.est_t, dtype=np.int64)
    x_est = np.vstack(run.est_x) if run.est_x else np.zeros((0, n))
    conv = np.vstack(run.est_conv) if run.est_conv else np.zeros((0, len(CONVERGENCE_FIELDS)))
    gt = float(obs.guaranteed_time)
    if after is not None:
        settle, settle_rule = float(after), "given (after= / --after)"
    elif settings["metrics.settle_time"] > 0.0:
        settle, settle_rule = settings["metrics.settle_time"], "params file (metrics.settle_time)"
    else:
        settle, settle_rule = M.default_settle_time(gt)
    t_start_ns = int(t_est_ns[0]) if t_est_ns.size else None

    truth_note = run.truth_note
    truth_t = truth_x = None
    if "truth" in run.roles:
        truth_t, truth_x, why = _truth_rows(streams.truth, run.truth_topic, n, "",
                                            f"the observer has {n} states")
        truth_note = why or truth_note
    errors = conv_time = err_t = err_norm = None
    if truth_x is not None and not t_est_ns.size:
        truth_note = "no accepted samples: nothing to compare with the ground truth"
    elif truth_x is not None:
        mask, x_at = M.match_truth(t_est_ns, truth_t, truth_x)
        err = x_at[mask] - x_est[mask]
        settled = conv[mask, 0] >= settle - 1e-9  # time since (re)start, float round-off
        errors = M.error_stats(err, names, settled)
        errors.update(
            matched_samples=int(mask.sum()), settled_samples=int(settled.sum()),
            unmatched_samples=int((~mask).sum()),
            definition="error = truth - estimate, the truth taken at each estimate's log time "
                       "(exact ns match, else linear interpolation; estimates outside the "
                       "truth's time range are left out); 'after_settle' = samples whose time "
                       "since the observer's (re)start is >= settle_time_s")
        if mask.any():
            t_rel = (t_est_ns[mask] - t_start_ns) / 1e9
            conv_time = M.convergence_time(t_rel, np.max(np.abs(err), axis=1), tolerance)
            err_t = (t_est_ns[mask] - info.start_ns) / 1e9
            err_norm = np.sqrt(np.sum(err * err, axis=1))
        elif truth_note is None:
            truth_note = "no estimate lies within the ground truth's time range"
    ui_errors, ui_note, ui_plot = _unknown_input_errors(obs, run, t_est_ns, conv, settle)
    p50_obs, p99_obs = runner.update_time_us()
    duration_s = info.duration_ns / 1e9
    wall = run.timing["replay_total"]
    source = settings["source"]
    metrics: dict[str, Any] = {
        "schema": METRICS_SCHEMA,
        "bag": str(bag_path),
        "params_file": str(params_path),
        "node_name": fqn,
        "observer_type": obs.TYPE,
        "state_names": names,
        "source": source,
        "input_topics": {_ROLE_NAMES[k]: v for k, v in run.roles.items()},
        "output_bag": str(out_dir),
        "output_topics": dict(sorted(run.counts.items())),
        "plot": None,
        "bag_start_s": info.start_ns / 1e9,
        "bag_duration_s": duration_s,
        "sample_count": len(streams.meas[1]) if source == "topics" else len(streams.joints[1]),
        "input_count": len(streams.inputs[1]),
        "samples_accepted": runner.accepted,
        "samples_rejected": sum(runner.rejected.values()),
        "rejected_by_reason": dict(sorted(runner.rejected.items())),
        "restarts": sum(runner.resets.values()),
        "restarts_by_reason": dict(sorted(runner.resets.items())),
        "guaranteed_time_s": gt if math.isfinite(gt) else None,
        "guarantee": f"exact {gt:g} s after each (re)start" if math.isfinite(gt)
        else "none",
        "settle_time_s": settle,
        "settle_time_rule": settle_rule,
        "tolerance": float(tolerance),
        "convergence_time_s": conv_time,
        "convergence_time_definition": (
            "first time (s after the observer's first accepted sample) from which the largest "
            "absolute error over all states stays below 'tolerance' to the end of the bag; "
            "null if it never does or there is no ground truth"),
        "observer_start_s": None if t_start_ns is None else t_start_ns / 1e9,
        "truth_topic": run.truth_topic if "truth" in run.roles else None,
        "errors": errors,
        "errors_note": truth_note,
        "update_time_us": {
            **M.percentiles_us(np.asarray(run.proc_s) * 1e6),
            "definition": "wall time of each Runner.process call that produced an output "
                          "(validation + observer update + output building), over every "
                          "accepted sample of the run"},
        "observer_update_time_us": {
            "p50": p50_obs, "p99": p99_obs,
            "definition": "Runner.update_time_us(): the observer's update() alone, over the "
                          "last 2000 updates (what /diagnostics shows)"},
        "replay_speed_x_realtime": duration_s / wall if wall > 0 else None,
        "replay_speed_definition": (
            "bag duration / wall time of the whole replay: opening, reading and decoding the "
            "bag, the runner, serialising and writing the output bag and closing it "
            "(excluded: params loading, one-time library set-up such as imports and the rosbags "
            "type store, the metrics and the plot; timing_s has the parts)"),
        "timing_s": dict(run.timing),
        "reader": streams.reader,
        "serializer_fallbacks": run.fallbacks,
        "diagnostics_levels": dict(run.status_levels),
        "final_status": {"level": LEVEL_NAMES.get(run.final_status.level,
                                                  str(run.final_status.level)),
                         "message": run.final_status.message},
        "observer_diagnostics": {
            str(k): (v if isinstance(v, (int, float, str, bool)) or v is None else str(v))
            for k, v in obs.diagnostics().items()},
    }
    if ui_plot is not None or "truth_ui" in run.roles:
        # only for observers that identify an unknown input, or bags that carry its truth
        metrics.update(
            unknown_input_topic=run.truth_ui_topic if "truth_ui" in run.roles else None,
            unknown_input_errors=ui_errors, unknown_input_errors_note=ui_note)
    t0 = info.start_ns
    plot_data = dict(
        t=(t_est_ns - t0) / 1e9, estimate=x_est, state_names=names,
        truth_t=None if truth_x is None else (truth_t - t0) / 1e9, truth=truth_x,
        err_t=err_t, err_norm=err_norm, guaranteed_time=gt, settle_time=settle,
        tolerance=tolerance if truth_x is not None else None,
        t_start=0.0 if t_start_ns is None else (t_start_ns - t0) / 1e9)
    if ui_plot is not None:
        ui_t, ui_est, ui_truth_t, ui_truth, ui_names = ui_plot
        plot_data.update(ui_t=(ui_t - t0) / 1e9, ui_estimate=ui_est,
                         ui_truth_t=None if ui_truth_t is None else (ui_truth_t - t0) / 1e9,
                         ui_truth=ui_truth, ui_names=ui_names)
    return metrics, plot_data


def _truth_rows(stream, topic: str, width: int, kind: str, has: str):
    """(stamps, rows, None) of a ground-truth stream whose messages all carry ``width``
    values, or (None, None, why there are no error metrics)."""
    t, rows = stream
    lengths = {len(v) for v in rows}
    if not t.size:
        return None, None, f"no {kind}ground truth: topic {topic} has no messages"
    if lengths != {width}:
        return None, None, (f"no {kind}error metrics: {topic} carries {sorted(lengths)} value(s) "
                            f"per message, {has}")
    return t, np.asarray(rows, dtype=float), None


def _unknown_input_errors(obs, run: _Run, t_est_ns: np.ndarray, conv: np.ndarray,
                          settle: float) -> tuple[dict | None, str | None, tuple | None]:
    """(errors like 'errors' but for the unknown input, a note, plot data) of a finished run."""
    if not run.est_ui:
        note = None if type(obs).unknown_input is Observer.unknown_input else \
            "the observer published no unknown-input estimate"
        return None, note, None
    idx = np.asarray(run.est_ui_idx, dtype=np.int64)
    ui = np.vstack(run.est_ui)
    t_ui = t_est_ns[idx]
    q = ui.shape[1]
    names = list(getattr(obs, "unknown_input_names", None) or [f"zeta{j}" for j in range(q)])
    truth_t = truth_x = None
    note = run.truth_ui_note
    if "truth_ui" in run.roles:
        truth_t, truth_x, why = _truth_rows(run.streams.truth_ui, run.truth_ui_topic, q,
                                            "unknown-input ", f"the estimate has {q}")
        note = why or note
    errors = None
    if truth_x is not None:
        mask, x_at = M.match_truth(t_ui, truth_t, truth_x)
        if mask.any():
            err = x_at[mask] - ui[mask]
            settled = conv[idx[mask], 0] >= settle - 1e-9
            errors = M.error_stats(err, names, settled)
            errors.update(
                matched_samples=int(mask.sum()), settled_samples=int(settled.sum()),
                definition="error = true unknown input - unknown_input_estimate, matched and "
                           "settled as 'errors'")
        else:
            note = "no unknown-input estimate lies within its ground truth's time range"
    return errors, note, (t_ui, ui, truth_t, truth_x, names)
