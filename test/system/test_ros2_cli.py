"""The package under the real ROS 2 Jazzy command line (test/support/ros2_cli.py): every launch file
run by `ros2 launch`, the parameters through `ros2 param dump/get/describe/set`, the managed
node through `ros2 lifecycle`.  Skipped, with the reason, where the tools' folder is absent.
Processes as in test/support/live_node.py (LOCALHOST discovery, a domain id of the test's own); the
CLI never starts a ros2 daemon (--no-daemon)."""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")
from sensor_msgs.msg import JointState  # noqa: E402

import ros2_cli  # noqa: E402
from faultkit import COUNTS  # noqa: E402
import domains  # noqa: E402
import live_node as L  # noqa: E402
from live_node import NODE, ROOT, Driver, NodeProcess  # noqa: E402

#: live DDS nodes: scripts/run-tests runs these after the rest, one at a time
pytestmark = [pytest.mark.live, pytest.mark.slow]

LAUNCH = ROOT / "launch"
CONFIG = ROOT / "config"
#: a start on a loaded 2-core machine (sympy, scipy, numba imports) takes up to ~20 s
START_S = 90


@pytest.fixture(scope="module")
def plant():
    return L.simulate(1.0)


@pytest.fixture(scope="module")
def prefix(tmp_path_factory):
    ros2_cli.ros2_command()                  # installs, or skips with the reason
    return ros2_cli.ament_prefix(tmp_path_factory.mktemp("ament_prefix"))


def _env(domain: int, tmp: Path, prefix: Path) -> dict:
    return ros2_cli.env_for(L.ros_env(domain, tmp), prefix)


def _launch(env: dict, tmp: Path, domain: int, *args: str) -> NodeProcess:
    """`ros2 launch ARGS` as a subprocess (stop() is Ctrl-C)."""
    return NodeProcess(tmp, domain, None, cmd=ros2_cli.argv("launch", *args), env=env)


def _default_config(path: Path) -> Path:
    """The params file an example launch file starts without arguments."""
    from test_launch_files import config_prefix, declared
    default, _ = declared(path)["observer"]
    return CONFIG / f"{config_prefix(path)}{default}.yaml"


def _observer_type(config: Path) -> str:
    doc = yaml.safe_load(config.read_text())
    return next(b["ros__parameters"]["observer"]["type"] for b in doc.values()
                if isinstance(b, dict) and "observer" in b.get("ros__parameters", {}))


def _cases():
    main = ("observer.launch.py", f"params_file:={CONFIG / 'dc_motor_single_delay.yaml'}")
    out = [pytest.param(main, "single_delay", id="observer.launch.py"),
           pytest.param(main + ("managed:=true",), "single_delay", id="observer.launch.py-managed")]
    for path in sorted(LAUNCH.glob("*.launch.py")):
        if path.name == "arm7_external_torque.launch.py":     # test/system/test_arm_node_live.py
            continue
        if path.name != "observer.launch.py":
            out.append(pytest.param((path.name,), _observer_type(_default_config(path)),
                                    id=path.name))
    return out


@pytest.mark.parametrize("args, observer", _cases())
def test_every_launch_file_starts_its_observer_under_ros2_launch(tmp_path, prefix, args, observer):
    """`ros2 launch fto_ros FILE` starts the node, which reports its observer on /diagnostics;
    Ctrl-C ends everything cleanly (exit 0, no traceback)."""
    domain = domains.take()
    launch = _launch(_env(domain, tmp_path, prefix), tmp_path, domain, "fto_ros", *args)
    driver = Driver(domain, outputs=())
    try:
        st = driver.wait_for(driver.last_status, START_S, f"the node of {args[0]}", launch)
        assert st["values"]["observer"] == observer, st["values"]
        COUNTS["live_ros2_launch"] += 1
    finally:
        driver.close()
        code = launch.stop()
    log = launch.log()
    assert code == 0, log
    assert "Traceback" not in log and "[ERROR]" not in log, log
    assert "process has finished cleanly" in log, log


