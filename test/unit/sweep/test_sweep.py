"""fto-sweep: the grid, the engine (this process, local worker processes, a Dask cluster), the
results, the command line's exit codes, and the main job (fto-report) on the same engine.

The sweeps replay the committed 5 s, 1 kHz DC-motor bags (about 0.3 s each on a quiet
machine) with the single_delay config: single_delay.k = 50 is refused by the observer (an
unstable internal mode: k > 98.6 is needed), so every grid with it has error rows.  The
Dask tests start a LocalCluster listening on 127.0.0.1 only, without a dashboard.
"""
from __future__ import annotations

import csv
import math
import operator
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from fto_ros.core.errors import ConfigError
from fto_ros.runner import Runner
from fto_ros.runner.params_file import load_params_files
from fto_ros.sweep import cli, engine as E, grid, results

REPO = Path(__file__).resolve().parents[3]
NOMINAL = REPO / "bags" / "dc_motor_nominal"
NOISY = REPO / "bags" / "dc_motor_noisy"
SINGLE_DELAY = REPO / "test" / "data" / "dc_motor_explicit" / "dc_motor_single_delay.yaml"
LUENBERGER = REPO / "test" / "data" / "dc_motor_explicit" / "dc_motor_luenberger.yaml"


def sweep_args(out: Path, *extra: str, bags=(NOMINAL,)) -> list[str]:
    args = ["--params", str(SINGLE_DELAY), "--set", "single_delay.k=50,100",
            "--set", "single_delay.tau=0.05,0.1", "--baseline", str(LUENBERGER),
            "--out", str(out), "--quiet"]
    for b in bags:
        args += ["--bag", str(b)]
    return args + list(extra)


def read_rows(out: Path) -> list[dict]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def without_timing(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in results.TIMING_COLUMNS} for r in rows]


@pytest.fixture(scope="module")
def sequential(tmp_path_factory):
    """The reference sweep: every run one after the other in this process."""
    out = tmp_path_factory.mktemp("sweep") / "sequential"
    assert cli.main(sweep_args(out, "--workers", "1")) == 0
    return out


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(host="127.0.0.1", n_workers=2, threads_per_worker=1,
                                  processes=True, dashboard_address=None) as c:
        yield c.scheduler_address


# ------------------------------------------------------------------------------ the grid
def test_values_split_on_commas_outside_brackets_and_quotes():
    assert grid.split_values("0.05, 0.1,0.2") == ["0.05", "0.1", "0.2"]
    assert grid.split_values("[1.0, 2.0],[3.0, 4.0]") == ["[1.0, 2.0]", "[3.0, 4.0]"]
    assert grid.split_values("'a,b',\"c,d\",{x: 1, y: 2}") == ["'a,b'", '"c,d"', "{x: 1, y: 2}"]
    for bad in ("[1, 2", "1]", "'open"):
        with pytest.raises(ValueError):
            grid.split_values(bad)


def test_axis_values_are_read_as_ros_reads_them():
    axis = grid.parse_axis("luenberger.process_noise=[1.0e-6, 0.25, 0.04],[1.0e-6, 1.0, 0.04]")
    assert axis.values == ([1e-6, 0.25, 0.04], [1e-6, 1.0, 0.04])
    assert axis.texts == ("[1.0e-6, 0.25, 0.04]", "[1.0e-6, 1.0, 0.04]")
    axis = grid.parse_axis("single_delay.tau = 0.05, 1, true, abc")
    assert axis.name == "single_delay.tau" and axis.values == (0.05, 1, True, "abc")
    for bad, why in [("single_delay.tau", "NAME=V1"), ("=1,2", "NAME=V1"),
                     ("single_delay.tau=0.1,,0.2", "empty value"),
                     ("single_delay.tau=0.1,0.1", "given twice"),
                     ("single_delay.tau=[1, 2.0]", "mixes integers"),
                     ("single_delay.tau={a: 1}", "mapping"),
                     ("single_delay.tau=[1, 2", "unclosed")]:
        with pytest.raises(ConfigError, match=why):
            grid.parse_axis(bad)
    with pytest.raises(ConfigError, match="two --set"):
        grid.parse_axes(["single_delay.tau=1", "single_delay.tau=2"])


