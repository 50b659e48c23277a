"""CDR (XCDR1, little endian) bytes of the messages the replay reads and writes, without
building rosbags message objects per sample: Float64MultiArray payloads decoded in bulk
with numpy, outputs encoded from byte templates.  Every template is checked once
against rosbags' own serialiser; one that does not reproduce it byte for byte is not
used (that message type then goes through rosbags, listed in ``fallbacks``).
"""
from __future__ import annotations

import struct
from typing import Any, Callable

import numpy as np

from ..core.errors import DecodeError, short
from .reader import BagError
from .writer import FLOAT64_MULTI_ARRAY as F64_ARRAY, JOINT_STATE

_U32 = struct.Struct("<I")
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


def f64_prefix(n: int, labels=None) -> bytes:
    """CDR bytes of a Float64MultiArray of n values up to its first double.

    ``labels`` None: an empty layout; else one dimension per element, ``(label, 1, 1)``
    (what the node publishes: each element named).
    """
    c = _Cdr()
    labels = list(labels or ())
    c.u32(len(labels))
    for label in labels:
        c.string(label)
        c.u32(1)
        c.u32(1)
    c.u32(0)  # data_offset
    c.u32(n)
    if n:
        c.align(8)
    return bytes(c.buf)


def _f64_data_at(p) -> tuple[int, int]:
    """(offset of the first double, count) of a little-endian CDR Float64MultiArray."""
    if bytes(p[:4]) != _CDR_LE:
        raise DecodeError("not little-endian CDR")
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
        raise DecodeError("truncated")
    return pos, count


def decode_float_block(payloads) -> np.ndarray | None:
    """The ``data`` of raw CDR Float64MultiArray payloads as one ``(N, n)`` float64 array,
    when they all have the same length and the same bytes before their data (one
    publisher, a fixed layout: the usual case, decoded with no Python per message); None
    otherwise.  ``payloads``: a :class:`~fto_ros.bag.mcap_scan.Payloads` or a list of bytes."""
    matrix = getattr(payloads, "matrix", None)
    if matrix is None:
        if not payloads or len({len(p) for p in payloads}) != 1:
            return None
        matrix = np.frombuffer(b"".join(payloads), np.uint8).reshape(len(payloads), -1)
    if not len(matrix):
        return None
    try:
        off, count = _f64_data_at(matrix[0])
    except (ValueError, struct.error):
        return None
    if not np.array_equal(matrix[:, :off], np.broadcast_to(matrix[0, :off], (len(matrix), off))):
        return None
    return matrix[:, off:off + 8 * count].copy().view("<f8")


def decode_float_arrays(payloads, typestore, where: str = "Float64MultiArray") -> list:
    """The ``data`` of raw CDR Float64MultiArray payloads, as lists of floats.

    In bulk (:func:`decode_float_block`) when every payload has the same length and the
    same bytes before its data; per message otherwise, with the rosbags deserialiser for
    anything unusual (big-endian CDR).  A payload nothing can decode raises BagError
    naming ``where`` (the bag and the topic) and the message.
    """
    if not len(payloads):
        return []
    block = decode_float_block(payloads)
    if block is not None:
        return block.tolist()
    out = []
    for k, p in enumerate(payloads):
        try:
            off, count = _f64_data_at(p)
            out.append(list(struct.unpack_from(f"<{count}d", p, off)))
        except (ValueError, struct.error):
            out.append(deserialize(typestore, p, F64_ARRAY, where, k).data.tolist())
    return out


def deserialize(typestore, payload, msgtype: str, where: str, k: int):
    """One raw CDR message, or BagError naming where it is."""
    try:
        return typestore.deserialize_cdr(bytes(payload), msgtype)
    except Exception as exc:  # rosbags raises SerdeError, struct.error, IndexError ...
        raise BagError(f"{where}: cannot decode message {k} as {msgtype}: "
                       f"{type(exc).__name__}: {short(exc)}") from None


