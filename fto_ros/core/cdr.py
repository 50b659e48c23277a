"""The one CDR codec of fto_ros: the bytes of every message the node and the replay take and
publish, with numpy, no message objects (the node's raw subscriptions and publishers, the
replay's bag blocks alike).

The wire format is what Fast DDS and rosbag2 use for ROS 2 messages: XCDR1 (plain CDR),
little endian, after the 4-byte encapsulation header ``00 01 00 00``; alignment counts
from the end of that header; a float64 sequence aligns to 8 only when it is not empty.
Anything else (big endian, XCDR2, a truncated or inconsistent payload, a name that is not
UTF-8) raises :class:`~fto_ros.core.errors.DecodeError`: the caller decides (the node hands
it to rclpy's deserialiser, the replay to rosbags', each the reference; what they refuse
too is a rejected sample in the node and a BagError naming the topic in the replay).
Padding bytes are never read: publishers leave them uninitialised.

- Float64MultiArray: :func:`f64_prefix` (the bytes up to the first double of a labelled or
  plain layout), :class:`FloatDecoder` (one payload: a read-only view of its data, the
  layout remembered), :func:`decode_float_block` (N payloads of one layout: one (N, n)
  array), :func:`float_block` (K rows -> K messages as one (K, L) uint8 array);
- sensor_msgs/JointState: :class:`JointStateDecoder` (one payload, or a block as runs of
  one layout with (k, n) views), :class:`JointStateEncoder` (one message into a reused
  buffer), :func:`joint_state_block` (K messages as one (K, L) uint8 array).

The encoders are byte for byte what rosbags' serialiser writes and what rclpy's
deserialiser reads back (test/unit/core/test_cdr.py, for every layout kind).  ROS-free.
"""
from __future__ import annotations

import struct
from typing import Callable, NamedTuple, Sequence

import numpy as np

from .errors import BadArgument, DecodeError

F64_ARRAY = "std_msgs/msg/Float64MultiArray"
JOINT_STATE = "sensor_msgs/msg/JointState"
CDR_LE = b"\x00\x01\x00\x00"
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_F8 = np.dtype("<f8")
_EMPTY = np.zeros(0)
_EMPTY.flags.writeable = False
#: sec, nanosec of a builtin_interfaces/Time: int32, uint32
_SEC_RANGE = (-2**31, 2**31 - 1)


class _Writer:
    """Little-endian XCDR1 bytes; alignment counts from the end of the 4-byte header."""

    def __init__(self):
        self.buf = bytearray(CDR_LE)

    def align(self, a: int) -> None:
        self.buf += b"\x00" * ((4 - len(self.buf)) % a)

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += _U32.pack(v)

    def string(self, s: str) -> None:
        raw = s.encode("utf-8") + b"\x00"
        self.u32(len(raw))
        self.buf += raw

    def doubles(self, k: int) -> int:
        """A float64 sequence of k zeros; the offset of its first double."""
        self.u32(k)
        if k:
            self.align(8)
        at = len(self.buf)
        self.buf += b"\x00" * (8 * k)
        return at


# -- Float64MultiArray -----------------------------------------------------------------------
def f64_prefix(n: int, labels=None) -> bytes:
    """The CDR of a Float64MultiArray of n values up to its first double: an empty layout
    (``labels`` None), else one dimension ``(label, 1, 1)`` per element (what the node
    publishes: each element named)."""
    w = _Writer()
    labels = list(labels or ())
    w.u32(len(labels))
    for label in labels:
        w.string(str(label))
        w.u32(1)
        w.u32(1)
    w.u32(0)  # data_offset
    w.doubles(n)
    return bytes(w.buf[:len(w.buf) - 8 * n])