def test_ros2_param_dump_get_describe_and_set(tmp_path, prefix):
    """Every declared parameter has a value for `ros2 param dump`/`get` (unset ones were
    declared without one: rclpy then answered no request naming them and dump printed {});
    a run-time change that cannot build an observer is refused with the reason by `ros2 param
    set` and the old observer runs on."""
    domain = domains.take()
    env = _env(domain, tmp_path, prefix)
    node = NodeProcess(tmp_path, domain, CONFIG / "dc_motor_plant.yaml",
                       "--params-file", str(CONFIG / "dc_motor_single_delay.yaml"),
                       "-p", "diagnostics.period:=0.2")
    driver = Driver(domain, outputs=())
    try:
        driver.wait_for(driver.last_status, START_S, "the node", node)
        dump = ros2_cli.run(env, "param", "dump", NODE)
        assert dump.returncode == 0, dump.stdout
        params = yaml.safe_load(dump.stdout)[NODE]["ros__parameters"]
        flat = _flatten(params)
        listed = ros2_cli.run(env, "param", "list", NODE).stdout.split()
        names = [n for n in listed if not n.endswith(":")]
        assert len(names) > 60 and set(names) <= set(flat), sorted(set(names) - set(flat))
        assert flat["single_delay.tau"] == 0.1 and flat["observer.initial_estimate"] == []
        assert flat["joint_states.input_joints"] == [] and flat["single_delay.n_unmeasured"] is None
        got = ros2_cli.run(env, "param", "get", NODE, "single_delay.A1")   # derived: unset, listed
        assert got.returncode == 0, got.stdout
        got = ros2_cli.run(env, "param", "get", NODE, "single_delay.tau")
        assert got.stdout.strip() == "Double value is: 0.1", got.stdout
        desc = ros2_cli.run(env, "param", "describe", NODE, "single_delay.tau").stdout
        assert "Type: double" in desc and "guaranteed convergence time" in desc, desc
        desc = ros2_cli.run(env, "param", "describe", NODE, "single_delay.n_unmeasured").stdout
        assert "type int, unset" in desc, desc
        # a run-time change that builds: taken
        res = ros2_cli.run(env, "param", "set", NODE, "single_delay.tau", "0.15")
        assert "Set parameter successful" in res.stdout, res.stdout
        driver.status_where(lambda s: s["values"].get("tau (guaranteed convergence time, s)") == "0.15",
                            20, "tau = 0.15", node)
        # ... and ones that cannot build an observer: refused with the reason, the node lives on
        for name, value in (("single_delay.tau", "1.0e+6"), ("single_delay.k", "1.0e+308")):
            res = ros2_cli.run(env, "param", "set", NODE, name, value)
            reason = res.stdout.partition("Setting parameter failed:")[2].strip()
            assert reason, res.stdout                      # refused, with the reason
            node.check_alive()
            COUNTS["live_param_extreme"] += 1
        got = ros2_cli.run(env, "param", "get", NODE, "single_delay.tau")
        assert got.stdout.strip() == "Double value is: 0.15", got.stdout
        st = driver.status_where(lambda s: True, 20, "a status after the refusals", node)
        assert st["values"]["tau (guaranteed convergence time, s)"] == "0.15", st["values"]
        assert "refused" in node.log() and "Traceback" not in node.log()
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def _cli_state(env) -> str:
    res = ros2_cli.run(env, "lifecycle", "get", NODE)
    assert res.returncode == 0, res.stdout
    return res.stdout.split()[0]