def test_grid_is_every_combination_first_axis_slowest():
    axes = grid.parse_axes(["a.x=1,2", "a.y=p,q,r"])
    settings = grid.expand(axes)
    assert [s.label() for s in settings] == [
        "a.x=1 a.y=p", "a.x=1 a.y=q", "a.x=1 a.y=r", "a.x=2 a.y=p", "a.x=2 a.y=q", "a.x=2 a.y=r"]
    assert settings[4].overrides == {"a.x": 2, "a.y": "q"}
    assert [s.label() for s in grid.expand([])] == ["(params as given)"]


def test_swept_names_must_be_parameters_of_the_observer():
    flat = {"observer.type": "single_delay", "single_delay.tau": 0.1, "plant.constants.k": 1.0}
    grid.check_axes(grid.parse_axes(["single_delay.k=1,2", "time.max_gap=0.1",
                                     "plant.constants.k=1,2"]), flat)
    with pytest.raises(ConfigError, match="'single_delay.taux': unknown parameter"):
        grid.check_axes(grid.parse_axes(["single_delay.taux=1"]), flat)
    with pytest.raises(ConfigError, match="unknown parameter for observer type single_delay"):
        grid.check_axes(grid.parse_axes(["luenberger.design=poles"]), flat)
    # sweeping the observer type makes each type's parameters known
    grid.check_axes(grid.parse_axes(["observer.type=single_delay,luenberger",
                                     "luenberger.design=poles"]), flat)
    with pytest.raises(ConfigError, match="observer.type"):
        grid.check_axes([], {"single_delay.tau": 0.1})


# --------------------------------------------------------------------------- the results
def test_pareto_front_keeps_the_settings_nothing_beats_on_both():
    pts = [(0.1, 5.0), (0.2, 1.0), (0.3, 2.0), (0.05, 9.0), (math.inf, 0.5), (0.2, 1.0)]
    assert results.pareto_front(pts) == [3, 0, 1, 4]
    assert results.pareto_front([]) == []


def _row(bag, setting, score, conv, run, role=results.SWEEP, kind=None):
    return {"bag": bag, "_setting": setting, "mean_rms_err": score, "convergence_time_s": conv,
            "run": run, "role": role, "status": "ok" if kind is None else "error",
            "_kind": kind}


def test_best_is_least_mean_rms_then_earliest_convergence():
    rows = [_row("b1", "s1", 1.0, 0.5, 0), _row("b1", "s2", 1.0, 0.2, 1),
            _row("b1", "s3", 3.0, 0.1, 2), _row("b2", "s1", 1.0, 0.1, 3),
            _row("b2", "s2", 2.0, 0.1, 4), _row("b2", "s3", None, None, 5, kind="config"),
            _row("b1", "base", 0.1, 0.1, 6, role=results.BASELINE)]
    best = results.best_per_bag(rows)
    assert best["b1"]["_setting"] == "s2" and best["b2"]["_setting"] == "s1"
    overall = results.best_overall(rows)   # s3 failed on b2: not judged on every bag
    assert overall["setting"] == "s1" and overall["mean_rms_err"] == 1.0
    assert [a["setting"] for a in results.aggregate(rows)] == ["s1", "s2"]


def test_exit_code_of_a_sweep():
    ok, refused = _row("b", "s", 1.0, 0.1, 0), _row("b", "t", None, None, 1, kind="config")
    bad_bag = _row("b", "u", None, None, 2, kind="bag")
    assert results.exit_code([ok, refused]) == 0
    assert results.exit_code([refused]) == 2
    assert results.exit_code([ok, bad_bag]) == 1