def f64_data_at(p) -> tuple[int, int]:
    """(offset of the first double, count) of a little-endian XCDR1 Float64MultiArray
    payload (bytes or a uint8 row); DecodeError for anything else."""
    n = len(p)
    if n < 4 or bytes(p[:4]) != CDR_LE:
        raise DecodeError("not a little-endian XCDR1 payload" if n >= 4 else "truncated payload")
    try:
        pos = 4
        (ndims,) = _U32.unpack_from(p, pos)
        if ndims > n // 12:
            raise DecodeError("dimension count exceeds the payload")
        pos += 4
        for _ in range(ndims):
            pos += (4 - pos) % 4
            (slen,) = _U32.unpack_from(p, pos)
            pos += 4 + slen
            pos += (4 - pos) % 4
            pos += 8  # size, stride
        pos += (4 - pos) % 4
        _offset, count = struct.unpack_from("<II", p, pos)
    except struct.error:
        raise DecodeError("truncated payload") from None
    pos += 8
    if count:
        pos += (4 - pos) % 8
    if pos + 8 * count > n:
        raise DecodeError("array length exceeds the payload")
    return pos, count


class FloatDecoder:
    """One Float64MultiArray payload -> a read-only float64 view of its data.  The bytes
    before the data of the last payload are remembered: a stream of one layout costs one
    comparison and one ``np.frombuffer`` per message."""

    def __init__(self):
        self._head = b""
        self._length = -1
        self._count = 0

    def decode(self, payload) -> np.ndarray:
        head = self._head
        if len(payload) == self._length and payload[:len(head)] == head:
            return np.frombuffer(payload, _F8, self._count, len(head))
        off, count = f64_data_at(payload)
        self._head, self._length, self._count = bytes(payload[:off]), len(payload), count
        return np.frombuffer(payload, _F8, count, off)


def decode_float_block(payloads) -> np.ndarray | None:
    """The data of N Float64MultiArray payloads as one (N, n) float64 array when they all
    have one length and the same bytes before their data (one publisher, a fixed layout:
    no Python per message); None otherwise.  ``payloads``: an (N, L) uint8 matrix, an
    object with one as ``.matrix``, or a list of bytes."""
    matrix = payloads if isinstance(payloads, np.ndarray) else getattr(payloads, "matrix", None)
    if matrix is None:
        if not len(payloads) or len({len(p) for p in payloads}) != 1:
            return None
        matrix = np.frombuffer(b"".join(payloads), np.uint8).reshape(len(payloads), -1)
    if not len(matrix):
        return None
    try:
        off, count = f64_data_at(matrix[0])
    except DecodeError:
        return None
    if not (matrix[:, :off] == matrix[0, :off]).all():
        return None
    return matrix[:, off:off + 8 * count].copy().view(_F8)


def float_block(n: int, labels=None) -> Callable[[np.ndarray], np.ndarray]:
    """``X (K, n) -> the K messages' CDR, a (K, L) uint8 array`` (layout: :func:`f64_prefix`)."""
    prefix = np.frombuffer(f64_prefix(n, labels), np.uint8)
    p = prefix.size

    def encode(x) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=_F8)
        x = x.reshape(len(x) if x.ndim > 1 else 1, n)
        out = np.empty((len(x), p + 8 * n), np.uint8)
        out[:, :p] = prefix
        out[:, p:] = x.view(np.uint8).reshape(len(x), 8 * n)
        return out
    return encode


class FloatEncoder:
    """One Float64MultiArray of n labelled values into a reused buffer (the node's outputs)."""

    def __init__(self, n: int, labels=None):
        self.n = n
        prefix = f64_prefix(n, labels)
        self._buf = bytearray(prefix + b"\x00" * (8 * n))
        self._view = np.frombuffer(self._buf, _F8, n, len(prefix))

    def encode(self, x) -> bytes:
        self._view[:] = x
        return bytes(self._buf)


# -- sensor_msgs/JointState ------------------------------------------------------------------
class _Stamp(NamedTuple):
    sec: int
    nanosec: int


class _Header(NamedTuple):
    stamp: _Stamp
    frame_id: str


