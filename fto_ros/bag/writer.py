"""Write rosbag2 bags (MCAP storage, metadata version 9 = ROS 2 Jazzy).

Messages are given as plain Python values (the writer builds and serializes the ROS 2
Jazzy messages itself with rosbags' type store), as ready CDR bytes, or as blocks of many
messages of one topic at once (:meth:`BagWriter.write_block`: the replay's fast path).
The log time of every message is the ``t_ns`` argument (integer nanoseconds, >= 0),
normally the sample time.  Connections (topics) are created on first use.  The MCAP file
and metadata.yaml are laid out as rosbags' writer lays them out
(:mod:`fto_ros.bag.mcap_write`); bags written here are read by ``ros2 bag info/play``
on a ROS 2 Jazzy install.

>>> with BagWriter("/tmp/example", overwrite=True) as bag:
...     bag.clock(0)
...     bag.float_array("/sys/input", 0, [1.5])
"""
from __future__ import annotations

import contextlib
import math
import os
import shutil
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from .. import __version__
from ..core.errors import short
from ..core.output_dir import abandon, create_output
from .mcap_write import McapBag
from .reader import BagError, shared_typestore

FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
JOINT_STATE = "sensor_msgs/msg/JointState"
CLOCK = "rosgraph_msgs/msg/Clock"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"

#: the distribution every bag written here says it is for (metadata.yaml ros_distro)
ROS_DISTRO = "jazzy"

#: DiagnosticStatus level names -> values (diagnostic_msgs/msg/DiagnosticStatus)
LEVELS = {"OK": 0, "WARN": 1, "ERROR": 2, "STALE": 3}


def _ns(value: Any, name: str) -> int:
    """Validate a time in integer nanoseconds (>= 0)."""
    if isinstance(value, (bool, np.bool_)):
        raise BagError(f"{name} must be an integer number of nanoseconds, got {value!r}")
    if isinstance(value, (int, np.integer)):
        out = int(value)
    elif isinstance(value, (float, np.floating)) and math.isfinite(value) and value == int(value):
        out = int(value)
    else:
        raise BagError(f"{name} must be an integer number of nanoseconds, got {value!r}")
    if out < 0:
        raise BagError(f"{name} must be >= 0, got {out}")
    return out


