"""`colcon build` of fto_ros as an ament_python package, and a start of the installed node.

What a ROS user does: `colcon build`, `source install/local_setup.bash`, `ros2 run fto_ros
observer_node --ros-args --params-file ...`. Here colcon is Debian's (it runs
/usr/bin/python3, which has no rclpy) and rclpy comes from the pip wheels of the venv
running this test. setup.cfg's `[build_scripts] executable=/usr/bin/env python3` makes
the installed scripts run with the python3 first on PATH, so putting this venv's bin/
first on PATH is all it takes: the same as an activated venv on a ROS machine.
"""
import glob
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

import domains
import processes

pytestmark = [pytest.mark.slow, pytest.mark.live]   # live: it starts the installed node

REPO = Path(__file__).resolve().parents[2]
PKG = 'fto_ros'
# Every console script in setup.py must land in lib/fto_ros/ for `ros2 run`.
EXECUTABLES = ['observer_node', 'fto-observer', 'fto-replay', 'fto-simulate',
               'fto-play', 'fto-report']
# Only what the build needs: no bags, tests, venv or old build output.
NOT_COPIED = {'.git', '.venv', 'build', 'install', 'log', 'bags', 'benchmarks', 'test',
              'out', '.pytest_cache', '.hypothesis', '.ci'}


def _ignore(directory, names):
    top = Path(directory) == REPO
    return {n for n in names
            if (top and n in NOT_COPIED) or n == '__pycache__' or n.endswith('.egg-info')}


def _colcon_skip_reason():
    if shutil.which('colcon') is None:
        return 'colcon not installed (apt-get install colcon python3-colcon-ros)'
    # --log-base /dev/null: no log/ directory in the work tree.
    out = subprocess.run(
        ['colcon', '--log-base', os.devnull, 'extensions', 'colcon_core.task.build'],
        capture_output=True, text=True).stdout
    if 'ament_python' not in out:
        return 'colcon cannot build ament_python packages (apt-get install python3-colcon-ros)'
    return None


@pytest.fixture(scope='module')
def workspace():
    """A colcon workspace in a temp dir with fto_ros built into install/."""
    reason = _colcon_skip_reason()
    if reason:
        pytest.skip(reason)  # the reason shows in the summary (pytest.ini: -rfEs)
    with tempfile.TemporaryDirectory(prefix='fto_colcon_') as tmp:
        ws = Path(tmp)
        shutil.copytree(REPO, ws / 'src' / PKG, ignore=_ignore)
        env = dict(os.environ)
        for var in ('VIRTUAL_ENV', 'PYTHONPATH', 'PYTHONHOME'):  # colcon runs Debian's python
            env.pop(var, None)
        result = subprocess.run(
            ['colcon', 'build', '--packages-select', PKG, '--event-handlers', 'console_direct+'],
            cwd=ws, env=env, capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, f'colcon build failed:\n{result.stdout}\n{result.stderr}'
        yield ws


def _sourced_run(ws, cmd, **kwargs):
    """Run cmd after `source install/local_setup.bash`, this venv's python3 first on PATH, in a
    session of its own (test/support/processes.py); a node it starts stays on this machine,
    on a domain id of the test's own."""
    domain = domains.take()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(domain))
    env['PATH'] = f'{Path(sys.executable).parent}{os.pathsep}{env["PATH"]}'
    env.pop('PYTHONPATH', None)
    script = 'source install/local_setup.bash && exec "$@"'
    return processes.spawn(['bash', '-c', script, 'bash', *cmd], domain=domain, cwd=ws, env=env,
                           **kwargs)


def test_build_installs_ros_layout(workspace):
    prefix = workspace / 'install' / PKG
    assert (prefix / 'share/ament_index/resource_index/packages' / PKG).is_file()
    assert (prefix / 'share' / PKG / 'package.xml').is_file()
    for yaml in sorted((REPO / 'config').glob('*.yaml')):
        assert (prefix / 'share' / PKG / 'config' / yaml.name).is_file(), yaml.name
    for urdf in sorted((REPO / 'urdf').glob('*.urdf')):          # the example arm
        assert (prefix / 'share' / PKG / 'urdf' / urdf.name).is_file(), urdf.name
    # `ros2 launch fto_ros <file>` looks in share/fto_ros/launch
    launch_files = sorted((REPO / 'launch').glob('*.launch.py'))
    assert launch_files, 'no launch files in launch/'
    for launch in launch_files:
        installed = prefix / 'share' / PKG / 'launch' / launch.name
        assert installed.is_file(), f'share/{PKG}/launch/{launch.name} missing'
        assert installed.read_text() == launch.read_text(), launch.name
    for exe in EXECUTABLES:
        path = prefix / 'lib' / PKG / exe
        assert path.is_file() and os.access(path, os.X_OK), f'lib/{PKG}/{exe} missing'
        # Not /usr/bin/python3 (the interpreter colcon ran): that one has no rclpy.
        assert path.read_text().splitlines()[0] == '#!/usr/bin/env python3', exe


