"""rosbag2 (MCAP) writer/reader helpers and ``fto-simulate``. No ROS needed."""
from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fto_ros.bag import (BagError, BagReader, BagWriter, bag_info, list_topics,
                         read_messages)
from fto_ros.cli import simulate as cli
from fto_ros.core.output_dir import OutputError, OutputExists
from fto_ros.models import get_model
from fto_ros.models.simulate import simulate, uniform_grid

ROOT = Path(__file__).resolve().parents[1]
F64 = "std_msgs/msg/Float64MultiArray"
JS = "sensor_msgs/msg/JointState"
CLOCK = "rosgraph_msgs/msg/Clock"
DIAG = "diagnostic_msgs/msg/DiagnosticArray"
VALUES = [0.0, -0.0, 1.5, -2.25, 1e-300, 1.7976931348623157e308, math.pi, -1.0 / 3.0]


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def write_sample_bag(path: Path, **kw) -> None:
    with BagWriter(path, custom_data={"k": "v", "json": '{"a": 1}'}, **kw) as bag:
        bag.clock(0)
        bag.float_array("/sys/y", 0, VALUES)
        bag.joint_state("/sys/joint_states", 0, 0, ["joint1"], position=[0.5])
        bag.clock(1_000_000)
        bag.joint_state("/sys/joint_states", 1_000_000, 999_999_999_999, ["a", "b"],
                        position=[1.0, 2.0], velocity=[], effort=[-3.0, 4.5], frame_id="base")
        bag.float_array("/sys/empty", 1_000_000, [])
        bag.diagnostics("/diagnostics", 2_500_000_000, [
            {"level": "WARN", "name": "obs: status", "message": "converging",
             "hardware_id": "dc_motor", "values": {"samples": 12, "residual": 1.5e-3}},
            {"level": 0, "name": "second", "message": "", "values": [("x", "y")]},
        ], stamp_ns=2_400_000_000)
        bag.clock(2_500_000_000)


def test_round_trip_all_message_types(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path)
    assert (path / "metadata.yaml").is_file() and list(path.glob("*.mcap"))
    msgs = list(read_messages(path))
    assert [(topic, t) for topic, t, _ in msgs] == [
        ("/clock", 0), ("/sys/y", 0), ("/sys/joint_states", 0),
        ("/clock", 1_000_000), ("/sys/joint_states", 1_000_000), ("/sys/empty", 1_000_000),
        ("/diagnostics", 2_500_000_000), ("/clock", 2_500_000_000)]
    clk0, y, js0, clk1, js1, empty, diag, clk2 = (m for _, _, m in msgs)
    assert stamp_ns(clk0.clock) == 0 and stamp_ns(clk1.clock) == 1_000_000
    assert stamp_ns(clk2.clock) == 2_500_000_000
    assert clk2.clock.sec == 2 and clk2.clock.nanosec == 500_000_000
    assert y.__msgtype__ == F64 and y.data.dtype == np.float64
    assert y.data.tolist() == VALUES  # bit-exact
    assert math.copysign(1.0, y.data[1]) == -1.0
    assert list(empty.data) == []
    assert js0.name == ["joint1"] and js0.position.tolist() == [0.5]
    assert len(js0.velocity) == 0 and len(js0.effort) == 0
    assert stamp_ns(js1.header.stamp) == 999_999_999_999 and js1.header.frame_id == "base"
    assert js1.name == ["a", "b"] and js1.position.tolist() == [1.0, 2.0]
    assert js1.effort.tolist() == [-3.0, 4.5] and len(js1.velocity) == 0
    assert stamp_ns(diag.header.stamp) == 2_400_000_000
    s0, s1 = diag.status
    assert (s0.level, s0.name, s0.message, s0.hardware_id) == (1, "obs: status", "converging",
                                                               "dc_motor")
    assert [(kv.key, kv.value) for kv in s0.values] == [("samples", "12"), ("residual", "0.0015")]
    assert (s1.level, s1.name, [(kv.key, kv.value) for kv in s1.values]) == (0, "second",
                                                                             [("x", "y")])


def test_topics_info_and_custom_data(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path)
    assert list_topics(path) == {
        "/clock": (CLOCK, 3), "/diagnostics": (DIAG, 1), "/sys/empty": (F64, 1),
        "/sys/joint_states": (JS, 2), "/sys/y": (F64, 1)}
    info = bag_info(path)
    assert info.message_count == 8 and info.storage == "mcap"
    assert (info.start_ns, info.end_ns, info.duration_ns) == (0, 2_500_000_000, 2_500_000_000)
    assert info.custom_data == {"k": "v", "json": '{"a": 1}'}