class Encoders:
    """Byte-template serialisers of the published messages, a block of K messages at once
    (the CDR of a fixed-layout message is a fixed template with a few fields changing:
    the K messages are one (K, L) uint8 array), each checked once against rosbags.

    A template that does not reproduce ``typestore.serialize_cdr`` byte for byte is not
    used: that message type then goes through rosbags (listed in ``fallbacks``), and its
    block encoder returns a list of bytes instead of a matrix.
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
        self._f64: dict[tuple, Callable] = {}
        self._js: dict[tuple, Callable] = {}
        self.fallbacks: list[str] = []

    def _rosbags_f64(self, x: np.ndarray, labels) -> bytes:
        dims = [self._Dim(label=label, size=1, stride=1) for label in labels or ()]
        msg = self._F64(layout=self._Layout(dim=dims, data_offset=0),
                        data=np.ascontiguousarray(x, dtype=np.float64))
        return bytes(self.ts.serialize_cdr(msg, F64_ARRAY))

    def float_block(self, n: int, labels=None) -> Callable[[np.ndarray], Any]:
        """``X (K, n) -> the K messages' CDR`` ((K, L) uint8; layout: :func:`f64_prefix`)."""
        labels = tuple(labels) if labels else None
        key = (n, labels)
        enc = self._f64.get(key)
        if enc is None:
            prefix = np.frombuffer(f64_prefix(n, labels), np.uint8)
            p = prefix.size

            def enc(x, _prefix=prefix, _p=p):
                x = np.ascontiguousarray(x, dtype="<f8")
                x = x.reshape(len(x), n)
                out = np.empty((len(x), _p + 8 * n), np.uint8)
                out[:, :_p] = _prefix
                out[:, _p:] = x.view(np.uint8)
                return out
            probe = np.arange(n, dtype=np.float64) * 1.25 - 0.5
            if enc(probe[None]).tobytes() != self._rosbags_f64(probe, labels):
                self.fallbacks.append(f"Float64MultiArray[{n}]")

                def enc(x, _labels=labels):
                    x = np.asarray(x, dtype=np.float64)
                    return [self._rosbags_f64(row, _labels) for row in x.reshape(len(x), n)]
            self._f64[key] = enc
        return enc

    def float_array(self, n: int, labels=None) -> Callable[[Any], bytes]:
        """``x (length n) -> CDR bytes`` of one message (see :meth:`float_block`)."""
        block = self.float_block(n, labels)

        def enc(x):
            out = block(np.asarray(x, dtype=np.float64)[None])
            return out[0] if isinstance(out, list) else out.tobytes()
        return enc

    def _rosbags_js(self, names, sec, nsec, pos, vel, eff, frame_id: str = "") -> bytes:
        msg = self._JS(header=self._Header(stamp=self._Time(sec=sec, nanosec=nsec), frame_id=frame_id),
                       name=list(names), position=np.asarray(pos, dtype=np.float64),
                       velocity=np.asarray(vel, dtype=np.float64),
                       effort=np.asarray(eff, dtype=np.float64))
        return bytes(self.ts.serialize_cdr(msg, JOINT_STATE))

    def joint_state_block(self, names: list[str], sizes: tuple[int, int, int],
                          frame_id: str = "") -> Callable:
        """``(sec (K,), nanosec (K,), position (K, a), velocity (K, b), effort (K, c)) ->
        the K messages' CDR`` for fixed names and sizes (a, b, c)."""
        key = (tuple(names), tuple(sizes), frame_id)
        enc = self._js.get(key)
        if enc is not None:
            return enc
        template, at = _joint_state_template(names, sizes, frame_id)

        def enc(sec, nsec, pos, vel, eff, _t=template, _at=at):
            sec = np.asarray(sec, dtype="<i4").reshape(-1)
            out = np.empty((sec.size, _t.size), np.uint8)
            out[:] = _t
            out[:, 4:8] = sec.view(np.uint8).reshape(-1, 4)
            out[:, 8:12] = np.asarray(nsec, dtype="<u4").reshape(-1).view(np.uint8).reshape(-1, 4)
            for off, k, vals in zip(_at, sizes, (pos, vel, eff)):
                if k:
                    v = np.ascontiguousarray(vals, dtype="<f8").reshape(-1, k)
                    out[:, off:off + 8 * k] = v.view(np.uint8)
            return out

        probe = [[0.5 + i + 10 * f for i in range(k)] for f, k in enumerate(sizes)]
        ref = self._rosbags_js(names, 12, 345, *probe, frame_id=frame_id)
        if enc([12], [345], *([p] for p in probe)).tobytes() != ref:
            self.fallbacks.append(f"JointState{tuple(sizes)}")

            def enc(sec, nsec, pos, vel, eff, _n=list(names), _f=frame_id):
                sec = np.asarray(sec).reshape(-1)
                rows = zip(sec.tolist(), np.asarray(nsec).reshape(-1).tolist(),
                           *(np.asarray(v, dtype=float).reshape(sec.size, k)
                             for v, k in zip((pos, vel, eff), sizes)))
                return [self._rosbags_js(_n, s_, n_, p_, v_, e_, frame_id=_f)
                        for s_, n_, p_, v_, e_ in rows]
        self._js[key] = enc
        return enc

    def joint_state(self, names: list[str], sizes: tuple[int, int, int],
                    frame_id: str = "") -> Callable:
        """``(sec, nanosec, position, velocity, effort) -> CDR bytes`` of one message."""
        block = self.joint_state_block(names, sizes, frame_id)

        def enc(sec, nsec, pos, vel, eff):
            out = block([sec], [nsec], [pos], [vel], [eff])
            return out[0] if isinstance(out, list) else out.tobytes()
        return enc


