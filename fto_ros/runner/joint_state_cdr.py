"""sensor_msgs/JointState <-> CDR bytes with numpy, for raw subscriptions and raw publishing.

A stream of JointState messages from one publisher repeats everything but the stamp and
the values: the frame_id, the names and the array lengths, hence every offset.
:class:`JointStateDecoder` parses one message fully, keeps its layout, and decodes the
next messages that share it with one bytes comparison and three ``np.frombuffer`` views
(a few microseconds, against ~20 us for rclpy to build a message object with seven
names).  A message with another layout is parsed fully and becomes the new layout.
:class:`JointStateEncoder` fills one preallocated buffer per message (stamp and values;
names, frame_id and lengths fixed at construction).

The wire format is what Fast DDS and rosbag2 use for ROS 2 messages: XCDR1 (plain CDR),
little endian, after the 4-byte encapsulation header ``00 01 00 00``; alignment counts
from the end of that header; a float64 sequence aligns to 8 only when it is not empty.
Anything else (big endian, XCDR2, a truncated or inconsistent payload, a name that is not
UTF-8) raises ``ValueError``: the caller decides (the node falls back to rclpy's own
deserialiser, which is the reference, and rejects what that refuses too).  Padding bytes
are never read: publishers leave them uninitialised.  No rclpy here (the replay may use it).
"""
from __future__ import annotations

import struct
from typing import NamedTuple, Sequence

import numpy as np

from ..core.errors import BadArgument, DecodeError

CDR_LE = b"\x00\x01\x00\x00"
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_F8 = np.dtype("<f8")
_EMPTY = np.zeros(0)
_EMPTY.flags.writeable = False
#: sec, nanosec of a builtin_interfaces/Time: int32, uint32
_SEC_RANGE = (-2**31, 2**31 - 1)


class _Stamp(NamedTuple):
    sec: int
    nanosec: int


class _Header(NamedTuple):
    stamp: _Stamp
    frame_id: str


class JointStateArrays(NamedTuple):
    """One decoded JointState.  ``name`` is a tuple shared by every message of a layout (so
    ``a.name is b.name`` tells the same names cheaply); the arrays are read-only float64
    views of the payload.  ``header`` gives the message's attribute layout, so code
    duck-typed on rclpy messages (``runner/messages.py``) takes these too."""

    sec: int
    nanosec: int
    frame_id: str
    name: tuple
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    @property
    def header(self) -> _Header:
        return _Header(_Stamp(self.sec, self.nanosec), self.frame_id)

    @property
    def stamp_ns(self) -> int:
        return self.sec * 1_000_000_000 + self.nanosec


class _Layout(NamedTuple):
    length: int            # payload length
    head_end: int          # offset of the first value (or the end of the last count)
    head: bytes            # payload[12:head_end]: frame_id, names, counts, padding included
    tail: tuple            # (start, end, bytes) of the counts after the first value
    check: tuple           # (start, end, bytes) of everything but stamp, values and padding
    frame_id: str
    name: tuple
    arrays: tuple          # ((offset, count), ...) of position, velocity, effort


def _parse(p) -> _Layout:
    """Full parse of one payload (bytes-like): its layout; ValueError for anything unusual."""
    n = len(p)
    if n < 12 or bytes(p[:4]) != CDR_LE:
        raise DecodeError("not a little-endian XCDR1 payload" if n >= 4 else "truncated payload")
    spans = []
    pos = 12  # after the header (4) and the stamp (8)

    def u32() -> int:
        nonlocal pos
        pos += (4 - pos) % 4
        if pos + 4 > n:
            raise DecodeError("truncated payload")
        (v,) = _U32.unpack_from(p, pos)
        pos += 4
        return v

    def string() -> str:
        nonlocal pos
        start = pos + (4 - pos) % 4
        size = u32()
        if size == 0 or pos + size > n or p[pos + size - 1] != 0:
            raise DecodeError("malformed string")
        raw = bytes(p[pos:pos + size - 1])
        pos += size
        spans.append((start, pos))
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise DecodeError("a string is not UTF-8") from None

    frame_id = string()
    start = pos + (4 - pos) % 4
    count = u32()
    spans.append((start, pos))
    if count > (n - pos) // 5:  # every name takes at least 5 bytes (length + NUL)
        raise DecodeError("name count exceeds the payload")
    name = tuple(string() for _ in range(count))
    arrays = []
    for _ in range(3):
        start = pos + (4 - pos) % 4
        count = u32()
        spans.append((start, pos))
        if count:
            pos += (4 - pos) % 8
            if count > (n - pos) // 8:
                raise DecodeError("array length exceeds the payload")
            arrays.append((pos, count))
            pos += 8 * count
        else:
            arrays.append((pos, 0))
    # merge adjacent spans; keep the bytes each must equal in the next message
    merged: list[list[int]] = []
    for s, e in spans:
        if merged and merged[-1][1] == s:
            merged[-1][1] = e
        else:
            merged.append([s, e])
    check = tuple((s, e, bytes(p[s:e])) for s, e in merged)
    head_end = next((o for o, c in arrays if c), merged[-1][1])
    tail = tuple(span for span in check if span[0] >= head_end)
    return _Layout(n, head_end, bytes(p[12:head_end]), tail, check, frame_id, name, tuple(arrays))