def test_uncompressed_bag_and_filters(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path, compress=False)
    with BagReader(path) as bag:
        got = [(topic, t) for topic, t, _ in bag.messages(["/clock"], start_ns=1,
                                                          stop_ns=2_500_000_000)]
        assert got == [("/clock", 1_000_000)]
        with pytest.raises(BagError, match="no topic"):
            bag.messages(["/nope"])


def test_equal_log_times_keep_write_order_across_chunks(tmp_path):
    path = tmp_path / "bag"
    n = 20000  # several MCAP chunks
    with BagWriter(path) as bag:
        for k in range(n):
            bag.float_array("/a", k * 1000, [k])
            bag.float_array("/b", k * 1000, [-k])
    prev = None
    count = 0
    for topic, t, msg in read_messages(path):
        k = t // 1000
        expected = ("/a", k) if count % 2 == 0 else ("/b", -k)
        assert (topic, msg.data[0]) == expected
        assert prev is None or t >= prev
        prev = t
        count += 1
    assert count == 2 * n


def test_decodes_with_rclpy_when_available(tmp_path):
    """The CDR written here is what a ROS 2 Jazzy node deserializes."""
    pytest.importorskip("rclpy")
    try:
        from rclpy.serialization import deserialize_message
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
    except ImportError as err:  # ROS libraries not loadable here
        pytest.skip(f"rclpy messages unavailable: {err}")
    from rosbags.rosbag2 import Reader
    types = {F64: Float64MultiArray, JS: JointState, CLOCK: Clock, DIAG: DiagnosticArray}
    path = tmp_path / "bag"
    write_sample_bag(path)
    with Reader(path) as reader:
        decoded = [(c.topic, deserialize_message(bytes(raw), types[c.msgtype]))
                   for c, _, raw in reader.messages()]
    assert list(decoded[1][1].data) == VALUES
    assert list(decoded[4][1].effort) == [-3.0, 4.5]
    assert decoded[6][1].status[0].values[1].value == "0.0015"


# ------------------------------------------------------------------- errors
def test_missing_path(tmp_path):
    with pytest.raises(BagError, match="does not exist") as exc:
        read_messages(tmp_path / "nope")
    assert str(tmp_path / "nope") in str(exc.value)
    with pytest.raises(BagError):
        bag_info(tmp_path / "nope")


def test_directory_that_is_not_a_bag(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match="not a rosbag2 bag") as exc:
        BagReader(tmp_path)
    assert str(tmp_path) in str(exc.value)
    other = tmp_path / "notes.txt"
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        list_topics(other)


@pytest.mark.parametrize("keep", [0.0, 0.3, 0.9, 0.999])
def test_truncated_mcap(tmp_path, keep):
    path = tmp_path / "bag"
    write_sample_bag(path)
    mcap = next(path.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * keep)])
    with pytest.raises(BagError) as exc:
        list(read_messages(path))
    assert str(path) in str(exc.value) and "Traceback" not in str(exc.value)


def test_corrupt_chunk_and_metadata(tmp_path):
    path = tmp_path / "bag"
    with BagWriter(path) as bag:
        for k in range(5000):
            bag.float_array("/a", k, np.sin(np.arange(8) * k))
    mcap = next(path.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    mid = len(data) // 3
    data[mid:mid + 64] = b"\xa5" * 64
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError, match="corrupt") as exc:
        list(read_messages(path))
    assert str(path) in str(exc.value)
    (path / "metadata.yaml").write_text("rosbag2_bagfile_information: [")
    with pytest.raises(BagError, match="cannot open bag"):
        bag_info(path)


def test_existing_output_and_overwrite(tmp_path):
    path = tmp_path / "bag"
    write_sample_bag(path)
    with pytest.raises(OutputExists, match="exists already") as exc:
        BagWriter(path).open()
    assert str(path) in str(exc.value)
    with BagWriter(path, overwrite=True) as bag:
        bag.clock(5)
    assert list_topics(path) == {"/clock": (CLOCK, 1)}
    # a directory that is not a bag is never deleted
    src = tmp_path / "src"
    (src / "pkg").mkdir(parents=True)
    (src / "setup.py").write_text("")
    with pytest.raises(OutputError, match="refusing to replace"):
        BagWriter(src, overwrite=True).open()
    assert (src / "setup.py").exists()
    # an empty directory is fine
    empty = tmp_path / "empty"
    empty.mkdir()
    with BagWriter(empty, overwrite=True) as bag:
        bag.clock(1)