# ---------------------------------------------------------------------------- the engine
def test_engine_returns_results_in_order_and_failures_as_values():
    calls = [(math.sqrt, 4.0), (math.sqrt, -1.0), (math.sqrt, 9.0)]
    seen = []
    with E.Engine(workers=1) as eng:
        out = eng.map(operator.call, calls, costs=[1, 2, 3], on_done=lambda i, r: seen.append(i))
    assert out[0] == 2.0 and out[2] == 3.0
    assert isinstance(out[1], E.Lost) and "ValueError" in out[1].message
    assert seen == [2, 1, 0]   # the costliest first


@pytest.mark.timeout(120)
def test_a_dying_local_worker_loses_only_its_task():
    """100 times (~5 s): the pool that a dying worker broke used to hang within 1-25 rounds
    (CPython 3.11 joined the surviving worker, which waited on its call queue for ever);
    pytest-timeout fails the test instead of the run hanging."""
    calls = [(math.sqrt, 4.0), (os._exit, 3), (math.sqrt, 9.0), (math.sqrt, 16.0)]
    for _ in range(100):
        with E.Engine(workers=2) as eng:
            out = eng.map(operator.call, calls)
        assert out[0] == 2.0 and out[2] == 3.0 and out[3] == 4.0
        assert isinstance(out[1], E.Lost) and "died" in out[1].message