def _joint_state_template(names, sizes, frame_id: str) -> tuple[np.ndarray, list[int]]:
    """(the CDR of a JointState with stamp 0 and zeros, offset of each array's first double)
    for fixed names and array sizes (XCDR1 little endian; the stamp is at bytes 4-12)."""
    c = _Cdr()
    c.buf += b"\x00" * 8                     # stamp: sec (int32), nanosec (uint32)
    c.string(frame_id)
    c.u32(len(names))
    for nm in names:
        c.string(nm)
    at = []
    for k in sizes:
        c.u32(k)
        if k:
            c.align(8)
        at.append(len(c.buf))
        c.buf += b"\x00" * (8 * k)
    return np.frombuffer(bytes(c.buf), np.uint8), at


class _Stamp:
    __slots__ = ("sec", "nanosec")

    def __init__(self, sec: int, nanosec: int):
        self.sec, self.nanosec = sec, nanosec


class _Header:
    __slots__ = ("stamp", "frame_id")

    def __init__(self, stamp: _Stamp, frame_id: str):
        self.stamp, self.frame_id = stamp, frame_id


class JointStateView:
    """A decoded JointState with the attributes of rosbags' (and rclpy's) message:
    ``header.stamp.sec/nanosec``, ``header.frame_id``, ``name``, and the float64 arrays
    ``position``, ``velocity``, ``effort`` (numpy, as rosbags gives them)."""

    __slots__ = ("header", "name", "position", "velocity", "effort")

    def __init__(self, header, name, position, velocity, effort):
        self.header, self.name = header, name
        self.position, self.velocity, self.effort = position, velocity, effort


def _joint_state_layout(row: bytes) -> tuple[list[str], tuple[int, int, int], str]:
    """(names, array sizes, frame_id) of one little-endian CDR JointState, or ValueError."""
    if row[:4] != _CDR_LE:
        raise DecodeError("not little-endian CDR")
    pos = 12

    def string() -> str:
        nonlocal pos
        pos += (4 - pos) % 4
        (n,) = _U32.unpack_from(row, pos)
        if n < 1 or row[pos + 4 + n - 1] != 0:
            raise DecodeError("bad string")
        text = row[pos + 4:pos + 3 + n].decode()
        pos += 4 + n
        return text

    frame = string()
    pos += (4 - pos) % 4
    (count,) = _U32.unpack_from(row, pos)
    pos += 4
    if count > len(row):
        raise DecodeError("bad name count")
    names = [string() for _ in range(count)]
    sizes = []
    for _ in range(3):
        pos += (4 - pos) % 4
        (k,) = _U32.unpack_from(row, pos)
        pos += 4
        if k:
            pos += (4 - pos) % 8
        pos += 8 * k
        sizes.append(k)
    if pos != len(row):
        raise DecodeError("length mismatch")
    return names, tuple(sizes), frame


def decode_joint_states(payloads) -> list[JointStateView] | None:
    """Raw CDR JointState payloads of one fixed layout (same length, names, frame and array
    sizes: one publisher) decoded at once with numpy; None for anything else (the caller
    then deserialises them one by one with rosbags)."""
    matrix = getattr(payloads, "matrix", None)
    if matrix is None or not len(matrix):
        return None
    try:
        names, sizes, frame = _joint_state_layout(matrix[0].tobytes())
    except (ValueError, struct.error, UnicodeDecodeError):
        return None
    template, at = _joint_state_template(names, sizes, frame)
    if template.size != matrix.shape[1]:
        return None
    fixed = np.ones(template.size, bool)
    fixed[4:12] = False
    for off, k in zip(at, sizes):
        fixed[off:off + 8 * k] = False
    if not np.array_equal(matrix[:, fixed], np.broadcast_to(template[fixed],
                                                            (len(matrix), int(fixed.sum())))):
        return None
    sec = matrix[:, 4:8].copy().view("<i4").ravel().tolist()
    nsec = matrix[:, 8:12].copy().view("<u4").ravel().tolist()
    arrays = [matrix[:, off:off + 8 * k].copy().view("<f8") for off, k in zip(at, sizes)]
    empty = np.zeros(0)
    cols = [a if k else [empty] * len(matrix) for a, k in zip(arrays, sizes)]
    return [JointStateView(_Header(_Stamp(s, n), frame), names, p, v, e)
            for s, n, p, v, e in zip(sec, nsec, *cols)]
