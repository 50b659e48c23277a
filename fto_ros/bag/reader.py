"""Read rosbag2 bags (MCAP or SQLite3) with rosbags, without ROS.

Messages come back deserialized by the rosbags ROS 2 Jazzy typestore: dataclass
objects with the same attribute names as rclpy messages (``msg.data``,
``msg.header.stamp.sec``, ``msg.name``, ``msg.position`` ...).  Numeric arrays
are numpy arrays (rclpy gives ``array.array``); use ``np.asarray`` on both.

Every failure (missing path, a directory that is not a bag, a corrupt or
truncated file, an undecodable message) raises :class:`BagError` whose message
names the path and the problem.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator, NamedTuple

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import get_types_from_msg

from ..core.errors import BagError, short


class TopicInfo(NamedTuple):
    """One topic of a bag: its message type and how many messages it holds."""

    msgtype: str
    count: int


@dataclass(frozen=True)
class BagInfo:
    """Summary of a bag (what ``ros2 bag info`` shows).

    ``start_ns``/``end_ns`` are the first and last log times (0 if empty),
    ``duration_ns = end_ns - start_ns``; ``custom_data`` is the key -> string
    map of metadata.yaml (``fto-simulate`` stores its settings there).
    """

    path: str
    topics: dict[str, TopicInfo]
    message_count: int
    start_ns: int
    end_ns: int
    duration_ns: int
    storage: str
    custom_data: dict[str, str]


def jazzy_typestore():
    """A fresh rosbags typestore with the ROS 2 Jazzy message definitions."""
    return get_typestore(Stores.ROS2_JAZZY)


@functools.lru_cache(maxsize=1)
def shared_typestore():
    """The process's Jazzy typestore for writing and decoding known types (never extended
    with a bag's own types: BagReader has a fresh one): rosbags generates a type's
    serialiser once per typestore, ~10-50 ms each, so every bag written in a process
    shares them."""
    return jazzy_typestore()


def deserialize(typestore, payload, msgtype: str, where: str, k: int):
    """One raw CDR message through rosbags (what the numpy codec, core/cdr.py, does not
    take: big endian, XCDR2), or BagError naming where it is."""
    try:
        return typestore.deserialize_cdr(bytes(payload), msgtype)
    except Exception as exc:  # rosbags raises SerdeError, struct.error, IndexError ...
        raise BagError(f"{where}: cannot decode message {k} as {msgtype}: "
                       f"{type(exc).__name__}: {short(exc)}") from None


def _describe(err: BaseException) -> str:
    text = " ".join(str(err)[:400].split()) or type(err).__name__
    return f"{text} ({type(err).__name__})"


class BagReader:
    """An open bag; use as a context manager (or call :meth:`close`).

    >>> with BagReader("bags/dc_motor") as bag:
    ...     for topic, t_ns, msg in bag.messages(["/dc_motor/measured_output"]):
    ...         y = msg.data
    """

    def __init__(self, path: str | os.PathLike):
        """Open the rosbag2 directory (or a single ``.mcap``/``.db3`` file) at ``path``."""
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag (path does not exist)")
        if self.path.is_dir():
            if not (self.path / "metadata.yaml").is_file():
                raise BagError(f"{self.path}: not a rosbag2 bag (directory has no metadata.yaml)")
        elif self.path.suffix not in (".mcap", ".db3"):
            raise BagError(f"{self.path}: not a rosbag2 bag (expected a bag directory "
                           f"or a .mcap/.db3 file)")
        self._typestore = jazzy_typestore()
        self.typestore = self._typestore   # public: the types of this bag (Jazzy + its own)
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except BagError:
            raise
        except Exception as err:  # rosbags raises ReaderError, OSError, struct errors ...
            raise BagError(f"{self.path}: cannot open bag (corrupt, truncated or unfinished "
                           f"file?): {_describe(err)}") from err
        self._open = True
        self._register_unknown_types()

    # -- context manager -------------------------------------------------------------
    def __enter__(self) -> "BagReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the bag (idempotent)."""
        if getattr(self, "_open", False):
            self._open = False
            try:
                self._reader.close()
            except Exception:  # closing a half-broken bag must not hide the real error
                pass

    # -- metadata ---------------------------------------------------------------------
    def _register_unknown_types(self) -> None:
        """Teach the typestore message types the bag defines but Jazzy does not know."""
        known = self._typestore.types
        for conn in self._reader.connections:
            if conn.msgtype in known or not conn.msgdef.data:
                continue
            try:
                self._typestore.register(get_types_from_msg(conn.msgdef.data, conn.msgtype))
            except Exception:
                pass  # reported on first use, with the topic name

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topic name -> (message type, message count), sorted by name."""
        out: dict[str, TopicInfo] = {}
        for conn in sorted(self._reader.connections, key=lambda c: c.topic):
            prev = out.get(conn.topic)
            out[conn.topic] = TopicInfo(conn.msgtype, conn.msgcount + (prev.count if prev else 0))
        return out

    @property
    def message_count(self) -> int:
        """Total number of messages."""
        return int(self._reader.message_count)

    @property
    def start_ns(self) -> int:
        """Log time of the first message (0 for an empty bag)."""
        return int(self._reader.start_time) if self.message_count else 0

    @property
    def end_ns(self) -> int:
        """Log time of the last message (0 for an empty bag)."""
        return int(self._reader.end_time) - 1 if self.message_count else 0

    @property
    def custom_data(self) -> dict[str, str]:
        """The ``custom_data`` key -> string map of metadata.yaml (empty if none)."""
        meta = getattr(self._reader.storage, "metadata", None)
        custom = getattr(meta, "custom", None) if meta is not None else None
        return dict(custom or {})

    def info(self) -> BagInfo:
        """A :class:`BagInfo` summary of this bag."""
        storage = "mcap"
        if self.path.is_dir():
            files = [p.suffix for p in self.path.iterdir()]
            storage = "sqlite3" if ".db3" in files else "mcap"
        elif self.path.suffix == ".db3":
            storage = "sqlite3"
        return BagInfo(path=str(self.path), topics=self.topics,
                       message_count=self.message_count, start_ns=self.start_ns,
                       end_ns=self.end_ns, duration_ns=self.end_ns - self.start_ns,
                       storage=storage, custom_data=self.custom_data)

    # -- messages ---------------------------------------------------------------------
    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 stop_ns: int | None = None) -> Iterator[tuple[str, int, Any]]:
        """Yield ``(topic, log_time_ns, msg)`` in log-time order.

        Args:
            topics: only these topics (all if None); an unknown name raises BagError.
            start_ns: only messages with log time >= start_ns.
            stop_ns: only messages with log time < stop_ns.

        Messages with equal log times come in the order they were written.
        A closed bag or an unknown topic raises BagError at the call; a corrupt
        file raises BagError during the iteration.
        """
        if not self._open:
            raise BagError(f"{self.path}: bag is closed")
        conns = self._reader.connections
        if topics is not None:
            wanted = set(topics)
            missing = wanted - {c.topic for c in conns}
            if missing:
                raise BagError(f"{self.path}: no topic(s) {sorted(missing)} in bag; "
                               f"topics: {sorted({c.topic for c in conns})}")
            conns = [c for c in conns if c.topic in wanted]
        return self._iterate(conns, start_ns, stop_ns)

    def _iterate(self, conns, start_ns, stop_ns) -> Iterator[tuple[str, int, Any]]:
        if not conns:
            return
        deserialize = self._typestore.deserialize_cdr
        types = self._typestore.types
        topic = "?"
        t_ns = -1
        try:
            for conn, t_ns, raw in self._reader.messages(conns, start=start_ns, stop=stop_ns):
                topic = conn.topic
                if conn.msgtype not in types:
                    raise BagError(f"{self.path}: topic {topic}: unknown message type "
                                   f"{conn.msgtype} (not in ROS 2 Jazzy and not defined "
                                   f"in the bag)")
                try:
                    msg = deserialize(raw, conn.msgtype)
                except Exception as err:  # SerdeError, struct.error, IndexError ...
                    raise BagError(f"{self.path}: topic {topic}: cannot decode the message at "
                                   f"log time {t_ns} ns as {conn.msgtype}: {_describe(err)}") from None
                yield topic, t_ns, msg
        except BagError:
            raise
        except GeneratorExit:
            raise
        except Exception as err:
            where = f" after topic {topic} at log time {t_ns} ns" if t_ns >= 0 else ""
            raise BagError(f"{self.path}: corrupt or unreadable bag{where}: "
                           f"{_describe(err)}") from err


def read_messages(path: str | os.PathLike, topics: Iterable[str] | None = None,
                  start_ns: int | None = None,
                  stop_ns: int | None = None) -> Iterator[tuple[str, int, Any]]:
    """Open the bag at ``path`` and yield ``(topic, log_time_ns, msg)`` in log-time order.

    The bag is opened (and checked: BagError) at the call, not at the first
    ``next``, and closed when the iteration ends or the generator is closed.
    See :meth:`BagReader.messages` for the arguments.
    """
    bag = BagReader(path)
    try:
        it = bag.messages(topics, start_ns, stop_ns)
    except BaseException:
        bag.close()
        raise
    return _closing(bag, it)


def _closing(bag: BagReader, it: Iterator[tuple[str, int, Any]]) -> Iterator[tuple[str, int, Any]]:
    try:
        yield from it
    finally:
        bag.close()


def list_topics(path: str | os.PathLike) -> dict[str, TopicInfo]:
    """Topic name -> (message type, message count) of the bag at ``path``."""
    with BagReader(path) as bag:
        return bag.topics


def bag_info(path: str | os.PathLike) -> BagInfo:
    """Summary (topics, counts, times, custom metadata) of the bag at ``path``."""
    with BagReader(path) as bag:
        return bag.info()
