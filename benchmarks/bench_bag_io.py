#!/usr/bin/env python3
"""Reading and writing the committed bags: fto_ros's own MCAP code against rosbags and
Foxglove's ``mcap`` library, measured in one run.

    python benchmarks/bench_bag_io.py [--repeat R] [--bag NAME ...]

Reading (every topic of every committed bag, to decoded values: Float64MultiArray data as
floats, JointState fields, the Clock payload):

- ``fto_ros``: bag/mcap_scan.py's indexed path (metadata.yaml, the MCAP summary and
  message indexes, every topic cut out at once), decoded with core/cdr.py as the replay's
  sources do (runner/sources/): a Float64MultiArray topic as one block
  (``decode_float_block``, else ``FloatDecoder`` per message), a JointState topic as runs
  of one layout with (k, n) arrays (``JointStateDecoder.decode_block``), rosbags'
  deserialiser for what the codec does not take (the replay's fallback);
- ``fto_ros scan``: the same code walking every record with ``struct`` (the replay's reader
  before; still the fallback for files without indexes);
- ``rosbags``: ``BagReader`` (rosbags' Reader, ``deserialize_cdr`` per message), opening
  included;
- ``mcap raw``: ``mcap.reader.make_reader(...).iter_messages()`` (payloads only, no
  decoding: a lower bound for anything built on it);
- ``mcap-ros2``: ``iter_decoded_messages()`` with ``mcap_ros2``'s decoder.

Every reader's values are compared with rosbags' (times and every field, exactly); a
column that differs is marked.  Writing (every message of the bag written again, zstd
chunk compression):

- ``fto_ros block``: ``BagWriter.write_block``, a topic's messages at once (the replay);
- ``fto_ros msg``: ``BagWriter``'s per-message ``raw_writer``;
- ``rosbags``: rosbags' ``Writer.write`` per message;
- ``mcap``: ``mcap.writer.Writer.add_message`` per message (the .mcap only: no
  metadata.yaml, so no rosbag2 bag).

The fto_ros and rosbags bags are then compared byte for byte (the library name in the
MCAP header and the YAML emitter set alike).  With ``--repeat R`` each measurement is the best of R runs, taken
in turn so that a change of load hits every column alike; the load average is printed.
Columns whose library is not installed are skipped with a note (``pip install mcap
mcap-ros2-support`` to measure them: they are not fto_ros dependencies).
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np

from fto_ros.bag import BagReader, BagWriter
from fto_ros.bag.mcap_scan import fast_info, read_raw
from fto_ros.bag.reader import deserialize, jazzy_typestore
from fto_ros.core.cdr import FloatDecoder, JointStateDecoder, decode_float_block
from fto_ros.core.errors import DecodeError

ROOT = Path(__file__).resolve().parent.parent
F64, JS, CLOCK = ("std_msgs/msg/Float64MultiArray", "sensor_msgs/msg/JointState",
                  "rosgraph_msgs/msg/Clock")

try:
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer as McapWriter
except ImportError:
    make_reader = None
try:
    from mcap_ros2.decoder import DecoderFactory
except ImportError:
    DecoderFactory = None


# ------------------------------------------------------------------ reading
def _values(msgtype: str, msg):
    """A decoded message as comparable plain values."""
    if msgtype == F64:
        return tuple(np.asarray(msg.data, dtype=float).tolist())
    if msgtype == JS:
        return (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id,
                tuple(msg.name), *(tuple(np.asarray(getattr(msg, f), dtype=float).tolist())
                                   for f in ("position", "velocity", "effort")))
    return (msg.clock.sec, msg.clock.nanosec) if msgtype == CLOCK else None


class _Runs(list):
    """A JointState topic as JointStateDecoder.decode_block's runs: (sec, nanosec, arrays)."""