def test_ros2_lifecycle_drives_the_managed_node_and_configure_after_cleanup(tmp_path, prefix, plant):
    """`ros2 launch ... managed:=true autostart:=false`, then `ros2 lifecycle set` through
    configure, activate, deactivate, cleanup, configure again (it used to fail silently after
    cleanup), activate: estimates flow; a transition the state lacks, asked for by id through
    `ros2 service call` (which `ros2 lifecycle set` refuses before calling), is refused with a
    log line and the node lives on; shutdown ends in finalized."""
    domain = domains.take()
    env = _env(domain, tmp_path, prefix)
    params = L.params_file(tmp_path, "managed", lambda p: p["diagnostics"].update(
        period=0.2, expected_rate=0.0))
    launch = _launch(env, tmp_path, domain, "fto_ros", "observer.launch.py",
                     f"params_file:={params}", "managed:=true", "autostart:=false")
    driver = Driver(domain)
    try:
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/transition_event") > 0,
                        START_S, "the managed node", launch)
        assert _cli_state(env) == "unconfigured"
        res = ros2_cli.run(env, "lifecycle", "set", NODE, "activate")
        assert "Unknown transition requested" in res.stdout, res.stdout
        res = ros2_cli.run(env, "service", "call", NODE + "/change_state",
                           "lifecycle_msgs/srv/ChangeState", "{transition: {id: 3}}")
        assert "success=False" in res.stdout, res.stdout
        for transition, state in (("configure", "inactive"), ("activate", "active"),
                                  ("deactivate", "inactive"), ("cleanup", "unconfigured"),
                                  ("configure", "inactive"), ("activate", "active")):
            res = ros2_cli.run(env, "lifecycle", "set", NODE, transition)
            assert "Transitioning successful" in res.stdout, (transition, res.stdout)
            assert _cli_state(env) == state, transition
            COUNTS["live_lifecycle_cli"] += 1
        driver.wait_connected(launch, [driver.pub_y, driver.pub_u])
        L.feed(driver, plant, 200)
        st = driver.status_where(lambda s: L.count(s, "samples accepted") >= 100, 20,
                                 "estimates after configure-after-cleanup", launch)
        assert driver.got("state_estimate"), st
        res = ros2_cli.run(env, "lifecycle", "set", NODE, "shutdown")
        assert "Transitioning successful" in res.stdout, res.stdout
        assert _cli_state(env) == "finalized"
        launch.check_alive()
    finally:
        driver.close()
        code = launch.stop()
    log = launch.log()
    assert code == 0 and "Traceback" not in log, log
    assert "transition id 3 refused in state 'unconfigured'" in log, log


def test_state_stamped_frame_id_changes_at_run_time(tmp_path, prefix):
    """`ros2 param set output.frame_id` takes effect on the stamped outputs at once, without a
    restart; the publishers' QoS is overridable (read-only qos_overrides parameters)."""
    domain = domains.take()
    env = _env(domain, tmp_path, prefix)

    def edit(p):
        p["source"] = "joint_states"
        p["joint_states"].update(input_joints=["joint1"], input_field="effort")
        p["diagnostics"].update(period=0.2, expected_rate=0.0)
        p["output"] = {"frame_id": "before"}
    node = NodeProcess(tmp_path, domain, L.params_file(tmp_path, "frame", edit),
                       "-p", f"qos_overrides.{NODE}/state_estimate_stamped.publisher.depth:=50")
    driver = Driver(domain, outputs=())
    frames: list = []
    driver.node.create_subscription(JointState, NODE + "/state_estimate_stamped",
                                    lambda m: frames.append(m.header.frame_id), 100)
    try:
        driver.wait_for(lambda: driver.node.count_publishers(NODE + "/state_estimate_stamped"),
                        START_S, "the stamped publisher", node)
        import time
        base = time.time_ns() - 10**9
        m = JointState(name=["joint1"], position=[0.5], velocity=[0.0], effort=[2.0])
        sent = [0]

        def feed(n):                        # the next n samples, 2 ms apart
            for _ in range(n):
                ns = base + sent[0] * 2 * 10**6
                m.header.stamp.sec, m.header.stamp.nanosec = ns // 10**9, ns % 10**9
                driver.pub_js.publish(m)
                sent[0] += 1
                time.sleep(0.002)
        driver.wait_for(lambda: (feed(20), frames)[1], 30, "stamped estimates", node)
        assert set(frames) == {"before"}
        res = ros2_cli.run(env, "param", "set", NODE, "output.frame_id", "after")
        assert "Set parameter successful" in res.stdout, res.stdout
        n = len(frames)
        driver.wait_for(lambda: (feed(20), "after" in frames[n:])[1], 30, "the new frame", node)
        st = driver.status_where(lambda s: True, 10, "a status", node)
        assert "restarts: reconfigure" not in st["values"], st["values"]
        got = ros2_cli.run(env, "param", "get", NODE,
                           f"qos_overrides.{NODE}/state_estimate_stamped.publisher.depth")
        assert got.stdout.strip() == "Integer value is: 50", got.stdout
        res = ros2_cli.run(env, "param", "set", NODE,
                           f"qos_overrides.{NODE}/state_estimate_stamped.publisher.depth", "5")
        assert "read-only" in res.stdout.lower() or "failed" in res.stdout.lower(), res.stdout
    finally:
        driver.close()
        code = node.stop()
    assert code == 0, node.log()
