"""The bag fast paths (fto_ros/bag/): the writer lays a bag out byte for byte as rosbags
would, its metadata says what rosbags would say, blocks read back as written, the fast reader
gives what rosbags reads on every committed bag, a damaged index falls back to the scan,
mixed layouts are left to rosbags, and a failed background write removes the bag."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from bag_samples import CLOCK, F64, JS, write_sample_bag
from fto_ros.bag import BagError, BagReader, BagWriter, bag_info, list_topics, read_messages

ROOT = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------- the fast paths
def _rosbags_raw(path: Path) -> dict:
    """topic -> [(log time, raw payload)] as rosbags reads them (its own order)."""
    with BagReader(path) as b:
        out = {c.topic: [] for c in b._reader.connections}
        for conn, t, raw in b._reader.messages(b._reader.connections):
            out[conn.topic].append((t, bytes(raw)))
    return out


def _write_sequence(rng, n_steps: int = 40):
    """A seeded mix of single messages, list blocks and matrix blocks on three topics,
    several MiB: chunks close inside blocks."""
    seq = []
    for _ in range(n_steps):
        i, n = int(rng.integers(3)), int(rng.integers(1, 3000))
        t = np.sort(rng.integers(0, 10 ** 10, n)).astype(np.uint64)
        r = rng.random()
        if r < 0.3:
            seq.append(("one", i, int(t[0]), rng.bytes(int(rng.integers(0, 90)))))
        elif r < 0.6:
            seq.append(("list", i, t, [rng.bytes(int(rng.integers(0, 50))) for _ in range(n)]))
        else:
            width = int(rng.integers(1, 90))
            seq.append(("matrix", i, t,
                        np.frombuffer(rng.bytes(n * width), np.uint8).reshape(n, width)))
    return seq


@pytest.mark.parametrize("compress,background", [(True, False), (False, False), (True, True)])
def test_writer_lays_out_the_bag_byte_for_byte_as_rosbags(tmp_path, compress, background):
    """The same messages, in the same order, through rosbags' writer (one at a time) and
    fto_ros's (blocks at once), given rosbags' YAML emitter: the same .mcap and
    metadata.yaml, byte for byte."""
    from importlib.metadata import version
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from fto_ros.bag.mcap_write import McapBag, dump_yaml_as_rosbags
    from fto_ros.bag.reader import jazzy_typestore
    ts = jazzy_typestore()
    topics = [("/a", F64), ("/b", CLOCK), ("/c", JS)]
    custom = {"k": "v 'quoted' \"twice\"", "json": '{"a": [1, 2]}'}
    ref, ours = tmp_path / "rosbags" / "bag", tmp_path / "fto_ros" / "bag"
    ref.parent.mkdir()
    ours.mkdir(parents=True)
    w = Writer(ref, version=9, storage_plugin=StoragePlugin.MCAP)
    if compress:
        w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for k, v in custom.items():
        w.set_custom_data(k, v)
    w.open()
    conns = [w.add_connection(t, m, typestore=ts) for t, m in topics]
    bag = McapBag(ours, compress=compress, library=f"rosbags-{version('rosbags')}",
                  ros_distro="rosbags", custom_data=custom, dump=dump_yaml_as_rosbags,
                  background=background)
    cids = [bag.add_connection(t, m, ts.generate_msgdef(m, ros_version=2)[0], ts.hash_rihs01(m))
            for t, m in topics]
    for kind, i, t, payloads in _write_sequence(np.random.default_rng(3)):
        if kind == "one":
            w.write(conns[i], t, payloads)
            bag.write(cids[i], t, payloads)
            continue
        for tt, p in zip(t.tolist(), payloads):
            w.write(conns[i], tt, bytes(p))
        bag.write_block(cids[i], t, payloads)
    w.close()
    bag.close()
    assert (ours / "bag.mcap").stat().st_size > 3 * (1 << 20)       # several chunks
    assert (ours / "bag.mcap").read_bytes() == (ref / "bag.mcap").read_bytes()
    assert (ours / "metadata.yaml").read_text() == (ref / "metadata.yaml").read_text()


def test_metadata_says_what_rosbags_would_say(tmp_path):
    """BagWriter's metadata.yaml (libyaml's emitter) holds the values rosbags' writer
    writes for the same bag (ros_distro apart), and the MCAP's copy of it too."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from fto_ros.bag.reader import jazzy_typestore
    import yaml
    ours = tmp_path / "ours"
    write_sample_bag(ours)
    ts = jazzy_typestore()
    ref = tmp_path / "ref"
    w = Writer(ref, version=9, storage_plugin=StoragePlugin.MCAP)
    w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    for k, v in {"k": "v", "json": '{"a": 1}'}.items():
        w.set_custom_data(k, v)
    w.open()
    conns = {}
    for topic, t, msg in read_messages(ours):
        if topic not in conns:
            conns[topic] = w.add_connection(topic, msg.__msgtype__, typestore=ts)
        w.write(conns[topic], t, ts.serialize_cdr(msg, msg.__msgtype__))
    w.close()
    a = yaml.safe_load((ours / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    b = yaml.safe_load((ref / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert a.pop("ros_distro") == "jazzy" and b.pop("ros_distro") == "rosbags"
    for meta in (a, b):
        meta["relative_file_paths"] = meta["files"][0]["path"] = "x.mcap"
    assert a == b
    with BagReader(ours) as r:                     # rosbags reads it, and its MCAP copy
        assert r.custom_data == {"k": "v", "json": '{"a": 1}'}


def test_write_block_is_read_back_as_written(tmp_path):
    path = tmp_path / "bag"
    rng = np.random.default_rng(5)
    data = np.frombuffer(rng.bytes(3000 * 40), np.uint8).reshape(3000, 40)
    t = np.arange(3000, dtype=np.int64) * 1000
    with BagWriter(path) as bag:
        bag.write_block("/m", F64, t, data)
        bag.write_block("/l", CLOCK, t[:5], [b"x" * k for k in range(5)])
        bag.clock(7)
        with pytest.raises(BagError, match="integer ns >= 0"):
            bag.write_block("/m", F64, np.array([-1]), data[:1])
        with pytest.raises(BagError, match="1 log times for 2"):
            bag.write_block("/m", F64, t[:1], data[:2])
        with pytest.raises(BagError, match="already has type"):
            bag.write_block("/l", F64, t[:1], data[:1])
    got = _rosbags_raw(path)
    assert got["/m"] == [(int(a), bytes(b)) for a, b in zip(t, data)]
    assert got["/l"] == [(int(a), b"x" * k) for k, a in enumerate(t[:5])]
    assert list_topics(path)["/clock"].count == 1


def _committed_bags():
    return sorted(p for p in (ROOT / "bags").iterdir() if p.is_dir())


@pytest.mark.parametrize("bag", _committed_bags(), ids=lambda p: p.name)
def test_fast_reader_gives_what_rosbags_reads_on_every_committed_bag(bag):
    """bag/mcap_scan.py (indexed and scanned) and the numpy decoders against rosbags:
    the same log times, payload bytes and, field by field, the same decoded values."""
    from fto_ros.bag.mcap_scan import fast_info, read_raw
    from fto_ros.core.cdr import JointStateDecoder, decode_float_block
    info, files = fast_info(bag)
    assert info == bag_info(bag)
    ref = _rosbags_raw(bag)
    for indexed in (True, False):
        got = read_raw(bag, list(info.topics), files, indexed=indexed)
        for topic, msgs in ref.items():
            t, payloads = got[topic]
            assert t.tolist() == [m[0] for m in msgs]
            assert list(payloads) == [m[1] for m in msgs]
    got = read_raw(bag, list(info.topics), files)
    with BagReader(bag) as b:
        decoded = {topic: [] for topic in info.topics}
        for topic, _, msg in b.messages():
            decoded[topic].append(msg)
    for topic, msgs in decoded.items():
        payloads = got[topic][1]
        assert payloads.matrix is not None        # one length per topic: no per-message path
        if info.topics[topic].msgtype == F64:
            np.testing.assert_array_equal(decode_float_block(payloads),
                                          np.array([m.data for m in msgs]))
        elif info.topics[topic].msgtype == JS:
            runs = JointStateDecoder().decode_block(payloads)
            assert len(runs) == 1                  # one layout: one run, no Python per message
            sec, nsec, js = runs[0]
            views = [js._replace(sec=int(a), nanosec=int(b), position=p, velocity=v, effort=e)
                     for a, b, p, v, e in zip(sec, nsec, js.position, js.velocity, js.effort)]
            assert len(views) == len(msgs)

            def fields(ms):
                return ([(m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id,
                          tuple(m.name)) for m in ms],
                        *(np.array([getattr(m, f) for m in ms]) for f in
                          ("position", "velocity", "effort")))
            for a, b in zip(fields(views), fields(msgs)):
                if isinstance(a, list):
                    assert a == b
                else:
                    assert a.dtype == b.dtype and a.shape == b.shape
                    np.testing.assert_array_equal(a, b)


def test_a_damaged_message_index_falls_back_to_the_scan(tmp_path):
    """An index entry that points at the wrong place is caught (the header it points at
    is checked) and the file is read record by record instead: the same messages."""
    from fto_ros.bag import mcap_scan
    path = tmp_path / "bag"
    write_sample_bag(path)
    mcap = next(path.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    _, _, chunks = mcap_scan._summary(bytes(data))
    at = next(iter(chunks[0][1].values()))             # a message index record
    data[at + 15 + 8] ^= 0x01                          # the first entry's offset, off by one
    mcap.write_bytes(bytes(data))
    with pytest.raises(mcap_scan.NotFast, match="message index"):
        mcap_scan._read_indexed(bytes(data), ["/clock", "/sys/y"])
    got = mcap_scan.read_raw(path, ["/clock", "/sys/y"])
    ref = _rosbags_raw(path)
    for topic in ("/clock", "/sys/y"):
        assert list(zip(got[topic][0].tolist(), got[topic][1])) == ref[topic]


def test_joint_states_of_mixed_layouts_are_decoded_as_runs_of_one_layout(tmp_path):
    from fto_ros.bag.mcap_scan import read_raw
    from fto_ros.core.cdr import JointStateDecoder
    path = tmp_path / "bag"
    with BagWriter(path) as bag:
        bag.joint_state("/j", 1, 1, ["a"], position=[1.0])
        bag.joint_state("/j", 2, 2, ["b"], position=[2.0])       # same length, other name
        bag.joint_state("/k", 1, 1, ["a", "b"], position=[1.0, 2.0], effort=[3.0, 4.0],
                        frame_id="base")
        bag.joint_state("/k", 2, 5, ["a", "b"], position=[5.0, 6.0], effort=[7.0, 8.0],
                        frame_id="base")
    raw = read_raw(path, ["/j", "/k"])
    runs = JointStateDecoder().decode_block(raw["/j"][1])      # one length, two layouts
    assert [(js.name, nsec.tolist(), js.position.tolist()) for _, nsec, js in runs] == \
        [(("a",), [1], [[1.0]]), (("b",), [2], [[2.0]])]
    (sec, nsec, js), = JointStateDecoder().decode_block(raw["/k"][1])
    assert (js.frame_id, nsec.tolist(), js.position.tolist(), js.velocity.shape,
            js.effort.tolist()) == ("base", [1, 5], [[1.0, 2.0], [5.0, 6.0]], (2, 0),
                                    [[3.0, 4.0], [7.0, 8.0]])


def test_a_failed_background_write_is_raised_and_the_bag_removed(tmp_path, monkeypatch):
    from fto_ros.bag import mcap_write

    def broken(data, level):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(mcap_write._zstd, "compress", broken)
    path = tmp_path / "bag"
    block = np.zeros((30000, 60), np.uint8)                    # > 1 MiB: a chunk closes
    with pytest.raises((OSError, BagError), match="No space left"):
        with BagWriter(path) as bag:
            bag.write_block("/a", F64, np.arange(30000), block)
    assert not path.exists()


def test_a_lone_mcap_file_is_replayed_through_the_fast_path(tmp_path):
    """A bag given as its .mcap file (no metadata.yaml beside it to read first) still goes
    through the fast reader, and gives the directory's replay."""
    from fto_ros.replay import replay
    params = [ROOT / "config" / "dc_motor_plant.yaml", ROOT / "config" / "dc_motor_luenberger.yaml"]
    lone = tmp_path / "nominal.mcap"
    shutil.copy(ROOT / "bags" / "dc_motor_nominal" / "dc_motor_nominal.mcap", lone)
    a = replay(lone, params, tmp_path / "a", plot=False, progress=False)
    b = replay(ROOT / "bags" / "dc_motor_nominal", params, tmp_path / "b", plot=False,
               progress=False)
    assert a["reader"] == b["reader"] == "MCAP fast path"
    for key in ("samples_accepted", "errors", "bag_duration_s", "output_topics"):
        assert a[key] == b[key], key