def _each(decode, payloads, msgtype: str, where: str, ts) -> list:
    """Per message: ``decode(payload)``, else rosbags' deserialiser (BagError if it fails)."""
    out = []
    for k, p in enumerate(payloads):
        try:
            out.append(decode(p))
        except DecodeError:
            out.append(deserialize(ts, p, msgtype, where, k))
    return out


def read_fto(bag: Path, indexed: bool = True) -> dict:
    info, files = fast_info(bag)
    raw = read_raw(bag, list(info.topics), files, indexed=indexed)
    ts = jazzy_typestore()
    out = {}
    for topic, (t, payloads) in raw.items():
        msgtype, where = info.topics[topic].msgtype, f"{bag}: topic {topic}"
        if msgtype == F64:
            vals = decode_float_block(payloads)
            if vals is None:
                vals = _each(FloatDecoder().decode, payloads, F64, where, ts)
        elif msgtype == JS:
            dec = JointStateDecoder()
            try:
                vals = _Runs(dec.decode_block(payloads))
            except DecodeError:      # one odd payload: each on its own
                vals = _each(dec.decode, payloads, JS, where, ts)
        else:
            vals = payloads
        out[topic] = (t, vals)
    return out


def _messages_of(vals) -> list:
    """read_fto's values of a topic, one item per message (runs cut into messages)."""
    if isinstance(vals, np.ndarray):
        return vals.tolist()
    if not isinstance(vals, _Runs):
        return vals
    return [js._replace(sec=int(sec[i]), nanosec=int(nsec[i]), position=js.position[i],
                        velocity=js.velocity[i], effort=js.effort[i])
            for sec, nsec, js in vals for i in range(sec.size)]


def read_rosbags(bag: Path) -> dict:
    with BagReader(bag) as r:
        topics = r.topics
        out = {t: ([], []) for t in topics}
        for topic, t_ns, msg in r.messages():
            out[topic][0].append(t_ns)
            out[topic][1].append(msg)
    return {t: (np.asarray(v[0], dtype=np.int64), v[1]) for t, v in out.items()}


def _mcap_file(bag: Path) -> Path:
    return next(bag.glob("*.mcap"))