def test_build_installs_every_module(workspace):
    """A directory without __init__.py works from the editable install (pip -e) but is
    silently left out by find_packages(), i.e. by colcon: catch that here."""
    site = glob.glob(str(workspace / 'install' / PKG / 'lib' / 'python3*' / '*-packages'))
    assert len(site) == 1, site
    missing = [str(src.relative_to(REPO)) for src in sorted((REPO / PKG).rglob('*.py'))
               if '__pycache__' not in src.parts
               and not (Path(site[0]) / src.relative_to(REPO)).is_file()]
    assert not missing, ('not installed by colcon (is an __init__.py missing in their '
                         f'package directory?): {missing}')


def test_sourced_install_is_what_runs(workspace):
    """After sourcing, ament_index finds the package (as `ros2 run` does) and python
    imports fto_ros from install/, not from the work tree the venv has it editable in."""
    code = ('import fto_ros, ament_index_python as a; '
            'print(fto_ros.__file__); print(a.get_package_prefix("fto_ros"))')
    proc = _sourced_run(workspace, ['python3', '-c', code],
                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    module_file, prefix = out.split()[-2:]
    install = workspace / 'install' / PKG
    assert Path(module_file).is_relative_to(install), module_file
    assert Path(prefix) == install
    assert os.access(Path(prefix) / 'lib' / PKG / 'observer_node', os.X_OK)


def test_installed_observer_node_starts(workspace):
    """`lib/fto_ros/observer_node --ros-args --params-file ...` comes up (its observer's
    log line), keeps running (spinning) for 3 s, then stops cleanly on Ctrl-C (SIGINT)
    without a traceback.  The signal waits for the log line: sent while the interpreter
    still starts, before the node's own handler is in place, it is Python's to take, and
    a process started with SIGINT ignored (a CI runner's background job) keeps ignoring it."""
    if not (REPO / PKG / 'nodes' / 'observer_node.py').is_file():
        pytest.skip('fto_ros/nodes/observer_node.py does not exist yet')
    share = workspace / 'install' / PKG / 'share' / PKG / 'config'
    # the DC-motor plant file, then a tuning file (as several --params-file merge)
    params = [share / 'dc_motor_plant.yaml', share / 'dc_motor_single_delay.yaml']
    exe = workspace / 'install' / PKG / 'lib' / PKG / 'observer_node'
    with tempfile.TemporaryFile(mode='a+') as log:  # a file: a chatty node cannot block on a pipe;
        # 'a+' (O_APPEND): the node's writes go to the end while this test seeks and reads
        proc = _sourced_run(workspace, [str(exe), '--ros-args', '--params-file', str(params[0]),
                                        '--params-file', str(params[1])],
                            stdout=log, stderr=subprocess.STDOUT, text=True)
        try:
            up = time.monotonic() + 300.0          # a cold compile cache on a loaded machine
            while time.monotonic() < up and proc.poll() is None:
                log.seek(0)
                if 'observer: ' in log.read():
                    break
                time.sleep(0.2)
            deadline = time.monotonic() + 3.0
            while time.monotonic() < deadline and proc.poll() is None:
                time.sleep(0.1)
            running = proc.poll() is None
            code = processes.interrupt(proc, 15)     # Ctrl-C, then SIGKILL to the group
        finally:
            processes.interrupt(proc, 0)
        log.seek(0)
        out = log.read()
    assert running, f'observer_node exited with {proc.returncode} within 3 s:\n{out}'
    assert 'Traceback' not in out, f'observer_node did not stop cleanly on SIGINT:\n{out}'
    assert code in (0, -signal.SIGINT, 128 + signal.SIGINT), f'exit code {code}:\n{out}'