def test_writer_validation(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        with pytest.raises(BagError, match=">= 0"):
            bag.clock(-1)
        with pytest.raises(BagError, match="integer number of nanoseconds"):
            bag.float_array("/a", 0.5, [1.0])
        bag.float_array("/a", 1, [1.0])
        with pytest.raises(BagError, match="already has type"):
            bag.clock(2, topic="/a")
        with pytest.raises(BagError, match="2 values for 1 joint"):
            bag.joint_state("/j", 1, 1, ["j"], position=[1.0, 2.0])
        with pytest.raises(BagError, match="unknown level"):
            bag.diagnostics("/diagnostics", 1, [{"level": "FINE"}])
        with pytest.raises(BagError, match="absolute"):
            bag.float_array("relative", 1, [1.0])
    with pytest.raises(BagError, match="not open"):
        BagWriter(tmp_path / "other").float_array("/a", 0, [1.0])


def test_failed_write_removes_half_written_bag(tmp_path):
    path = tmp_path / "bag"
    with pytest.raises(RuntimeError):
        with BagWriter(path) as bag:
            bag.clock(1)
            raise RuntimeError("boom")
    assert not path.exists()


# ------------------------------------------------------------------- fto-simulate
def run_cli(*argv) -> int:
    return cli.main([str(a) for a in argv])


def test_simulate_cli_records_the_documented_topics(tmp_path, capsys):
    out = tmp_path / "dcm"
    assert run_cli("dc_motor", "--out", out, "--duration", 0.2) == 0
    assert "wrote" in capsys.readouterr().out
    assert list_topics(out) == {
        "/clock": (CLOCK, 201), "/dc_motor/input": (F64, 201),
        "/dc_motor/joint_states": (JS, 201), "/dc_motor/measured_output": (F64, 201),
        "/dc_motor/true_state": (F64, 201)}
    spec = get_model("dc_motor")
    t = uniform_grid(0.2, 1000.0)
    ref = simulate(spec.make_rhs(dict(spec.default_params)), spec.default_x0, t,
                   spec.default_input)
    rows: dict[str, list] = {}
    for topic, t_ns, msg in read_messages(out):
        rows.setdefault(topic, []).append((t_ns, msg))
    assert [t_ns for t_ns, _ in rows["/clock"]] == [k * 1_000_000 for k in range(201)]
    truth = np.array([m.data for _, m in rows["/dc_motor/true_state"]])
    np.testing.assert_array_equal(truth, ref.x)
    np.testing.assert_array_equal([m.data[0] for _, m in rows["/dc_motor/input"]], ref.u[:, 0])
    np.testing.assert_array_equal([m.data[0] for _, m in rows["/dc_motor/measured_output"]],
                                  ref.x[:, 0])  # no noise by default
    for t_ns, js in rows["/dc_motor/joint_states"]:
        assert stamp_ns(js.header.stamp) == t_ns and js.name == ["joint1"]
        assert len(js.velocity) == 0 and len(js.effort) == 0
    settings = json.loads(bag_info(out).custom_data[cli.METADATA_KEY])
    assert settings["model"] == "dc_motor" and settings["x0"] == [0.5, -1.0, 0.2]
    assert settings["params"]["a4"] == 200.0 and settings["seed"] == 0


def test_simulate_cli_sparse_noisy(tmp_path):
    out = tmp_path / "sparse"
    assert run_cli("dc_motor", "--out", out, "--duration", 1.0, "--noise", 1e-3,
                   "--uncertainty", "--seed", 5, "--sparse-min", 0.02, "--sparse-max", 0.05) == 0
    rows: dict[str, list] = {}
    for topic, t_ns, msg in read_messages(out):
        rows.setdefault(topic, []).append((t_ns, msg))
    t_meas = np.array([t for t, _ in rows["/dc_motor/measured_output"]])
    gaps = np.diff(t_meas)
    assert t_meas[0] == 0 and gaps.min() >= 20_000_000 and gaps.max() <= 50_000_000
    assert len(rows["/dc_motor/input"]) == 1001
    truth = {t: m.data for t, m in rows["/dc_motor/true_state"]}
    clock = {t for t, _ in rows["/clock"]}
    assert set(t_meas) <= set(truth) and set(t_meas) <= clock  # truth wherever y exists
    err = np.array([m.data[0] - truth[t][0] for t, m in rows["/dc_motor/measured_output"]])
    assert 0 < np.abs(err).max() < 6e-3
    settings = json.loads(bag_info(out).custom_data[cli.METADATA_KEY])
    assert settings["measurement_sampling"]["mode"] == "sparse"
    assert settings["uncertainty"]["enabled"] is True
    assert settings["measurement_noise"]["sigma"] == 1e-3
    # same seed, same bag contents
    out2 = tmp_path / "sparse2"
    assert run_cli("dc_motor", "--out", out2, "--duration", 1.0, "--noise", 1e-3,
                   "--uncertainty", "--seed", 5, "--sparse-min", 0.02, "--sparse-max", 0.05) == 0
    a = [(tp, t, list(m.data)) for tp, t, m in read_messages(out, ["/dc_motor/measured_output"])]
    b = [(tp, t, list(m.data)) for tp, t, m in read_messages(out2, ["/dc_motor/measured_output"])]
    assert a == b


def test_simulate_cli_sample_times_file(tmp_path):
    times = tmp_path / "times.txt"
    times.write_text("# instants\n0.0, 0.0105\n0.05 0.1234\n")
    out = tmp_path / "file"
    assert run_cli("dc_motor", "--out", out, "--duration", 0.2, "--sample-times", times) == 0
    got = [t for _, t, _ in read_messages(out, ["/dc_motor/joint_states"])]
    assert got == [0, 10_500_000, 50_000_000, 123_400_000]


@pytest.mark.parametrize("argv,message", [
    (["nope", "--out", "X"], "unknown model 'nope'; known models: "),
    (["dc_motor"], "--out"),
    (["dc_motor", "--out", "X", "--duration", "-1"], "--duration"),
    (["dc_motor", "--out", "X", "--rate", "abc"], "--rate"),
    (["dc_motor", "--out", "X", "--noise", "-0.1"], "--noise"),
    (["dc_motor", "--out", "X", "--sparse-min", "0.1"], "together"),
    (["dc_motor", "--out", "X", "--sparse-min", "0.2", "--sparse-max", "0.1"], "<="),
    (["dc_motor", "--out", "X", "--sparse-min", "0.1", "--sparse-max", "0.2",
      "--sample-times", "f"], "mutually exclusive"),
])
def test_simulate_cli_bad_arguments_exit_2(tmp_path, capsys, argv, message):
    argv = [str(tmp_path / a) if a == "X" else a for a in argv]
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "X").exists()