# ------------------------------------------------------------------------ the sweep's CLI
def test_sweep_rows_errors_summary_and_figures(sequential):
    rows = read_rows(sequential)
    assert [(r["role"], r["single_delay.k"], r["single_delay.tau"]) for r in rows] == [
        ("sweep", "50", "0.05"), ("sweep", "50", "0.1"), ("sweep", "100", "0.05"),
        ("sweep", "100", "0.1"), ("baseline", "", "")]
    head = list(rows[0])
    assert head[:4] == ["bag", "params", "single_delay.k", "single_delay.tau"]
    for r in rows[:2]:   # k = 50: refused by the observer, a row with its error
        assert r["status"] == "error" and "single_delay.k" in r["error"]
        assert "\n" not in r["error"] and r["mean_rms_err"] == ""
    for r in rows[2:]:
        assert r["status"] == "ok" and r["error"] == ""
        rms = [float(r[f"rms_err.{s}"]) for s in ("q", "q_dot", "current")]
        assert float(r["mean_rms_err"]) == pytest.approx(sum(rms) / 3)
        assert float(r["convergence_time_s"]) < 0.2 and r["rejected"] == "0"
    assert rows[4]["observer"] == "luenberger" and rows[4]["params"] == str(LUENBERGER)
    # single_delay is exact after tau: the guaranteed time is the swept tau
    assert [float(r["guaranteed_time_s"]) for r in rows[2:4]] == [0.05, 0.1]
    summary = (sequential / "summary.txt").read_text()
    best = min(rows[2:4], key=lambda r: float(r["mean_rms_err"]))
    assert f"single_delay.k=100 single_delay.tau={best['single_delay.tau']}:" in summary
    assert "baseline" in summary and "failed runs (2" in summary
    for name in ("error_vs_single_delay.k.png", "error_vs_single_delay.tau.png", "pareto.png"):
        assert (sequential / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_local_pool_and_dask_cluster_give_the_sequential_results(sequential, cluster, tmp_path):
    reference = without_timing(read_rows(sequential))
    for name, extra in [("pool", ["--workers", "2"]),
                        ("dask", ["--scheduler", cluster]),
                        ("dask_send", ["--scheduler", cluster, "--data", "send"])]:
        out = tmp_path / name
        assert cli.main(sweep_args(out, *extra)) == 0, name
        assert without_timing(read_rows(out)) == reference, name


@pytest.mark.slow
def test_sweep_over_two_bags_keeps_runs_and_ranks_over_all_bags(tmp_path):
    out = tmp_path / "two"
    assert cli.main(sweep_args(out, "--keep-runs", bags=(NOMINAL, NOISY))) == 0
    rows = read_rows(out)
    assert len(rows) == 2 * 4 + 2
    kept = sorted(p.name for p in (out / "runs").iterdir())
    # the refused runs (k = 50: 0, 1, 4, 5) never started a replay: nothing to keep
    assert kept == [f"{i:04d}_{b}" for i, b in [(2, NOMINAL.name), (3, NOMINAL.name),
                                                (6, NOISY.name), (7, NOISY.name),
                                                (8, NOMINAL.name), (9, NOISY.name)]]
    for name in kept:
        assert (out / "runs" / name / "metrics.json").is_file()
        assert (out / "runs" / name / "metadata.yaml").is_file()   # the output bag
    assert "best over all bags" in (out / "summary.txt").read_text()


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("fto-sweep: error: "), err
    assert "Traceback" not in err
    return lines[0]


_OK = ["--params", str(SINGLE_DELAY), "--bag", str(NOMINAL), "--out", "never-written"]


@pytest.mark.parametrize("args", [
    [],                                                          # nothing
    ["--params", "x.yaml", "--bag", "b"],                        # no --out
    _OK + ["--workers", "0"],
    _OK + ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],  # one or the other
    _OK + ["--scheduler", "localhost"],                          # not an address
    _OK + ["--data", "ftp"],
])
def test_usage_errors_exit_2_with_one_line(args, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(args)
    assert exc.value.code == 2
    _one_line_error(capsys)


def test_bad_parameters_exit_2_and_a_bad_bag_exits_1(tmp_path, capsys):
    broken = tmp_path / "broken.yaml"
    broken.write_text("observer_node: {ros__parameters: {observer: {type: [}}}\n")
    cases = [
        (["--params", str(broken)], 2, "not valid YAML"),
        (["--params", str(tmp_path / "missing.yaml")], 2, "does not exist"),
        (["--params", str(SINGLE_DELAY), "--set", "single_delay.taux=1,2"], 2,
         "unknown parameter"),
        (["--params", str(SINGLE_DELAY), "--set", "single_delay.tau=[1,"], 2, "unclosed"),
        (["--params", str(SINGLE_DELAY), "--baseline", str(broken)], 2, "not valid YAML"),
        (["--params", str(SINGLE_DELAY), "--bag", str(tmp_path / "nobag")], 1,
         "does not exist"),
    ]
    for extra, code, why in cases:
        args = extra + ["--out", str(tmp_path / "out"), "--quiet"]
        if "--bag" not in extra:
            args += ["--bag", str(NOMINAL)]
        assert cli.main(args) == code, extra
        assert why in _one_line_error(capsys)
    assert not (tmp_path / "out" / "results.csv").exists()


def test_every_run_refused_exits_2_and_junk_bag_exits_1_with_rows(tmp_path, capsys):
    out = tmp_path / "refused"
    assert cli.main(["--params", str(SINGLE_DELAY), "--bag", str(NOMINAL), "--quiet",
                     "--set", "single_delay.k=10,20", "--out", str(out), "--no-plots"]) == 2
    assert [r["status"] for r in read_rows(out)] == ["error", "error"]
    junk = tmp_path / "junk_bag"
    junk.mkdir()
    (junk / "metadata.yaml").write_text("not: a bag\n")
    out = tmp_path / "junk"
    assert cli.main(["--params", str(LUENBERGER), "--bag", str(junk), "--quiet",
                     "--out", str(out)]) == 1
    (row,) = read_rows(out)
    assert row["status"] == "error" and row["error"]
    # results are not overwritten by accident
    capsys.readouterr()
    assert cli.main(["--params", str(LUENBERGER), "--bag", str(junk), "--quiet",
                     "--out", str(out)]) == 2
    assert "--overwrite" in _one_line_error(capsys)


def test_unreachable_scheduler_exits_1(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(E, "CONNECT_TIMEOUT_S", 1.0)
    assert cli.main(["--params", str(LUENBERGER), "--bag", str(NOMINAL), "--quiet",
                     "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9"]) == 1
    assert "cannot connect to the Dask scheduler at tcp://127.0.0.1:9" in _one_line_error(capsys)


# --------------------------------------------------------------------- the main job
def _table_rows(text: str) -> list[list[str]]:
    """The rows of fto-report's markdown tables, without the timing columns (the last two)."""
    return [line.split(" | ")[:-2] for line in text.splitlines() if line.startswith("| ")]


@pytest.mark.slow
def test_main_job_on_two_workers_prints_the_same_tables(tmp_path, capsys):
    from fto_ros.cli import report
    bags, cfg = tmp_path / "bags", tmp_path / "config"
    cfg.mkdir()
    for b in (NOMINAL, NOISY):
        shutil.copytree(b, bags / b.name)
    for c in (SINGLE_DELAY, LUENBERGER):
        shutil.copy(c, cfg / c.name)
    tables = []
    for workers in ("1", "2"):
        out = tmp_path / f"out{workers}"
        assert report.main(["--out", str(out), "--bags-dir", str(bags), "--config-dir",
                            str(cfg), "--no-progress", "--workers", workers]) == 0
        printed = capsys.readouterr().out
        tables.append(_table_rows(printed))
        assert _table_rows((out / "report.md").read_text()) == tables[-1]
        assert (out / "dc_motor_noisy__dc_motor_luenberger" / "replay.png").is_file()
    assert len(tables[0]) == 2 + 4 and tables[0] == tables[1]


# -- the figures ------------------------------------------------------------------------------------
def _figure_of(monkeypatch, draw):
    """Run draw() and return the matplotlib figure it saved."""
    from matplotlib.figure import Figure
    saved = []
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: saved.append(self))
    draw()
    assert len(saved) == 1
    return saved[0]


def _pareto_row(bag, setting, c, e, role=results.SWEEP, run=0):
    return {"bag": bag, "_setting": setting, "convergence_time_s": c, "mean_rms_err": e,
            "role": role, "run": run, "params": setting}


def test_pareto_draws_never_converged_runs_apart_and_labels_every_point(monkeypatch, tmp_path):
    """Was: runs that never converged drawn at 1.0 s on a 0.96-1.04 axis, one of three points
    labelled, the legend a raw file list."""
    from fto_ros.sweep import plots
    never = [_pareto_row("bags/a", f"luenberger.poles=[{-20 * k}.0]", math.inf,
                         0.00975 + 1e-5 * k, run=k) for k in range(1, 4)]
    base = _pareto_row("bags/a", "config/dc_motor_plant.yaml,config/dc_motor_ekf.yaml", math.inf,
                       0.0102, role=results.BASELINE, run=4)
    mixed = [_pareto_row("bags/b", "tau=0.05", 0.05, 0.003, run=5),
             _pareto_row("bags/b", "tau=0.1", 0.1, 0.002, run=6),
             _pareto_row("bags/b", "tau=0.2", math.inf, 0.0021, run=7)]
    fig = _figure_of(monkeypatch, lambda: plots.pareto(tmp_path / "p.png", never + [base] + mixed))
    a, b = fig.axes
    for ax, rows in ((a, never), (b, mixed)):
        ticks = [t.get_text() for t in ax.get_xticklabels()]
        assert "never" in ticks, ticks
        never_x = ax.get_xticks()[ticks.index("never")]
        lo, hi = ax.get_xlim()
        assert lo == 0.0 and lo < never_x < hi
        labels = {t.get_text() for t in ax.texts}
        assert {r["_setting"] for r in rows} <= labels, labels        # every point labelled
        legend = [t.get_text() for t in ax.get_legend().get_texts()]
        assert not any("," in t and ".yaml" in t for t in legend), legend
    legend = [t.get_text() for t in a.get_legend().get_texts()]
    assert any("never below the tolerance (3)" in t for t in legend), legend
    assert any(t.startswith("baseline dc_motor_ekf") for t in legend), legend
    # the finite times keep their numbers on the axis; the never column is right of them
    ticks = [t.get_text() for t in b.get_xticklabels()]
    assert "0.1" in ticks and b.get_xticks()[ticks.index("never")] > 0.1


def test_replay_figure_axes_name_the_units(monkeypatch, tmp_path):
    from fto_ros.replay.plot import plot_replay
    t = np.linspace(0, 1, 50)
    x = np.column_stack([np.sin(t), np.cos(t), t])
    fig = _figure_of(monkeypatch, lambda: plot_replay(
        tmp_path / "r.png", t=t, estimate=x, state_names=["q", "q_dot", "current"],
        truth_t=t, truth=x, err_t=t, err_norm=np.abs(t) + 1e-9, units=["rad", "rad/s", "A"],
        ui_t=t, ui_estimate=t[:, None], ui_names=["tau_L"], ui_units=["N m"]))
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels[:3] == ["q [rad]", "q_dot [rad/s]", "current [A]"], labels
    assert labels[3].startswith("tau_L [N m]") and "mixed units" in labels[4], labels


def test_plant_units_are_checked_and_read(tmp_path):
    from fto_ros.plant.block import units_of
    flat = load_params_files([REPO / "config" / "dc_motor_plant.yaml",
                              REPO / "config" / "dc_motor_single_delay.yaml"])
    assert units_of(flat) == (["rad", "rad/s", "A"], ["N m"], ["rad"])
    with pytest.raises(ConfigError, match="plant.units"):
        Runner({**flat, "plant.units": ["rad"]})


# -- progress (a terminal) --------------------------------------------------------------------------
def _on_a_terminal(cmd: list[str], cwd: Path, ok=(0,)) -> str:
    """What ``cmd`` writes to stderr when stderr is a terminal (a pseudo-terminal)."""
    import select
    import subprocess
    import sys
    master, slave = os.openpty()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    p = subprocess.Popen([sys.executable, "-c", "import sys; from fto_ros.%s import main; "
                          "sys.exit(main())" % cmd[0], *cmd[1:]], cwd=cwd, env=env,
                         stderr=slave, stdout=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    os.close(slave)
    out = b""
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:
                break
            if not chunk:
                break
            out += chunk
        elif p.poll() is not None:
            break
    assert p.wait(timeout=300) in ok
    return out.decode(errors="replace")


@pytest.mark.slow
def test_sweep_progress_bar_from_the_start_on_two_workers(tmp_path):
    """Was: nothing for the first ~10 s (the parser imported the whole replay first)."""
    text = _on_a_terminal(["sweep.cli", "--params", str(SINGLE_DELAY), "--bag", str(NOMINAL),
                           "--set", "single_delay.k=150,200", "--out", str(tmp_path / "s"),
                           "--workers", "2", "--no-plots"], REPO)
    first = text.index("[1/2]")
    assert "loading" in text[:first] and "0/2 runs" in text[:first], text[:first]
    assert "2/2 runs" in text, text
    assert "leaked" not in text


@pytest.mark.slow
def test_report_progress_bar_with_two_workers(tmp_path):
    """Was: no progress at all with more than one worker (the default)."""
    bags, config = tmp_path / "bags", tmp_path / "config"
    bags.mkdir()
    config.mkdir()
    (bags / "dc_motor_nominal").symlink_to(NOMINAL)
    for name in ("dc_motor_plant.yaml", "dc_motor_luenberger.yaml", "dc_motor_single_delay.yaml"):
        shutil.copy(REPO / "config" / name, config / name)
    text = _on_a_terminal(["cli.report", "--bags-dir", str(bags), "--config-dir", str(config),
                           "--out", str(tmp_path / "o"), "--workers", "2"], REPO, ok=(0, 1))
    # (exit 1: the config's other bags are not in this bags directory)
    assert "0/2 replays" in text and "2/2 replays" in text, text
    assert "leaked" not in text


def test_sweep_help_says_the_replays_defaults():
    from fto_ros.replay import DEFAULT_NODE_NAME, DEFAULT_TOLERANCE
    helps = {a.dest: a.help for a in cli.build_parser()._actions}
    assert f"default {DEFAULT_TOLERANCE:g}," in helps["tolerance"]
    assert f"default {DEFAULT_NODE_NAME})" in helps["node_name"]
