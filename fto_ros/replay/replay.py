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
  ``u`` (when input joints are configured) is set before ``y`` is processed.
- Every accepted sample publishes ``state_estimate``, ``convergence``,
  ``unknown_input_estimate`` (observers that have one) and
  ``estimated_joint_states`` (when configured) under the node's name, with log
  time = sample time.  ``/diagnostics`` gets ``runner.status(t)`` every
  ``diagnostics.period`` seconds of bag time (1 s by default), plus a final one.

Speed: the bag is read with a small MCAP fast path (chunks decompressed and
scanned with ``struct``, Float64MultiArray payloads decoded in bulk with
numpy; anything unusual falls back to :class:`~fto_ros.bag.BagReader`), and
outputs are serialised from byte templates checked once against the rosbags
serialiser.  ``metrics.json`` reports the measured speed and where the time
went.
"""
from __future__ import annotations

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
from ..core.errors import ConfigError
from ..runner.messages import joint_state_sample
from ..runner.runner import CONVERGENCE_FIELDS, LEVEL_NAMES, Output, Runner
from ..runner.settings import load_params_file
from . import metrics as M

F64_ARRAY = "std_msgs/msg/Float64MultiArray"
JOINT_STATE = "sensor_msgs/msg/JointState"
DEFAULT_NODE_NAME = "observer_node"
DEFAULT_TOLERANCE = 1e-2
METRICS_SCHEMA = "fto_ros/replay-metrics/1"

# event kinds; at equal log times they are processed in this order
K_INPUT, K_MEAS, K_JOINT, K_TRUTH = 0, 1, 1, 2
_KIND_INPUT, _KIND_MEAS, _KIND_JOINT, _KIND_TRUTH = 0, 1, 2, 3


_ROLE_NAMES = {"meas": "measured_output", "inputs": "input", "joints": "joint_states",
               "truth": "true_state"}


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
#: the fast path reads whole files into memory; larger bags stream through BagReader
FAST_PATH_MAX_BYTES = 1 << 30


class _NotFast(Exception):
    """The fast MCAP path cannot read this bag; use BagReader."""


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
        t = np.asarray(times, dtype=np.int64)
        if t.size > 1 and np.any(np.diff(t) < 0):
            order = np.argsort(t, kind="stable")
            t = t[order]
            payloads = [payloads[i] for i in order.tolist()]
        out[topic] = (t, payloads)
    return out


# --------------------------------------------------------------------------------------
# CDR: decoding Float64MultiArray, encoding outputs
# --------------------------------------------------------------------------------------
_CDR_LE = b"\x00\x01\x00\x00"


def _f64_prefix(n: int) -> bytes:
    """CDR bytes of a Float64MultiArray (empty layout) up to its first double."""
    return _CDR_LE + struct.pack("<III", 0, 0, n) + (b"\x00" * 4 if n else b"")


def decode_float_arrays(payloads: list, typestore) -> list:
    """The ``data`` of raw CDR Float64MultiArray payloads, as lists of floats.

    Bulk numpy decoding when every payload has the same length and an empty
    layout (the usual case); per message otherwise, with the rosbags
    deserialiser for anything but little-endian CDR with an empty layout.
    """
    if not payloads:
        return []
    lengths = {len(p) for p in payloads}
    if len(lengths) == 1:
        length = lengths.pop()
        if length >= 16:
            raw = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(len(payloads), length)
            head = raw[:, :16].copy().view("<u4")  # header, dims, data_offset, count
            count = int(head[0, 3])
            expected = 20 + 8 * count if count else 16
            if (np.all(raw[:, :4] == np.frombuffer(_CDR_LE, np.uint8)) and not np.any(head[:, 1])
                    and np.all(head[:, 3] == count) and length in (expected, expected + 4)):
                if count == 0:
                    return [[] for _ in payloads]
                return raw[:, 20:20 + 8 * count].copy().view("<f8").tolist()
    out = []
    for p in payloads:
        if len(p) >= 16 and bytes(p[:4]) == _CDR_LE and not _U32.unpack_from(p, 4)[0]:
            (count,) = _U32.unpack_from(p, 12)
            if count == 0:
                out.append([])
                continue
            if len(p) >= 20 + 8 * count:
                out.append(list(struct.unpack_from(f"<{count}d", p, 20)))
                continue
        out.append(typestore.deserialize_cdr(bytes(p), F64_ARRAY).data.tolist())
    return out


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
        self._JS = T[JOINT_STATE]
        self._Header = T["std_msgs/msg/Header"]
        self._Time = T["builtin_interfaces/msg/Time"]
        self._f64: dict[int, Callable[[np.ndarray], bytes]] = {}
        self._js: dict[tuple, Callable] = {}
        self.fallbacks: list[str] = []

    def _rosbags_f64(self, x: np.ndarray) -> bytes:
        msg = self._F64(layout=self._Layout(dim=[], data_offset=0),
                        data=np.ascontiguousarray(x, dtype=np.float64))
        return bytes(self.ts.serialize_cdr(msg, F64_ARRAY))

    def float_array(self, n: int) -> Callable[[np.ndarray], bytes]:
        """``x (float64, length n) -> CDR bytes``."""
        enc = self._f64.get(n)
        if enc is None:
            prefix = _f64_prefix(n)

            def enc(x, _p=prefix):
                return _p + x.tobytes()

            probe = np.arange(n, dtype=np.float64) * 1.25 - 0.5
            if enc(probe) != self._rosbags_f64(probe):
                self.fallbacks.append(f"Float64MultiArray[{n}]")
                enc = self._rosbags_f64
            self._f64[n] = enc
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
class _Sink:
    """Raw (already serialised) writes into a BagWriter, plus message counts."""

    def __init__(self, bag: BagWriter):
        self.bag = bag
        self.counts: dict[str, int] = {}

    def channel(self, topic: str, msgtype: str) -> Callable[[int, bytes], None]:
        """A ``write(t_ns, cdr_bytes)`` function for ``topic``."""
        bag = self.bag
        self.counts.setdefault(topic, 0)
        counts = self.counts
        raw = getattr(bag, "raw_writer", None)
        if raw is not None:  # public API, if the bag layer offers it
            write = raw(topic, msgtype)
        else:
            conn = bag._connection(topic, msgtype)
            wr = bag._writer.write

            def write(t_ns, data, _c=conn, _w=wr):
                _w(_c, t_ns, data)

        def counted(t_ns, data, _w=write, _t=topic):
            _w(t_ns, data)
            counts[_t] += 1

        return counted


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
        if not self.enabled:
            return
        wall = time.perf_counter() - self.start
        if wall < self.delay:
            return
        frac = min(max((t_ns - self.t0) / self.span, 0.0), 1.0)
        fill = int(frac * self.WIDTH)
        sys.stderr.write(f"\rreplay [{'#' * fill}{'.' * (self.WIDTH - fill)}] {frac * 100:5.1f}% "
                         f"{(t_ns - self.t0) / 1e9:8.2f} / {self.span / 1e9:.2f} s bag time")
        sys.stderr.flush()
        self.drawn = True

    def done(self) -> None:
        if self.drawn:
            self.update(self.t0 + self.span)
            sys.stderr.write("\n")
            sys.stderr.flush()


# --------------------------------------------------------------------------------------
# the replay
# --------------------------------------------------------------------------------------
@dataclass
class _Streams:
    """The messages of one replay, grouped by role, with log times (ns)."""

    inputs: tuple[np.ndarray, list] = field(default_factory=lambda: (np.zeros(0, np.int64), []))
    meas: tuple[np.ndarray, list] = field(default_factory=lambda: (np.zeros(0, np.int64), []))
    joints: tuple[np.ndarray, list] = field(default_factory=lambda: (np.zeros(0, np.int64), []))
    truth: tuple[np.ndarray, list] = field(default_factory=lambda: (np.zeros(0, np.int64), []))
    truth_copy: list = field(default_factory=list)   # raw bytes (fast path) or messages
    truth_raw: bool = True
    reader: str = ""


def _read_streams(bag_path: Path, reader: BagReader, roles: dict[str, str],
                  typestore) -> _Streams:
    """Read and decode the role topics (role -> topic name) of the bag."""
    topics = sorted(set(roles.values()))
    s = _Streams()
    try:
        raw = _read_fast(bag_path, topics)
        s.reader = "mcap fast path"
    except _NotFast as why:
        raw = None
        s.reader = f"rosbags BagReader ({why})"
    if raw is not None:
        for role, topic in roles.items():
            t, payloads = raw[topic]
            if role == "joints":
                msgs = [typestore.deserialize_cdr(bytes(p), JOINT_STATE) for p in payloads]
                s.joints = (t, msgs)
            else:
                values = decode_float_arrays(payloads, typestore)
                setattr(s, role, (t, values))
                if role == "truth":
                    s.truth_copy = payloads
        return s
    # fallback: rosbags deserialisation of every message
    lists: dict[str, tuple[list, list]] = {topic: ([], []) for topic in topics}
    for topic, t_ns, msg in reader.messages(topics):
        lists[topic][0].append(t_ns)
        lists[topic][1].append(msg)
    for role, topic in roles.items():
        t = np.asarray(lists[topic][0], dtype=np.int64)
        msgs = lists[topic][1]
        if role == "joints":
            s.joints = (t, msgs)
        else:
            setattr(s, role, (t, [np.asarray(m.data, dtype=float).tolist() for m in msgs]))
            if role == "truth":
                s.truth_copy, s.truth_raw = msgs, False
    return s


def _check_topic(topics: dict, topic: str, msgtype: str, what: str, bag_path: Path) -> None:
    if topic not in topics:
        listing = ", ".join(f"{k} ({v.msgtype})" for k, v in topics.items()) or "none"
        raise ReplayError(f"{bag_path}: the bag has no {what} topic {topic!r} "
                          f"(set by the params file); the bag's topics: {listing}")
    if topics[topic].msgtype != msgtype:
        raise ReplayError(f"{bag_path}: topic {topic} has type {topics[topic].msgtype}, "
                          f"the {what} must be {msgtype}")


def replay(bag_path, params_path, out_dir, *, node_name: str | None = None,
           overwrite: bool = False, progress: bool = True, after: float | None = None,
           tolerance: float = DEFAULT_TOLERANCE, plot: bool = True) -> dict[str, Any]:
    """Replay ``bag_path`` through the observer of ``params_path``; write ``out_dir``.

    Args:
        bag_path: rosbag2 bag (directory or .mcap file).
        params_path: ROS 2 params file; the block of ``node_name`` (or ``/**``,
            or the only block) is used.
        out_dir: output bag directory; also receives ``metrics.json`` and
            ``replay.png``.  Must not exist unless ``overwrite``.
        node_name: node name for the params block and the output topic
            namespace (default ``observer_node``).
        progress: draw a progress bar on stderr (only on a terminal, and only
            when the replay takes more than half a second).
        after: settle time (s after the observer's (re)start) for the
            "after settling" errors; default guaranteed_time + 0.01 s, or
            0.11 s for observers without a guarantee.
        tolerance: error bound (state units) for the measured convergence time.
        plot: write ``replay.png``.

    Returns the metrics (also written to ``metrics.json``).
    Raises ConfigError (params), BagError (bags), ReplayError (anything else
    that stops the replay), each with a one-line message.
    """
    if not (isinstance(tolerance, (int, float)) and math.isfinite(tolerance) and tolerance > 0):
        raise ReplayError(f"tolerance must be a positive number, got {tolerance!r}")
    if after is not None and not (math.isfinite(after) and after >= 0):
        raise ReplayError(f"after must be a finite number >= 0, got {after!r}")
    bag_path, params_path, out_dir = Path(bag_path), Path(params_path), Path(out_dir)
    fqn = node_fqn(node_name)
    flat = load_params_file(params_path, node_name)
    runner = Runner(flat)
    settings, obs = runner.settings, runner.observer
    if out_dir.exists() and not overwrite:
        raise BagError(f"{out_dir}: output exists already (remove it or pass --overwrite)")

    # ---- read --------------------------------------------------------------------------
    wall0 = time.perf_counter()
    with BagReader(bag_path) as reader:
        info = reader.info()
        topics = info.topics
        roles: dict[str, str] = {}
        source = settings["source"]
        if source == "topics":
            roles["meas"] = resolve_topic(settings["topics.measured_output"], fqn)
            _check_topic(topics, roles["meas"], F64_ARRAY, "measured_output", bag_path)
            if obs.n_inputs:
                roles["inputs"] = resolve_topic(settings["topics.input"], fqn)
                _check_topic(topics, roles["inputs"], F64_ARRAY,
                             f"input (the observer has {obs.n_inputs} known input(s))", bag_path)
        else:
            roles["joints"] = resolve_topic(settings["topics.joint_states"], fqn)
            _check_topic(topics, roles["joints"], JOINT_STATE, "joint_states", bag_path)
        truth_topic = resolve_topic(settings["topics.true_state"], fqn)
        truth_note = None
        if truth_topic not in topics:
            truth_note = f"no ground truth: the bag has no topic {truth_topic}"
        elif topics[truth_topic].msgtype != F64_ARRAY:
            truth_note = (f"no ground truth: {truth_topic} is {topics[truth_topic].msgtype}, "
                          f"not {F64_ARRAY}")
        else:
            roles["truth"] = truth_topic
        typestore = reader._typestore if hasattr(reader, "_typestore") else None
        if typestore is None:
            from ..bag.reader import jazzy_typestore
            typestore = jazzy_typestore()
        streams = _read_streams(bag_path, reader, roles, typestore)
    wall_read = time.perf_counter()

    # ---- order the events ----------------------------------------------------------------
    parts = [(streams.inputs[0], K_INPUT, _KIND_INPUT), (streams.meas[0], K_MEAS, _KIND_MEAS),
             (streams.joints[0], K_JOINT, _KIND_JOINT), (streams.truth[0], K_TRUTH, _KIND_TRUTH)]
    t_all = np.concatenate([p[0] for p in parts])
    prio_all = np.concatenate([np.full(p[0].size, p[1], np.int8) for p in parts])
    kind_all = np.concatenate([np.full(p[0].size, p[2], np.int8) for p in parts])
    idx_all = np.concatenate([np.arange(p[0].size) for p in parts])
    order = np.lexsort((prio_all, t_all))
    ev_t = t_all[order].tolist()
    ev_kind = kind_all[order].tolist()
    ev_idx = idx_all[order].tolist()
    wall_sort = time.perf_counter()

    # ---- run -----------------------------------------------------------------------------
    enc = _Encoders(typestore)
    period_ns = max(int(round(settings["diagnostics.period"] * 1e9)), 1)
    diag_name = f"{fqn.lstrip('/')}: state observer"
    hw_id = settings["diagnostics.hardware_id"]
    status_levels: dict[str, int] = {}
    proc_us: list[float] = []
    est_t: list[int] = []
    est_x: list[np.ndarray] = []
    est_conv: list[np.ndarray] = []
    runner_s = 0.0
    final_status = None
    n_events = len(ev_t)
    t_first = ev_t[0] if n_events else info.start_ns
    t_last = ev_t[-1] if n_events else info.end_ns
    out_topics = {name: f"{fqn}/{name}" for name in
                  ("state_estimate", "convergence", "unknown_input_estimate",
                   "estimated_joint_states")}
    bar = _Progress(progress, t_first, t_last)
    custom = {"fto_ros.replay.source_bag": str(bag_path),
              "fto_ros.replay.params_file": str(params_path),
              "fto_ros.replay.observer_type": obs.TYPE}
    wall_loop0 = time.perf_counter()
    with BagWriter(out_dir, overwrite=overwrite, custom_data=custom) as bag:
        sink = _Sink(bag)
        w_est = sink.channel(out_topics["state_estimate"], F64_ARRAY)
        w_conv = sink.channel(out_topics["convergence"], F64_ARRAY)
        w_ui = w_js = None
        enc_est = enc.float_array(obs.n_states)
        enc_conv = enc.float_array(len(CONVERGENCE_FIELDS))
        enc_js = None
        if "truth" in roles:
            if streams.truth_raw:
                w_truth = sink.channel(truth_topic, F64_ARRAY)
            else:
                def w_truth(t_ns, msg, _topic=truth_topic):
                    bag.write_message(_topic, t_ns, msg)
                    sink.counts[_topic] = sink.counts.get(_topic, 0) + 1
            truth_copy = streams.truth_copy
        inputs, meas, joints = streams.inputs[1], streams.meas[1], streams.joints[1]
        set_input, process = runner.set_input, runner.process
        perf = time.perf_counter
        next_diag = t_first + period_ns

        def diagnostics(t_ns: int):
            st = runner.status(t_ns / 1e9)
            bag.diagnostics("/diagnostics", t_ns, [{
                "level": st.level, "name": diag_name, "message": st.message,
                "hardware_id": hw_id, "values": st.values}])
            sink.counts["/diagnostics"] = sink.counts.get("/diagnostics", 0) + 1
            name = LEVEL_NAMES.get(st.level, str(st.level))
            status_levels[name] = status_levels.get(name, 0) + 1
            return st

        def publish(t_ns: int, out: Output) -> None:
            nonlocal w_ui, w_js, enc_js
            est_t.append(t_ns)
            est_x.append(out.estimate)
            est_conv.append(out.convergence)
            w_est(t_ns, enc_est(out.estimate))
            w_conv(t_ns, enc_conv(out.convergence))
            ui = out.unknown_input
            if ui is not None:
                if w_ui is None:
                    w_ui = sink.channel(out_topics["unknown_input_estimate"], F64_ARRAY)
                w_ui(t_ns, enc.float_array(ui.size)(ui))
            js = out.joint_state
            if js is not None:
                names, pos, vel, eff = js
                if w_js is None:
                    w_js = sink.channel(out_topics["estimated_joint_states"], JOINT_STATE)
                enc_j = enc_js if enc_js is not None else enc.joint_state(
                    names, (len(pos), len(vel), len(eff)))
                if enc_js is None:
                    enc_js = enc_j
                w_js(t_ns, enc_j(t_ns // 1_000_000_000, t_ns % 1_000_000_000, pos, vel, eff))

        for t_ns, kind, i in zip(ev_t, ev_kind, ev_idx):
            if t_ns >= next_diag:
                while t_ns >= next_diag:
                    diagnostics(next_diag)
                    next_diag += period_ns
                bar.update(t_ns)
            if kind == _KIND_MEAS:
                c0 = perf()
                out = process(t_ns / 1e9, meas[i])
                c1 = perf()
                runner_s += c1 - c0
                if out.__class__ is not str:
                    proc_us.append(c1 - c0)
                    publish(t_ns, out)
            elif kind == _KIND_INPUT:
                c0 = perf()
                set_input(t_ns / 1e9, inputs[i])
                runner_s += perf() - c0
            elif kind == _KIND_TRUTH:
                w_truth(t_ns, truth_copy[i])
            else:  # JointState source
                c0 = perf()
                sample = joint_state_sample(joints[i], settings)
                if sample.__class__ is str:
                    runner._reject(sample)  # TODO(lead): public Runner API for this
                    runner_s += perf() - c0
                    continue
                t, y, u = sample
                if u is not None:
                    set_input(t, u)
                c1 = perf()
                out = process(t, y)
                c2 = perf()
                runner_s += c2 - c0
                if out.__class__ is not str:
                    proc_us.append(c2 - c1)
                    stamp = joints[i].header.stamp
                    publish(stamp.sec * 1_000_000_000 + stamp.nanosec, out)
        final_status = diagnostics(t_last)
        bar.done()
        wall_loop1 = time.perf_counter()
    wall_end = time.perf_counter()

    # ---- metrics -------------------------------------------------------------------------
    m0 = time.perf_counter()
    names = list(obs.state_names)
    n = obs.n_states
    t_est_ns = np.asarray(est_t, dtype=np.int64)
    x_est = np.vstack(est_x) if est_x else np.zeros((0, n))
    conv = np.vstack(est_conv) if est_conv else np.zeros((0, len(CONVERGENCE_FIELDS)))
    gt = float(obs.guaranteed_time)
    if after is None:
        settle, settle_rule = M.default_settle_time(gt)
    else:
        settle, settle_rule = float(after), "given (--after)"
    t_start_ns = int(t_est_ns[0]) if t_est_ns.size else None

    errors = None
    conv_time = None
    err_t = err_norm = None
    truth_t = truth_x = None
    if "truth" in roles:
        truth_t = streams.truth[0]
        lengths = {len(v) for v in streams.truth[1]}
        if not truth_t.size:
            truth_note = f"no ground truth: topic {truth_topic} has no messages"
        elif lengths != {n}:
            truth_note = (f"no error metrics: {truth_topic} carries {sorted(lengths)} values per "
                          f"message, the observer has {n} states")
        else:
            truth_x = np.asarray(streams.truth[1], dtype=float)
    if truth_x is not None:
        mask, x_at = M.match_truth(t_est_ns, truth_t, truth_x)
        err = x_at[mask] - x_est[mask]
        settled = conv[mask, 0] >= settle
        errors = M.error_stats(err, names, settled)
        errors["matched_samples"] = int(mask.sum())
        errors["settled_samples"] = int(settled.sum())
        errors["unmatched_samples"] = int((~mask).sum())
        errors["definition"] = ("error = truth - estimate, truth at each estimate's log time "
                                "(exact ns match, else linear interpolation; estimates outside "
                                "the truth's time range left out); 'after_settle' = samples "
                                "whose time since the observer's (re)start >= settle_time_s")
        if t_start_ns is not None:
            t_rel = (t_est_ns[mask] - t_start_ns) / 1e9
            conv_time = M.convergence_time(t_rel, np.max(np.abs(err), axis=1) if err.size
                                           else np.zeros(0), tolerance)
            err_t = (t_est_ns[mask] - info.start_ns) / 1e9
            err_norm = np.sqrt(np.sum(err * err, axis=1))
        if truth_note is None and not mask.any():
            truth_note = "no estimate lies within the ground truth's time range"
    p50_obs, p99_obs = runner.update_time_us()
    duration_s = info.duration_ns / 1e9
    replay_wall = wall_end - wall0
    rejected = dict(sorted(runner.rejected.items()))
    metrics: dict[str, Any] = {
        "schema": METRICS_SCHEMA,
        "bag": str(bag_path),
        "params_file": str(params_path),
        "node_name": fqn,
        "observer_type": obs.TYPE,
        "state_names": names,
        "source": settings["source"],
        "input_topics": {_ROLE_NAMES[k]: v for k, v in roles.items()},
        "output_bag": str(out_dir),
        "output_topics": dict(sorted(sink.counts.items())),
        "plot": "replay.png" if plot else None,
        "bag_start_s": info.start_ns / 1e9,
        "bag_duration_s": duration_s,
        "sample_count": len(meas) if settings["source"] == "topics" else len(joints),
        "input_count": len(inputs),
        "samples_accepted": runner.accepted,
        "samples_rejected": sum(runner.rejected.values()),
        "rejected_by_reason": rejected,
        "restarts": sum(runner.resets.values()),
        "restarts_by_reason": dict(sorted(runner.resets.items())),
        "guaranteed_time_s": gt if math.isfinite(gt) else None,
        "guarantee": f"exact after {gt:g} s" if math.isfinite(gt) else "none (asymptotic)",
        "settle_time_s": settle,
        "settle_time_rule": settle_rule,
        "tolerance": float(tolerance),
        "convergence_time_s": conv_time,
        "convergence_time_definition": (
            "first time (s after the observer's first accepted sample) from which the largest "
            "absolute error over all states stays below 'tolerance' to the end of the bag; "
            "null if it never does or there is no ground truth"),
        "observer_start_s": None if t_start_ns is None else t_start_ns / 1e9,
        "truth_topic": truth_topic if "truth" in roles else None,
        "errors": errors,
        "errors_note": truth_note,
        "update_time_us": {**M.percentiles_us(np.asarray(proc_us) * 1e6),
                           "definition": "wall time of each Runner.process call that produced "
                                         "an output (validation + observer update + output "
                                         "building), every accepted sample of the run"},
        "observer_update_time_us": {
            "p50": p50_obs, "p99": p99_obs,
            "definition": "Runner.update_time_us(): the observer's update() alone, over the "
                          "last 2000 updates (what /diagnostics shows)"},
        "replay_speed_x_realtime": (duration_s / replay_wall) if replay_wall > 0 else None,
        "replay_speed_definition": ("bag duration / wall time of the whole replay: opening and "
                                    "reading the bag, decoding, the runner, serialising and "
                                    "writing the output bag, closing it (metrics.json and the "
                                    "plot are not included)"),
        "timing_s": {
            "read_decode": wall_read - wall0,
            "order_events": wall_sort - wall_read,
            "runner": runner_s,
            "serialize_write": (wall_loop1 - wall_loop0) - runner_s,
            "close_output": wall_end - wall_loop1,
            "replay_total": replay_wall,
        },
        "reader": streams.reader,
        "template_fallbacks": enc.fallbacks,
        "diagnostics_messages": status_levels,
        "final_status": {"level": LEVEL_NAMES.get(final_status.level, str(final_status.level)),
                         "message": final_status.message},
        "observer_diagnostics": {str(k): (v if isinstance(v, (int, float, str, bool)) else str(v))
                                 for k, v in obs.diagnostics().items()},
    }
    metrics["timing_s"]["metrics"] = time.perf_counter() - m0

    if plot:
        p0 = time.perf_counter()
        from .plot import plot_replay
        t0 = info.start_ns
        truth_rel = None if truth_x is None else (truth_t - t0) / 1e9
        plot_replay(out_dir / "replay.png", t=(t_est_ns - t0) / 1e9, estimate=x_est,
                    state_names=names, truth_t=truth_rel, truth=truth_x, err_t=err_t,
                    err_norm=err_norm, guaranteed_time=gt, settle_time=settle,
                    tolerance=tolerance if truth_x is not None else None,
                    t_start=0.0 if t_start_ns is None else (t_start_ns - t0) / 1e9,
                    title=f"{obs.TYPE} on {bag_path.name}")
        metrics["timing_s"]["plot"] = time.perf_counter() - p0
    (out_dir / "metrics.json").write_text(
        json.dumps(M.json_safe(metrics), indent=2, allow_nan=False) + "\n")
    return metrics