class JointStateArrays(NamedTuple):
    """One decoded JointState (or a run of k: (k, n) arrays, ``sec``/``nanosec`` the first
    message's).  ``name`` is a tuple shared by every message of a layout (so ``a.name is
    b.name`` tells the same names cheaply); the arrays are read-only float64 views of the
    payload.  ``header`` gives the attribute layout of rclpy's and rosbags' messages."""

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
    """Full parse of one payload (bytes-like): its layout; DecodeError for anything unusual."""
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
    merged: list[list[int]] = []   # adjacent spans merged; the bytes each must equal
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
    """Decode JointState payloads.  A stream from one publisher repeats everything but the
    stamp and the values, hence every offset: the last ``MEMORY`` layouts are remembered
    (an arm's and a gripper's publisher may alternate), and a payload of a remembered
    layout is decoded with a few bytes comparisons and three ``np.frombuffer`` views.
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
            return all(p[s:e] == b for s, e, b in lay.tail)
        return all(p[s:e] == b for s, e, b in lay.check)

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
        """One payload (bytes; a memoryview or bytearray works but is not kept)."""
        lay = self._layout(payload)
        sec, nsec = _STAMP.unpack_from(payload, 4)
        (po, pc), (vo, vc), (eo, ec) = lay.arrays
        frombuffer = np.frombuffer
        return JointStateArrays(sec, nsec, lay.frame_id, lay.name,
                                frombuffer(payload, _F8, pc, po) if pc else _EMPTY,
                                frombuffer(payload, _F8, vc, vo) if vc else _EMPTY,
                                frombuffer(payload, _F8, ec, eo) if ec else _EMPTY)

    def decode_block(self, payloads) -> list[tuple[np.ndarray, np.ndarray, JointStateArrays]]:
        """Several payloads (a list of bytes, or an (N, L) uint8 matrix / an object with one
        as ``.matrix``: one length) -> runs of consecutive messages of one layout:
        ``[(sec (k,) int64, nanosec (k,) int64, JointStateArrays with (k, n) arrays), ...]``
        (``stamp_ns(sec, nanosec)`` the stamps in ns).  A matrix
        whose rows share the first row's layout is one run, checked without Python per
        message.  DecodeError as :meth:`decode`."""
        matrix = payloads if isinstance(payloads, np.ndarray) else getattr(payloads, "matrix", None)
        if matrix is not None:
            if not len(matrix):
                return []
            lay = self._layout(matrix[0].tobytes())
            if all((matrix[:, s:e] == np.frombuffer(b, np.uint8)).all() for s, e, b in lay.check):
                self.fast += len(matrix) - 1
                return [_run(lay, np.ascontiguousarray(matrix))]
            payloads = [row.tobytes() for row in matrix]
        runs = []
        i, total = 0, len(payloads)
        while i < total:
            lay = self._layout(payloads[i])
            j = i + 1
            while j < total and self._same(payloads[j], lay):
                j += 1
            self.fast += j - i - 1
            joined = np.frombuffer(b"".join(payloads[m] for m in range(i, j)),  # any Sequence
                                   np.uint8).reshape(j - i, lay.length)
            runs.append(_run(lay, joined))
            i = j
        return runs


def stamp_ns(sec, nanosec):
    """Header stamps (sec, nanosec: numbers or int64 arrays) in ns."""
    return sec * 1_000_000_000 + nanosec


def _run(lay: _Layout, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray, JointStateArrays]:
    """(sec, nanosec, arrays) of k payloads of one layout, rows of a C-contiguous uint8 matrix."""
    k, size = matrix.shape

    def column(dtype, offset, count=None):
        if count is None:
            return np.ndarray((k,), dtype, matrix, offset, (size,))
        if count == 0:
            return np.zeros((k, 0))
        return np.ndarray((k, count), dtype, matrix, offset, (size, 8))
    sec, nsec = column("<i4", 4).astype(np.int64), column("<u4", 8).astype(np.int64)
    pos, vel, eff = (column(_F8, o, c) for o, c in lay.arrays)
    return sec, nsec, JointStateArrays(int(sec[0]), int(nsec[0]), lay.frame_id, lay.name,
                                    pos, vel, eff)


def _joint_state_template(names, sizes, frame_id: str) -> tuple[bytearray, list[int]]:
    """(the CDR of a JointState with stamp 0 and zeros, the offset of each array's first
    double) for fixed names, array sizes and frame_id; the stamp is at bytes 4-12."""
    if len(sizes) != 3 or any(int(k) != k or k < 0 for k in sizes):
        raise BadArgument(f"sizes must be three lengths >= 0, got {sizes}")
    w = _Writer()
    w.buf += b"\x00" * 8                     # stamp: sec (int32), nanosec (uint32)
    w.string(frame_id)
    w.u32(len(names))
    for nm in names:
        w.string(str(nm))
    at = [w.doubles(int(k)) for k in sizes]
    return w.buf, at


def _check_stamp(sec: int, nanosec: int) -> None:
    if not (_SEC_RANGE[0] <= sec <= _SEC_RANGE[1] and 0 <= nanosec < 2**32):
        raise BadArgument(f"stamp ({sec}, {nanosec}) does not fit builtin_interfaces/Time")


class JointStateEncoder:
    """JointState CDR bytes for fixed names, frame_id and array lengths; one buffer reused.
    ``sizes``: the lengths of position, velocity and effort (default: one value per name
    in each; 0 leaves that array empty)."""

    def __init__(self, names: Sequence[str], sizes: tuple[int, int, int] | None = None,
                 frame_id: str = ""):
        self.names = tuple(str(nm) for nm in names)
        self.sizes = tuple(sizes) if sizes is not None else (len(self.names),) * 3
        self._buf, at = _joint_state_template(self.names, self.sizes, frame_id)
        self._views = [np.frombuffer(self._buf, _F8, k, o) if k else None
                       for o, k in zip(at, self.sizes)]
        self.frame_id = frame_id

    def encode(self, sec: int, nanosec: int, position, velocity=None, effort=None) -> bytes:
        """The payload of one message (BadArgument for a stamp outside int32/uint32 or
        arrays of other lengths than ``sizes``; None for an empty array)."""
        _check_stamp(sec, nanosec)
        _STAMP.pack_into(self._buf, 4, sec, nanosec)
        for view, values, k in zip(self._views, (position, velocity, effort), self.sizes):
            got = 0 if values is None else len(values)
            if got != k:
                raise BadArgument(f"an array of length {got} where the layout has {k}")
            if k:
                view[:] = values
        return bytes(self._buf)


def joint_state_block(names: Sequence[str], sizes: tuple[int, int, int],
                      frame_id: str = "") -> Callable:
    """``(sec (K,), nanosec (K,), position (K, a), velocity (K, b), effort (K, c)) -> the K
    messages' CDR, a (K, L) uint8 array`` for fixed names, sizes (a, b, c) and frame_id."""
    buf, at = _joint_state_template(names, sizes, frame_id)
    template = np.frombuffer(bytes(buf), np.uint8)

    def encode(sec, nsec, pos, vel, eff) -> np.ndarray:
        sec = np.asarray(sec, dtype="<i4").reshape(-1)
        out = np.empty((sec.size, template.size), np.uint8)
        out[:] = template
        out[:, 4:8] = sec.view(np.uint8).reshape(-1, 4)
        out[:, 8:12] = np.asarray(nsec, dtype="<u4").reshape(-1).view(np.uint8).reshape(-1, 4)
        for off, k, vals in zip(at, sizes, (pos, vel, eff)):
            if k:
                v = np.ascontiguousarray(vals, dtype=_F8).reshape(-1, k)
                out[:, off:off + 8 * k] = v.view(np.uint8)
        return out
    return encode