class JointStateDecoder:
    """Decode JointState payloads; see the module docstring.  The last ``MEMORY`` layouts
    are remembered (several publishers on one topic, an arm's and a gripper's, alternate).
    ``fast`` / ``parsed`` count the payloads decoded on a remembered layout / by a full parse."""

    MEMORY = 4

    def __init__(self):
        self._layouts: list[_Layout] = []
        self.fast = 0
        self.parsed = 0

    @staticmethod
    def _same(p, lay: _Layout) -> bool:
        if len(p) != lay.length:
            return False
        if p[12:lay.head_end] == lay.head:     # when the padding repeats too: 1-3 comparisons
            for s, e, b in lay.tail:
                if p[s:e] != b:
                    return False
            return True
        for s, e, b in lay.check:
            if p[s:e] != b:
                return False
        return True

    def _layout(self, p) -> _Layout:
        """The payload's layout: a remembered one (moved to the front), else a full parse."""
        lays = self._layouts
        for i, lay in enumerate(lays):
            if self._same(p, lay):
                self.fast += 1
                if i:
                    lays.insert(0, lays.pop(i))
                return lay
        lay = _parse(p)
        self.parsed += 1
        lays.insert(0, lay)
        del lays[self.MEMORY:]
        return lay

    def decode(self, payload) -> JointStateArrays:
        """One payload (bytes; memoryview/bytearray work but are not kept) -> JointStateArrays."""
        lay = self._layout(payload)
        sec, nsec = _STAMP.unpack_from(payload, 4)
        (po, pc), (vo, vc), (eo, ec) = lay.arrays
        frombuffer = np.frombuffer
        return JointStateArrays(sec, nsec, lay.frame_id, lay.name,
                                frombuffer(payload, _F8, pc, po) if pc else _EMPTY,
                                frombuffer(payload, _F8, vc, vo) if vc else _EMPTY,
                                frombuffer(payload, _F8, ec, eo) if ec else _EMPTY)

    def decode_block(self, payloads: Sequence[bytes]) -> list[tuple[np.ndarray, JointStateArrays]]:
        """Several payloads -> runs of consecutive messages that share a layout:
        ``[(stamps_ns (k,) int64, JointStateArrays with (k, n) arrays), ...]`` (the run's
        ``sec``/``nanosec`` are its first message's).  One numpy view per field and run;
        ValueError as :meth:`decode`."""
        runs = []
        i, total = 0, len(payloads)
        while i < total:
            lay = self._layout(payloads[i])
            j = i + 1
            while j < total and self._same(payloads[j], lay):
                j += 1
            self.fast += j - i - 1
            k, size = j - i, lay.length
            joined = b"".join(payloads[i:j])

            def column(dtype, offset, count=None):
                if count is None:
                    return np.ndarray((k,), dtype, joined, offset, (size,))
                if count == 0:
                    return np.zeros((k, 0))
                return np.ndarray((k, count), dtype, joined, offset, (size, 8))
            sec, nsec = column("<i4", 4), column("<u4", 8)
            stamps = sec.astype(np.int64) * 1_000_000_000 + nsec
            pos, vel, eff = (column(_F8, o, c) for o, c in lay.arrays)
            runs.append((stamps, JointStateArrays(int(sec[0]), int(nsec[0]), lay.frame_id,
                                                  lay.name, pos, vel, eff)))
            i = j
        return runs


class JointStateEncoder:
    """JointState CDR bytes for fixed names, frame_id and array lengths; one buffer reused.

    ``sizes``: the lengths of position, velocity and effort (default: one value per name
    in each; 0 leaves that array empty).
    """

    def __init__(self, names: Sequence[str], sizes: tuple[int, int, int] | None = None,
                 frame_id: str = ""):
        self.names = tuple(str(nm) for nm in names)
        self.sizes = tuple(sizes) if sizes is not None else (len(self.names),) * 3
        if len(self.sizes) != 3 or any(int(k) != k or k < 0 for k in self.sizes):
            raise BadArgument(f"sizes must be three lengths >= 0, got {sizes}")
        buf = bytearray(CDR_LE + b"\x00" * 8)

        def align(a: int) -> None:
            buf.extend(b"\x00" * ((4 - len(buf)) % a))

        def string(s: str) -> None:
            raw = s.encode("utf-8") + b"\x00"
            align(4)
            buf.extend(_U32.pack(len(raw)) + raw)

        string(frame_id)
        align(4)
        buf.extend(_U32.pack(len(self.names)))
        for nm in self.names:
            string(nm)
        offsets = []
        for k in self.sizes:
            align(4)
            buf.extend(_U32.pack(k))
            if k:
                align(8)
            offsets.append(len(buf))
            buf.extend(b"\x00" * (8 * k))
        self._buf = buf
        self._views = [np.frombuffer(buf, _F8, k, o) if k else None
                       for o, k in zip(offsets, self.sizes)]
        self.frame_id = frame_id

    def encode(self, sec: int, nanosec: int, position, velocity=None, effort=None) -> bytes:
        """The payload of one message (ValueError for a stamp outside int32/uint32 or
        arrays of other lengths than ``sizes``; None for an empty array)."""
        if not (_SEC_RANGE[0] <= sec <= _SEC_RANGE[1] and 0 <= nanosec < 2**32):
            raise BadArgument(f"stamp ({sec}, {nanosec}) does not fit builtin_interfaces/Time")
        _STAMP.pack_into(self._buf, 4, sec, nanosec)
        for view, values, k in zip(self._views, (position, velocity, effort), self.sizes):
            got = 0 if values is None else len(values)
            if got != k:
                raise BadArgument(f"an array of length {got} where the layout has {k}")
            if k:
                view[:] = values
        return bytes(self._buf)