def read_mcap_raw(bag: Path) -> dict:
    out: dict = {}
    with open(_mcap_file(bag), "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            t, d = out.setdefault(channel.topic, ([], []))
            t.append(message.log_time)
            d.append(message.data)
    return out


def read_mcap_ros2(bag: Path) -> dict:
    out: dict = {}
    with open(_mcap_file(bag), "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=True):
            t, d = out.setdefault(channel.topic, ([], []))
            t.append(message.log_time)
            d.append(decoded)
    return out


def same_as(ref: dict, got: dict, types: dict, decoded: bool = True) -> bool:
    """Whether ``got`` has ref's times and (if ``decoded``) values on every topic."""
    for topic, (t, msgs) in ref.items():
        if topic not in got:
            return False
        gt, gv = got[topic]
        rows = _messages_of(gv)
        if list(map(int, gt)) != t.tolist() or len(rows) != len(msgs):
            return False
        if not decoded:
            continue
        msgtype = types[topic]
        if msgtype == CLOCK:
            continue                      # copied as raw bytes by the replay: compared below
        for m, g in zip(msgs, rows):
            ok = (_values(msgtype, m) == tuple(g)) if msgtype == F64 and not hasattr(g, "data") \
                else _values(msgtype, m) == _values(msgtype, g)
            if not ok:
                return False
    return True


# ------------------------------------------------------------------ writing
def _messages(bag: Path):
    """topic -> (msgtype, log times, raw payloads) of every message of the bag."""
    info, files = fast_info(bag)
    raw = read_raw(bag, list(info.topics), files)
    return {t: (info.topics[t].msgtype, tt, p) for t, (tt, p) in raw.items()}


def _in_time_order(msgs: dict) -> list:
    rows = [(int(t), k, topic, bytes(p[j])) for k, (topic, (_m, ts, p)) in
            enumerate(msgs.items()) for j, t in enumerate(ts)]
    rows.sort(key=lambda r: (r[0], r[1]))
    return rows


def write_fto_block(msgs: dict, out: Path) -> None:
    with BagWriter(out) as bag:
        for topic, (msgtype, t, payloads) in msgs.items():
            data = payloads.matrix if payloads.matrix is not None else list(payloads)
            bag.write_block(topic, msgtype, t, data)


def write_fto_msg(msgs: dict, rows: list, out: Path) -> None:
    with BagWriter(out) as bag:
        writers = {topic: bag.raw_writer(topic, m[0]) for topic, m in msgs.items()}
        for t, _k, topic, data in rows:
            writers[topic](t, data)


def write_rosbags(msgs: dict, rows: list, out: Path) -> None:
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    ts = jazzy_typestore()
    w = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    w.open()
    conns = {topic: w.add_connection(topic, m[0], typestore=ts) for topic, m in msgs.items()}
    for t, _k, topic, data in rows:
        w.write(conns[topic], t, data)
    w.close()


def write_mcap(msgs: dict, rows: list, out: Path) -> None:
    ts = jazzy_typestore()
    out.mkdir()
    with open(out / f"{out.name}.mcap", "wb") as f:
        w = McapWriter(f, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="bench")
        sids, cids = {}, {}
        for topic, (msgtype, _t, _p) in msgs.items():
            if msgtype not in sids:
                sids[msgtype] = w.register_schema(
                    msgtype, "ros2msg", ts.generate_msgdef(msgtype, ros_version=2)[0].encode())
            cids[topic] = w.register_channel(topic, "cdr", sids[msgtype])
        for t, _k, topic, data in rows:
            w.add_message(cids[topic], t, data, t)
        w.finish()


# ------------------------------------------------------------------ the run
def _best(fn, repeat: int) -> float:
    return min(_timed(fn) for _ in range(repeat))


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _row(name: str, n: int, times: dict[str, float | None], notes: dict[str, str]) -> str:
    best = min(v for v in times.values() if v is not None)
    cells = []
    for k, v in times.items():
        cells.append("skipped" if v is None else
                     f"{v * 1e3:.1f} ms ({v / best:.1f}x){notes.get(k, '')}")
    return f"| {name} | {n} | " + " | ".join(cells) + " |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--bag", action="append", default=[], help="only these bags (names)")
    args = ap.parse_args(argv)
    bags = sorted(p for p in (ROOT / "bags").iterdir() if p.is_dir()
                  and (not args.bag or p.name in args.bag))
    print(f"load average before: {os.getloadavg()[0]:.2f}; rosbags {version('rosbags')}"
          + (f", mcap {version('mcap')}" if make_reader else ", mcap not installed")
          + (f", mcap-ros2-support {version('mcap-ros2-support')}" if DecoderFactory else ""))
    read_cols = ["fto_ros", "fto_ros scan", "rosbags", "mcap raw", "mcap-ros2"]
    write_cols = ["fto_ros block", "fto_ros msg", "rosbags", "mcap"]
    read_rows, write_rows, totals_r, totals_w, identical = [], [], {}, {}, []
    tmp = Path(tempfile.mkdtemp(prefix="bench-bag-io-"))
    try:
        for bag in bags:
            info, _ = fast_info(bag)
            types = {t: v.msgtype for t, v in info.topics.items()}
            n = info.message_count
            ref = read_rosbags(bag)
            readers = {"fto_ros": lambda: read_fto(bag), "fto_ros scan": lambda: read_fto(bag, False),
                       "rosbags": lambda: read_rosbags(bag),
                       "mcap raw": (lambda: read_mcap_raw(bag)) if make_reader else None,
                       "mcap-ros2": (lambda: read_mcap_ros2(bag)) if DecoderFactory else None}
            notes = {}
            for k, fn in readers.items():
                if fn is not None and not same_as(ref, fn(), types, decoded=k != "mcap raw"):
                    notes[k] = " DIFFERS"
            times = {k: None for k in read_cols}
            for _ in range(args.repeat):                  # in turn: the load hits all alike
                for k, fn in readers.items():
                    if fn is not None:
                        dt = _timed(fn)
                        times[k] = dt if times[k] is None else min(times[k], dt)
            read_rows.append(_row(bag.name, n, times, notes))
            for k, v in times.items():
                totals_r[k] = None if v is None else totals_r.get(k, 0.0) + v
            msgs = _messages(bag)
            rows = _in_time_order(msgs)
            writers = {"fto_ros block": lambda o: write_fto_block(msgs, o),
                       "fto_ros msg": lambda o: write_fto_msg(msgs, rows, o),
                       "rosbags": lambda o: write_rosbags(msgs, rows, o),
                       "mcap": (lambda o: write_mcap(msgs, rows, o)) if make_reader else None}
            wtimes = {k: None for k in write_cols}
            for rep in range(args.repeat):
                for k, fn in writers.items():
                    if fn is None:
                        continue
                    out = tmp / f"{k.replace(' ', '_')}_{rep}" / bag.name
                    out.parent.mkdir()
                    dt = _timed(lambda: fn(out))
                    wtimes[k] = dt if wtimes[k] is None else min(wtimes[k], dt)
                    shutil.rmtree(out.parent)
            write_rows.append(_row(bag.name, n, wtimes, {}))
            for k, v in wtimes.items():
                totals_w[k] = None if v is None else totals_w.get(k, 0.0) + v
            identical.append(_identical(msgs, rows, tmp / "same" / bag.name))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    total_n = sum(fast_info(b)[0].message_count for b in bags)
    print("\nReading: every topic, decoded (best of %d; ratio to the fastest)\n" % args.repeat)
    print("| bag | messages | " + " | ".join(read_cols) + " |")
    print("|---|---|" + "---|" * len(read_cols))
    print("\n".join(read_rows))
    print(_row("**all bags**", total_n, totals_r, {}))
    print("\nWriting: every message again, zstd chunks (best of %d; ratio to the fastest)\n"
          % args.repeat)
    print("| bag | messages | " + " | ".join(write_cols) + " |")
    print("|---|---|" + "---|" * len(write_cols))
    print("\n".join(write_rows))
    print(_row("**all bags**", total_n, totals_w, {}))
    same = sum(identical)
    print(f"\nfto_ros's bag equal to rosbags' byte for byte (MCAP and metadata.yaml, the "
          f"header's library name and the YAML emitter set alike): {same} of "
          f"{len(identical)} bags")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if same == len(identical) else 1


def _identical(msgs: dict, rows: list, out: Path) -> bool:
    """The same messages through fto_ros's writer (in rosbags' order, one at a time, with
    rosbags' YAML emitter) and through rosbags': the same bytes?"""
    from fto_ros.bag.mcap_write import McapBag, dump_yaml_as_rosbags
    ts = jazzy_typestore()
    a, b = out.parent / "rosbags" / out.name, out.parent / "fto" / out.name
    a.parent.mkdir(parents=True, exist_ok=True)
    b.mkdir(parents=True)
    write_rosbags(msgs, rows, a)
    bag = McapBag(b, library=f"rosbags-{version('rosbags')}", ros_distro="rosbags",
                  dump=dump_yaml_as_rosbags)
    cids = {topic: bag.add_connection(topic, m[0], ts.generate_msgdef(m[0], ros_version=2)[0],
                                      ts.hash_rihs01(m[0])) for topic, m in msgs.items()}
    for t, _k, topic, data in rows:
        bag.write(cids[topic], t, data)
    bag.close()
    return all((a / f).read_bytes() == (b / f).read_bytes()
               for f in (f"{out.name}.mcap", "metadata.yaml"))


if __name__ == "__main__":
    raise SystemExit(main())
