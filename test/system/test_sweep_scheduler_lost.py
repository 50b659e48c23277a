"""A Dask scheduler killed in the middle of a sweep (F18): the sweep ends with its results
tabulated (the runs it finished, and a row per run not done saying so), then one error
line, exit 1; no distributed traceback or log line on stderr.  The cluster is a
distributed.LocalCluster on 127.0.0.1 in a process of the test's own, killed with its
process group."""
from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
NOMINAL = REPO / "bags" / "dc_motor_nominal"
SINGLE_DELAY = REPO / "test" / "data" / "dc_motor_explicit" / "dc_motor_single_delay.yaml"

CLUSTER = '''
import time
import distributed
if __name__ == "__main__":
    c = distributed.LocalCluster(host="127.0.0.1", n_workers=1, threads_per_worker=1,
                                 processes=True, dashboard_address=None)
    print(c.scheduler_address, flush=True)
    while True:
        time.sleep(1)
'''


@pytest.mark.slow
def test_a_lost_scheduler_ends_the_sweep_with_one_line_beside_the_results(tmp_path):
    pytest.importorskip("distributed")
    (tmp_path / "cluster.py").write_text(CLUSTER)
    cluster = subprocess.Popen([sys.executable, "cluster.py"], cwd=tmp_path,
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                               start_new_session=True)
    try:
        address = cluster.stdout.readline().strip()
        assert address.startswith("tcp://127.0.0.1:"), address
        sweep = subprocess.Popen(
            [sys.executable, "-m", "fto_ros.sweep.cli", "--params", str(SINGLE_DELAY),
             "--bag", str(NOMINAL), "--set", "single_delay.k=100,110,120,130,140,150",
             "--set", "single_delay.tau=0.05,0.1", "--out", str(tmp_path / "out"),
             "--no-plots", "--scheduler", address],
            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        err = []
        deadline = time.monotonic() + 600
        for line in sweep.stderr:                   # the first finished run, then the kill
            err.append(line)
            if "[1/12]" in line or time.monotonic() > deadline:
                break
        os.killpg(cluster.pid, signal.SIGKILL)
        out, rest = sweep.communicate(timeout=300)
        err.append(rest)
    finally:
        if cluster.poll() is None:
            os.killpg(cluster.pid, signal.SIGKILL)
        cluster.wait(timeout=60)
    stderr = "".join(err)
    assert sweep.returncode == 1, stderr
    assert "Traceback" not in stderr and "distributed." not in stderr, stderr
    last = stderr.strip().splitlines()[-1]
    assert last.startswith(f"fto-sweep: error: lost the connection to the Dask scheduler at "
                           f"{address}") and "run(s) not done" in last
    with open(tmp_path / "out" / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 12
    assert any(r["status"] == "ok" for r in rows)
    assert any("not run: lost the connection" in r["error"] for r in rows)
    assert "wrote" in out and "results.csv" in out