class BagWriter:
    """A rosbag2 (MCAP, version 9) bag being written; use as a context manager.

    Args:
        path: bag directory to create.
        overwrite: if the path exists, replace it, but only if it is an empty folder
            or a bag fto_ros wrote (:mod:`fto_ros.core.output_dir`: anything else, a
            file, a device, a symlink, a folder holding other things, raises
            OutputError and nothing is removed).  Without it an existing path raises
            OutputExists.
        inputs: paths the bag must not replace, be inside of or contain (the input
            bag and params files of the command writing it): OutputError.
        custom_data: key -> string pairs stored in metadata.yaml ``custom_data``.
        compress: zstd-compress the MCAP chunks (MCAP's own chunk compression,
            what ``ros2 bag record --storage-preset-profile zstd_fast`` does;
            metadata.yaml shows no compression mode and every MCAP reader
            handles it).  Bags of smooth simulated signals shrink ~3-5x.
        level: the zstd level (3: zstd's and rosbags' default; the replay writes its
            output bag at 1, half the time for a 7 % larger file).

    Full MCAP chunks are compressed and written by a thread of their own while the caller
    goes on.  The bag directory gets fto_ros's output marker, so that a later ``overwrite``
    recognises it.  If the ``with`` block raises, the half-written bag directory is
    removed.  ``counts`` is topic -> messages written.
    """

    def __init__(self, path: str | os.PathLike, *, overwrite: bool = False,
                 custom_data: Mapping[str, str] | None = None, compress: bool = True,
                 level: int = 3, inputs: Iterable[str | os.PathLike] = ()):
        self._path_arg = path
        self.path = Path(path)
        self.overwrite = overwrite
        self.inputs = tuple(inputs)
        self.compress, self.level = compress, level
        self.typestore = shared_typestore()
        self._types = self.typestore.types
        self._custom: dict[str, str] = {}
        self._writer: McapBag | None = None
        for key, value in (custom_data or {}).items():
            self.set_custom_data(key, value)
        self._conns: dict[str, Any] = {}
        self._conn_types: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        # message classes, looked up once
        t = self._types
        self._Time = t["builtin_interfaces/msg/Time"]
        self._Header = t["std_msgs/msg/Header"]
        self._F64 = t[FLOAT64_MULTI_ARRAY]
        self._Layout = t["std_msgs/msg/MultiArrayLayout"]
        self._JointState = t[JOINT_STATE]
        self._Clock = t[CLOCK]
        self._DiagArray = t[DIAGNOSTIC_ARRAY]
        self._DiagStatus = t["diagnostic_msgs/msg/DiagnosticStatus"]
        self._KeyValue = t["diagnostic_msgs/msg/KeyValue"]
        self._empty_layout = self._Layout(dim=[], data_offset=0)
        self._serialize = self.typestore.serialize_cdr

    # -- lifecycle --------------------------------------------------------------------
    def open(self) -> "BagWriter":
        """Create the bag directory (replacing an old bag if ``overwrite``)."""
        if self._writer is not None:
            raise BagError(f"{self.path}: bag is already open")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path}: parent directory {self.path.parent} does not exist")
        create_output(self._path_arg, "bag", overwrite=self.overwrite, inputs=self.inputs)
        try:
            self._writer = McapBag(self.path, compress=self.compress, level=self.level,
                                   library=f"fto_ros-{__version__}", ros_distro=ROS_DISTRO,
                                   custom_data=self._custom, background=True)
        except OSError as err:
            shutil.rmtree(self.path, ignore_errors=True)
            raise BagError(f"{self.path}: cannot create bag: {err}") from err
        return self

    def close(self) -> None:
        """Finish the bag: write the MCAP summary and metadata.yaml.  A bag that cannot be
        finished (a full disk) is removed: no half-written bag looks like a bag."""
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        try:
            writer.close()
        except Exception as err:
            with contextlib.suppress(Exception):
                writer.abort()
            what = abandon(self.path, "bag", short(err))
            raise BagError(f"{self.path}: cannot finish bag: {short(err)}; {what}") from err

    def abort(self) -> None:
        """Stop writing and delete the half-written bag directory."""
        writer, self._writer = self._writer, None
        if writer is not None:
            try:
                writer.abort()
            except Exception:
                pass
            shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self) -> "BagWriter":
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # -- metadata ---------------------------------------------------------------------
    def set_custom_data(self, key: str, value: str) -> None:
        """Store ``key: value`` (both strings) in metadata.yaml ``custom_data``."""
        if not isinstance(key, str) or not isinstance(value, str):
            raise BagError(f"{self.path}: custom_data keys and values must be strings, "
                           f"got {key!r}: {type(value).__name__}")
        self._custom[key] = value
        if self._writer is not None:
            self._writer.custom_data[key] = value

    # -- low level --------------------------------------------------------------------
    def _connection(self, topic: str, msgtype: str) -> int:
        """The channel id of ``topic`` (created on first use) after checking its type."""
        cid = self._conns.get(topic)
        if cid is not None:
            if self._conn_types[topic] != msgtype:
                raise BagError(f"{self.path}: topic {topic} already has type "
                               f"{self._conn_types[topic]}, cannot write {msgtype}")
            return cid
        if self._writer is None:
            raise BagError(f"{self.path}: bag is not open (use 'with BagWriter(...)')")
        if not topic.startswith("/"):
            raise BagError(f"{self.path}: topic names must be absolute, got {topic!r}")
        try:
            msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
            cid = self._writer.add_connection(topic, msgtype, msgdef,
                                              self.typestore.hash_rihs01(msgtype))
        except Exception as err:
            raise BagError(f"{self.path}: cannot add topic {topic} ({msgtype}): {err}") from err
        self._conns[topic] = cid
        self._conn_types[topic] = msgtype
        self.counts[topic] = 0
        return cid

    def connect(self, topic: str, msgtype: str) -> None:
        """Create ``topic``'s connection now (the order of connections is the order of the
        topics in metadata.yaml; a connection made mid-bag puts its records there)."""
        self._connection(topic, msgtype)

    def write_block(self, topic: str, msgtype: str, t_ns, payloads) -> None:
        """Many messages of one topic at once, in this order: ``t_ns`` (integer ns >= 0,
        one per message) and their CDR bytes, an (n, L) uint8 matrix (every message L
        bytes: written with no Python per message) or a sequence of bytes."""
        cid = self._connection(topic, msgtype)
        t = np.asarray(t_ns)
        if t.size and (t.dtype.kind not in "iu" or t.min() < 0):
            raise BagError(f"{self.path}: {topic}: log times must be integer ns >= 0")
        if len(payloads) != t.size:
            raise BagError(f"{self.path}: {topic}: {t.size} log times for {len(payloads)} "
                           "messages")
        self._writer.write_block(cid, t, payloads)
        self.counts[topic] += t.size

    def raw_writer(self, topic: str, msgtype: str) -> Callable[[int, bytes], None]:
        """A ``write(t_ns, cdr_bytes)`` for ``topic``: the caller serialises (the topic's
        connection is created and checked once, here)."""
        cid = self._connection(topic, msgtype)
        write = self._writer.write
        counts = self.counts

        def write_raw(t_ns: int, data: bytes) -> None:
            write(cid, t_ns, data)
            counts[topic] += 1
        return write_raw

    def write_message(self, topic: str, t_ns: int, msg: Any) -> None:
        """Write any rosbags Jazzy message object ``msg`` on ``topic`` at log time ``t_ns``."""
        t = _ns(t_ns, "t_ns")
        msgtype = msg.__msgtype__
        cid = self._connection(topic, msgtype)
        try:
            data = self._serialize(msg, msgtype)
        except Exception as err:
            raise BagError(f"{self.path}: cannot serialize {msgtype} for {topic}: {err}") from err
        self._writer.write(cid, t, data)
        self.counts[topic] += 1

    def _stamp(self, stamp_ns: int, name: str = "stamp_ns"):
        s = _ns(stamp_ns, name)
        return self._Time(sec=s // 1_000_000_000, nanosec=s % 1_000_000_000)

    # -- typed helpers ----------------------------------------------------------------
    def float_array(self, topic: str, t_ns: int, values: Sequence[float] | np.ndarray) -> None:
        """Write a ``std_msgs/Float64MultiArray`` with ``data = values`` (empty layout)."""
        data = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
        self.write_message(topic, t_ns, self._F64(layout=self._empty_layout, data=data))

    def joint_state(self, topic: str, t_ns: int, stamp_ns: int, names: Sequence[str],
                    position: Sequence[float] | np.ndarray = (),
                    velocity: Sequence[float] | np.ndarray = (),
                    effort: Sequence[float] | np.ndarray = (),
                    frame_id: str = "") -> None:
        """Write a ``sensor_msgs/JointState`` (header stamp ``stamp_ns``); empty fields stay empty.

        Each non-empty ``position``/``velocity``/``effort`` must have one entry per name.
        """
        names = [str(n) for n in names]
        arrays = []
        for field, vals in (("position", position), ("velocity", velocity), ("effort", effort)):
            arr = np.ascontiguousarray(vals, dtype=np.float64).reshape(-1)
            if arr.size not in (0, len(names)):
                raise BagError(f"{self.path}: {topic}: JointState {field} has {arr.size} "
                               f"values for {len(names)} joint names")
            arrays.append(arr)
        header = self._Header(stamp=self._stamp(stamp_ns), frame_id=frame_id)
        self.write_message(topic, t_ns, self._JointState(
            header=header, name=names, position=arrays[0], velocity=arrays[1],
            effort=arrays[2]))

    def clock(self, t_ns: int, topic: str = "/clock") -> None:
        """Write a ``rosgraph_msgs/Clock`` whose clock is ``t_ns`` (log time = ``t_ns``)."""
        self.write_message(topic, t_ns, self._Clock(clock=self._stamp(t_ns, "t_ns")))

    def diagnostics(self, topic: str, t_ns: int, status_list: Iterable[Mapping[str, Any]],
                    stamp_ns: int | None = None) -> None:
        """Write a ``diagnostic_msgs/DiagnosticArray`` (header stamp ``stamp_ns``, default ``t_ns``).

        Each status is a mapping with ``level`` (0-3 or "OK"/"WARN"/"ERROR"/"STALE"),
        ``name``, ``message``, optional ``hardware_id`` and optional ``values``
        (a mapping or a sequence of (key, value) pairs; values are turned into
        strings with ``str``).
        """
        statuses = []
        for i, st in enumerate(status_list):
            level = st.get("level", 0)
            if isinstance(level, str):
                if level.upper() not in LEVELS:
                    raise BagError(f"{self.path}: {topic}: status {i}: unknown level "
                                   f"{level!r}; use one of {list(LEVELS)}")
                level = LEVELS[level.upper()]
            if int(level) not in LEVELS.values():
                raise BagError(f"{self.path}: {topic}: status {i}: level must be 0..3, "
                               f"got {level!r}")
            values = st.get("values", ())
            pairs = values.items() if isinstance(values, Mapping) else values
            statuses.append(self._DiagStatus(
                level=int(level), name=str(st.get("name", "")),
                message=str(st.get("message", "")),
                hardware_id=str(st.get("hardware_id", "")),
                values=[self._KeyValue(key=str(k), value=str(v)) for k, v in pairs]))
        header = self._Header(stamp=self._stamp(t_ns if stamp_ns is None else stamp_ns),
                              frame_id="")
        self.write_message(topic, t_ns, self._DiagArray(header=header, status=statuses))


def warm_up() -> None:
    """Have rosbags generate the serialisers of the message types written here (once per
    process, ~0.1 s; part of the one-time set-up, like the imports)."""
    ts = shared_typestore()
    T = ts.types
    for msgtype in (FLOAT64_MULTI_ARRAY, JOINT_STATE, CLOCK, DIAGNOSTIC_ARRAY):
        fields = {}
        if msgtype == FLOAT64_MULTI_ARRAY:
            fields = {"layout": T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
                      "data": np.zeros(1)}
        elif msgtype == CLOCK:
            fields = {"clock": T["builtin_interfaces/msg/Time"](sec=0, nanosec=0)}
        else:
            header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
                sec=0, nanosec=0), frame_id="")
            fields = {"header": header, "name": [], "position": np.zeros(0),
                      "velocity": np.zeros(0), "effort": np.zeros(0)} \
                if msgtype == JOINT_STATE else {"header": header, "status": []}
        ts.serialize_cdr(T[msgtype](**fields), msgtype)