def test_simulate_cli_existing_output(tmp_path, capsys):
    out = tmp_path / "dcm"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert run_cli("dc_motor", "--out", out, "--duration", 0.01) == 1
    assert "exists already" in capsys.readouterr().err
    assert run_cli("dc_motor", "--out", out, "--duration", 0.01, "--overwrite") == 2
    assert "refusing to replace" in capsys.readouterr().err
    assert (out / "keep.txt").exists()
    shutil.rmtree(out)
    assert run_cli("dc_motor", "--out", out, "--duration", 0.01) == 0
    assert run_cli("dc_motor", "--out", out, "--duration", 0.02, "--overwrite") == 0
    assert list_topics(out)["/clock"].count == 21


def test_simulate_runs_as_module(tmp_path):
    out = tmp_path / "m"
    proc = subprocess.run([sys.executable, "-m", "fto_ros.cli.simulate", "dc_motor", "--out",
                           str(out), "--duration", "0.05"], cwd=ROOT, capture_output=True,
                          text=True)
    assert proc.returncode == 0, proc.stderr
    assert "/dc_motor/true_state 51" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "fto_ros.cli.simulate", "nope", "--out",
                           str(out)], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 2 and "unknown model" in proc.stderr and "dc_motor" in proc.stderr


def test_bag_layer_imports_no_rclpy():
    code = ("import sys, fto_ros.bag, fto_ros.cli.simulate; "
            "sys.exit(1 if 'rclpy' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT).returncode == 0


def test_simulate_cli_state_jump(tmp_path, capsys):
    """--state-jump: the state jumps by DELTA at T (the sample at T sees it), nothing else
    changes before T, the metadata records it; bad values are refused (exit 2)."""
    plain, jump = tmp_path / "plain", tmp_path / "jump"
    assert run_cli("dc_motor", "--out", plain, "--duration", 0.3) == 0
    assert run_cli("dc_motor", "--out", jump, "--duration", 0.3,
                   "--state-jump", "0.15,q_dot,4") == 0
    a, b = ({t: np.array(m.data) for topic, t, m in read_messages(p)
             if topic == "/dc_motor/true_state"} for p in (plain, jump))
    t_j = 150_000_000
    assert all(np.array_equal(a[t], b[t]) for t in a if t < t_j)
    assert b[t_j][1] - a[t_j][1] == pytest.approx(4.0, abs=1e-9)
    assert b[t_j][0] == pytest.approx(a[t_j][0], abs=1e-12)       # q itself does not jump
    settings = json.loads(bag_info(jump).custom_data[cli.METADATA_KEY])
    assert settings["state_jumps"] == [{"t": 0.15, "state": "q_dot", "delta": 4.0}]
    capsys.readouterr()
    for bad in ("0.15,speed,4", "0.15,q_dot", "9.0,q_dot,1", "0.1,7,1", "nan,q_dot,1"):
        with pytest.raises(SystemExit) as exc:
            run_cli("dc_motor", "--out", tmp_path / "bad", "--duration", 0.3, "--state-jump", bad)
        assert exc.value.code == 2
        assert "--state-jump" in capsys.readouterr().err


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
