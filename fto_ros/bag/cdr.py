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

from ..core.errors import short
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

    def _rosbags_f64(self, x: np.ndarray, labels) -> bytes:
        dims = [self._Dim(label=label, size=1, stride=1) for label in labels or ()]
        msg = self._F64(layout=self._Layout(dim=dims, data_offset=0),
                        data=np.ascontiguousarray(x, dtype=np.float64))
        return bytes(self.ts.serialize_cdr(msg, F64_ARRAY))

    def float_array(self, n: int, labels=None,
                    values: str = "array") -> Callable[[Any], bytes]:
        """``x (length n) -> CDR bytes`` (layout: see :func:`f64_prefix`).

        ``values``: "array" for a float64 numpy array, "list" for a list of floats.
        """
        labels = tuple(labels) if labels else None
        key = (n, labels, values)
        enc = self._f64.get(key)
        if enc is None:
            prefix = f64_prefix(n, labels)
            if values == "array":
                def enc(x, _p=prefix):
                    return _p + x.tobytes()
            else:
                def enc(x, _p=prefix, _pack=struct.Struct(f"<{n}d").pack):
                    return _p + _pack(*x)
            probe = np.arange(n, dtype=np.float64) * 1.25 - 0.5
            if enc(probe if values == "array" else probe.tolist()) != self._rosbags_f64(probe, labels):
                self.fallbacks.append(f"Float64MultiArray[{n}]")

                def enc(x, _labels=labels):
                    return self._rosbags_f64(np.asarray(x, dtype=np.float64), _labels)
            self._f64[key] = enc
        return enc

    def _rosbags_js(self, names, sec, nsec, pos, vel, eff, frame_id: str = "") -> bytes:
        msg = self._JS(header=self._Header(stamp=self._Time(sec=sec, nanosec=nsec), frame_id=frame_id),
                       name=list(names), position=np.asarray(pos, dtype=np.float64),
                       velocity=np.asarray(vel, dtype=np.float64),
                       effort=np.asarray(eff, dtype=np.float64))
        return bytes(self.ts.serialize_cdr(msg, JOINT_STATE))

    def joint_state(self, names: list[str], sizes: tuple[int, int, int],
                    frame_id: str = "") -> Callable:
        """``(sec, nanosec, position, velocity, effort) -> CDR bytes`` for fixed names and sizes."""
        key = (tuple(names), sizes, frame_id)
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

        string(frame_id)
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
            ok = enc(12, 345, *probe) == self._rosbags_js(names, 12, 345, *probe, frame_id=frame_id)
        except struct.error:
            ok = False
        if not ok:
            self.fallbacks.append(f"JointState{sizes}")

            def enc(sec, nsec, pos, vel, eff, _n=list(names), _f=frame_id):
                return self._rosbags_js(_n, sec, nsec, pos, vel, eff, frame_id=_f)
        self._js[key] = enc
        return enc
