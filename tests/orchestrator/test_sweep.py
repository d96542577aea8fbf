"""Ablation sweeps: a grid over the coupled-oscillator scenario run on spawned processes and on
a Dask cluster, metrics recomputed independently from the MCAP logs, failed runs reported per
row, malformed sweep files rejected with exact messages."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from immersim.orchestrator.cli import main as cli_main
from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.mcapio import read_info, read_series
from immersim.orchestrator.sweep import (MetricSpec, SweepFailed, load_sweep, read_summary, reduce_signals,
                                         run_sweep, safe_id)

from .helpers import oscillator_scenario

# A NaN forced into m2 at t = 3 s: beyond the base stop time (1 s), so only a variant that
# runs longer meets it.
FAULT = '[[faults]]\ntarget = "m2.x_other"\nat = 3.0\nvalue = nan\n'

GRID = '''
scenario = "osc.toml"
[grid]
"simulation.algorithm" = ["jacobi", "gauss-seidel"]
"simulation.extrapolation" = ["zoh", "linear"]
[metrics]
x1_max = { signal = "m1.x", reduce = "max" }
x2_min = { signal = "m2.x", reduce = "min" }
v_absmax = { signal = "m*.v", reduce = "absmax" }
x_rms_late = { signal = "m*.x", reduce = "rms", after = 0.5 }
f_mean = { signal = "m1.f_coupling", reduce = "mean" }
x2_final = { signal = "m2.x", reduce = "final" }
n = "steps"
rtf = "realtime_factor"
m1_s = "unit_time:m1"
[plot]
x = "simulation.extrapolation"
y = ["x2_final", "x_rms_late"]
hue = "simulation.algorithm"
'''
IDS = ["000_jacobi_zoh", "001_jacobi_linear", "002_gauss-seidel_zoh", "003_gauss-seidel_linear"]
# Columns that differ between two executions of the same sweep.
TIMING = ("wall_time_s", "loop_time_s", "rtf", "m1_s")


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory, test_fmus) -> Path:
    """A folder with the oscillator scenario ``osc.toml`` (1 s, step 0.01 s) and ``grid.toml``."""
    d = tmp_path_factory.mktemp("sweep")
    oscillator_scenario(d, test_fmus["oscillator"], step=0.01, stop=1.0, extra=FAULT)
    (d / "grid.toml").write_text(GRID)
    return d


@pytest.fixture(scope="module")
def local_grid(sweep_dir):
    """The 2x2 grid run once on 2 local worker processes."""
    out = sweep_dir / "local"
    return run_sweep(sweep_dir / "grid.toml", out, workers=2), out


def independent_metrics(mcap: Path) -> dict:
    """The [metrics] of GRID computed directly from the log with read_series and numpy."""
    s = read_series(mcap, ["m1.*", "m2.*"])
    t1, x1, _ = s["m1.x"]
    t2, x2, _ = s["m2.x"]
    late = np.concatenate([x1[t1 >= 0.5], x2[t2 >= 0.5]])
    return {"x1_max": x1.max(), "x2_min": x2.min(),
            "v_absmax": max(np.abs(s["m1.v"][1]).max(), np.abs(s["m2.v"][1]).max()),
            "x_rms_late": math.sqrt(np.mean(late ** 2)), "f_mean": s["m1.f_coupling"][1].mean(),
            "x2_final": x2[-1]}


def test_grid_runs_every_variant_with_metrics_from_its_log(local_grid, sweep_dir):
    result, out = local_grid
    rows = read_summary(out / "summary.csv")
    assert [r["id"] for r in rows] == IDS
    assert sorted(p.name for p in out.glob("*.mcap")) == sorted(f"{i}.mcap" for i in IDS)
    assert [(r["simulation.algorithm"], r["simulation.extrapolation"]) for r in rows] == [
        ("jacobi", "zoh"), ("jacobi", "linear"), ("gauss-seidel", "zoh"), ("gauss-seidel", "linear")]
    for r in rows:
        assert (r["status"], r["steps"], r["n"], float(r["t_end_s"]), r["reason"]) == ("completed", "100", "100", 1.0, "")
        wall, loop, m1 = float(r["wall_time_s"]), float(r["loop_time_s"]), float(r["m1_s"])
        assert 0 < m1 < loop < wall and float(r["rtf"]) == pytest.approx(1.0 / loop, rel=1e-12)
        mcap = out / r["mcap"]
        meta = read_info(mcap).metadata["immersim"]
        assert (meta["algorithm"], meta["extrapolation"]) == (r["simulation.algorithm"], r["simulation.extrapolation"])
        for name, value in independent_metrics(mcap).items():
            assert float(r[name]) == pytest.approx(value, rel=1e-12, abs=1e-15), (r["id"], name)
    # The variants really differ: the coupling error depends on algorithm and extrapolation.
    assert len({r["x2_final"] for r in rows}) == 4
    assert (out / "x2_final-x_rms_late_vs_simulation.extrapolation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert result.plots == [out / "x2_final-x_rms_late_vs_simulation.extrapolation.png"]
    assert "4 of 4 runs completed" in str(result)


def test_sweep_run_equals_a_direct_run(local_grid, sweep_dir, tmp_path):
    """A variant run by the sweep worker ends where run_scenario with the same overrides ends."""
    _, out = local_grid
    row = read_summary(out / "summary.csv")[3]
    res = run_scenario(sweep_dir / "osc.toml", None,
                       overrides={"simulation.algorithm": "gauss-seidel", "simulation.extrapolation": "linear"})
    assert float(row["x2_final"]) == res.values["m2"]["x"]


def test_failed_runs_are_reported_in_their_rows(sweep_dir, tmp_path):
    """A NaN fault met by the longer variant and a missing FMU fail their runs; the sweep
    completes the others, writes every row and then raises SweepFailed."""
    (sweep_dir / "fail.toml").write_text('''
scenario = "osc.toml"
[[variants]]
name = "ok"
[[variants]]
name = "long run"
"simulation.stop" = 4.0
[[variants]]
name = "swap"
"m1:fmu" = "nowhere/other_osc.fmu"
[metrics]
x2_final = { signal = "m2.x", reduce = "final" }
''')
    out = tmp_path / "fail"
    with pytest.raises(SweepFailed, match=r"2 of 3 runs did not complete \(001_long-run: failed: unit m2: fmi2DoStep "
                                          r"returned discard at t = 3 s: .*; 002_swap: failed: FmuLoadError: unit m1: "
                                          r"FMU '.*nowhere/other_osc.fmu' not found"):
        run_sweep(sweep_dir / "fail.toml", out, workers=2)
    rows = {r["id"]: r for r in read_summary(out / "summary.csv")}
    assert list(rows) == ["000_ok", "001_long-run", "002_swap"]
    ok, late, swap = rows.values()
    assert (ok["status"], ok["steps"]) == ("completed", "100") and math.isfinite(float(ok["x2_final"]))
    assert (late["status"], late["steps"], late["t_end_s"], late["x2_final"]) == ("failed", "300", "3.0", "")
    assert re.search(r"FmuInputError: m2: input x_other = nan at t = 3 s", late["reason"])
    assert read_info(out / late["mcap"]).channels["m2"].count == 301  # every completed step kept
    assert (swap["status"], swap["steps"], swap["mcap"], swap["m1:fmu"]) == ("failed", "0", "", "nowhere/other_osc.fmu")
    assert swap["reason"].startswith("FmuLoadError: unit m1: FMU")


def test_cli_sweep_exits_nonzero_when_a_run_fails(sweep_dir, tmp_path, capsys):
    (sweep_dir / "bad_swap.toml").write_text('scenario = "osc.toml"\n[grid]\n"m2:fmu" = ["missing.fmu"]\n')
    code = cli_main(["sweep", str(sweep_dir / "bad_swap.toml"), "-o", str(tmp_path), "-j", "1"])
    assert code != 0
    assert re.search(r"sweep .*bad_swap.toml: 1 of 1 runs did not complete \(000: failed: FmuLoadError: unit m2",
                     capsys.readouterr().err)
    assert read_summary(tmp_path / "summary.csv")[0]["status"] == "failed"


def test_dask_cluster_gives_the_same_summary(local_grid, sweep_dir):
    """The same sweep on a one-worker Dask LocalCluster: identical rows except timing."""
    distributed = pytest.importorskip("distributed")
    try:
        cluster = distributed.LocalCluster(n_workers=1, processes=True, threads_per_worker=1,
                                           dashboard_address=None, silence_logs=50)
    except Exception as exc:  # pragma: no cover - sandboxed machines without sockets
        pytest.skip(f"cannot start a Dask LocalCluster: {exc}")
    out = sweep_dir / "dask"
    try:
        with cluster:
            run_sweep(sweep_dir / "grid.toml", out, scheduler=cluster.scheduler_address)
    finally:
        cluster.close()
    local = read_summary(local_grid[1] / "summary.csv")
    dask = read_summary(out / "summary.csv")
    strip = [{k: v for k, v in r.items() if k not in TIMING} for r in (local, dask) for r in r]
    assert strip[:4] == strip[4:]
    assert sorted(p.name for p in out.glob("*.mcap")) == sorted(f"{i}.mcap" for i in IDS)


def test_reduce_signals_pools_matches_and_windows_in_time():
    t = np.array([0.0, 0.5, 1.0])
    series = {"a.x": (t, np.array([3.0, -4.0, 1.0]), "m"), "b.x": (t, np.array([0.0, 2.0, -2.0]), "m")}
    assert reduce_signals(series, MetricSpec("m", signal="*.x", reduce="absmax")) == 4.0
    assert reduce_signals(series, MetricSpec("m", signal="*.x", reduce="rms", after=0.5)) == math.sqrt(25 / 4)
    assert math.isnan(reduce_signals(series, MetricSpec("m", signal="*.x", reduce="max", after=2.0)))
    with pytest.raises(ValueError, match=r"metric m: reduce 'final' needs exactly one signal, '\*.x' matches 2: a.x, b.x"):
        reduce_signals(series, MetricSpec("m", signal="*.x", reduce="final"))


def test_run_ids_are_short_and_file_system_safe():
    assert safe_id(7, ["gauss-seidel", 0.01, "../fmus/my net.fmu", "a/b c"]) == "007_gauss-seidel_0.01_my-net_b-c"
    assert safe_id(1, ["x" * 200]) == "001_" + "x" * 24  # each part cut to 24 characters
    assert len(safe_id(1, ["x" * 30] * 4)) == 4 + 60      # the whole to 60 after the index


BAD = [
    ("scenario = 1\n[grid]\n'm1.k' = [1.0]\n", r"bad.toml: scenario: expected a string, got 1"),
    ("scenario = 'nope.toml'\n[grid]\n'm1.k' = [1.0]\n", r"bad.toml: scenario: 'nope.toml' does not exist"),
    ("scenario = 'osc.toml'\n[grid\n", r"bad.toml: invalid TOML"),
    ("scenario = 'osc.toml'\nruns = 3\n", r"bad.toml: unknown key 'runs' \(expected one of description, grid"),
    ("scenario = 'osc.toml'\n", r"bad.toml: nothing to run: give a \[grid\] or \[\[variants\]\]"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = 2.0\n", r"bad.toml: grid\['m1.k'\]: expected an array, got 2.0"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = []\n", r"bad.toml: grid\['m1.k'\]: must not be empty"),
    ("scenario = 'osc.toml'\n[grid]\n'simulation.dt' = [0.1]\n",
     r"bad.toml: grid key 'simulation.dt': unknown simulation setting 'simulation.dt'"),
    ("scenario = 'osc.toml'\n[grid]\n'stiffness' = [1]\n", r"bad.toml: grid key 'stiffness': 'stiffness' is not an override key"),
    ("scenario = 'osc.toml'\n[grid]\n'mx.k' = [1.0, 2.0]\n",
     r"bad.toml: variant 000_1 \{'mx.k': 1.0\}: override 'mx.k': no unit 'mx' in .*osc.toml"),
    ("scenario = 'osc.toml'\n[grid]\n'simulation.algorithm' = ['jacobi', 'euler']\n",
     r"bad.toml: variant 001_euler \{'simulation.algorithm': 'euler'\}: .*osc.toml: simulation.algorithm \(set by override "
     r"'simulation.algorithm'\): 'euler' is not one of gauss-seidel, jacobi"),
    ("scenario = 'osc.toml'\n[grid]\n'simulation.step' = [0.01, -1.0]\n",
     r"bad.toml: variant 001_-1 .*simulation.step \(set by override 'simulation.step'\): must be > 0, got -1.0"),
    ("scenario = 'osc.toml'\n[[variants]]\nname = 'a'\n[[variants]]\nname = 'a'\n",
     r"bad.toml: variants\[1\]: duplicate variant name 'a'"),
    ("scenario = 'osc.toml'\n[[variants]]\nname = 'a'\n'm1.k' = [1, 2]\n",
     r"bad.toml: variants\[0\]: key 'm1.k': expected a single value, got \[1, 2\]"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[metrics]\ne = { signal = 'm1.x', reduce = 'median' }\n",
     r"bad.toml: metrics.e.reduce: 'median' is not one of max, min, mean, rms, absmax, final"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[metrics]\ne = { signal = 'x' }\n",
     r"bad.toml: metrics.e.signal: 'x' is not of the form 'unit.variable'"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[metrics]\ne = 'cpu'\n",
     r"bad.toml: metrics.e: unknown built-in metric 'cpu' \(expected one of wall_time, loop_time, realtime_factor, "
     r"steps, status, unit_time:<unit>, or a table \{signal, reduce\}\)"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[metrics]\ne = 'unit_time:'\n",
     r"bad.toml: metrics.e: unknown built-in metric 'unit_time:'"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[metrics]\nstatus = 'steps'\n",
     r"bad.toml: metrics.status: the name 'status' is already a summary column"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[metrics]\ne = { signal = 'm1.x', window = 1 }\n",
     r"bad.toml: metrics.e: unknown key 'window'"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[plot]\nx = 'm1.k'\ny = 'err'\n",
     r"bad.toml: plot.y: 'err' is not an override key or metric \(columns: m1.k, steps, t_end_s, "
     r"wall_time_s, loop_time_s\)"),
    ("scenario = 'osc.toml'\n[grid]\n'm1.k' = [1.0]\n[[plot]]\ny = 'steps'\n", r"bad.toml: plot\[0\].x: missing \(required\)"),
]


@pytest.mark.parametrize("text,match", BAD, ids=[f"bad{i}" for i in range(len(BAD))])
def test_malformed_sweep_files_name_file_and_key(sweep_dir, text, match):
    bad = sweep_dir / "bad.toml"
    bad.write_text(text)
    with pytest.raises(ScenarioError, match=match):
        load_sweep(bad)


def test_missing_sweep_file(tmp_path):
    with pytest.raises(ScenarioError, match=r"sweep file .*none.toml does not exist"):
        run_sweep(tmp_path / "none.toml", tmp_path)


def test_fmu_swap_paths_resolve_against_the_sweep_file(sweep_dir, test_fmus):
    sub = sweep_dir / "sub"
    sub.mkdir(exist_ok=True)
    (sub / "swap.toml").write_text(f'scenario = "../osc.toml"\n[grid]\n"m1:fmu" = ["../fmus/a.fmu", "{test_fmus["oscillator"]}"]\n')
    spec = load_sweep(sub / "swap.toml")
    assert [v.resolved["m1:fmu"] for v in spec.variants] == [str(sweep_dir / "fmus" / "a.fmu"), str(test_fmus["oscillator"])]
    assert [v.id for v in spec.variants] == ["000_a", "001_oscillator"]


CRASHER = '''"""Test unit that kills its process at t >= crash_at (a crash inside an FMU)."""
import os

from immersim.fmus.common import TableSlave, Var


class crasher(TableSlave):
    modelName = "crasher"
    VARIABLES = (
        Var("crash_at", "parameter", "Real", 1e9, "s", "time of the crash"),
        Var("x_other", "input", "Real", 0.0, "m", "ignored"),
        Var("x", "output", "Real", 0.0, "m", "always 0"),
    )

    def setup_model(self):
        self.values["x"] = 0.0

    def step_model(self, t, h):
        if t >= self.values["crash_at"]:
            os._exit(3)
'''


def test_a_worker_that_dies_fails_only_its_own_run(sweep_dir, tmp_path):
    """A process crash breaks the local pool; the unfinished runs are retried one per process
    and only the crashing one is reported failed."""
    from immersim.orchestrator.build import build_unit

    unit = tmp_path / "crasher"
    unit.mkdir()
    (unit / "crasher_fmu.py").write_text(CRASHER)
    fmu = build_unit(unit, tmp_path / "fmus")
    (sweep_dir / "crash.toml").write_text(f'''
scenario = "osc.toml"
[grid]
"m1.k" = [1.0, 2.0]
[[variants]]
name = "crash"
"m2:fmu" = "{fmu}"
"m2.crash_at" = 0.5
[[variants]]
name = "after"
"m1.k" = 3.0
''')
    out = tmp_path / "crash"
    res = run_sweep(sweep_dir / "crash.toml", out, workers=2, check=False)
    assert [(r.id, r.status) for r in res.rows] == [("000_1", "completed"), ("001_2", "completed"),
                                                    ("002_crash", "failed"), ("003_after", "completed")]
    assert res.rows[2].reason == "worker process died (crash inside an FMU?)"
    assert [r["status"] for r in read_summary(out / "summary.csv")] == ["completed", "completed", "failed", "completed"]


EXAMPLES = {
    "platform_ablation.toml": ["000_computed_torque_rk4", "001_computed_torque_cvode_bdf", "002_pd_rk4",
                               "003_pd_cvode_bdf", "004_planar"],
    "prediction_orders.toml": ["000_0_20", "001_0_80", "002_1_20", "003_1_80", "004_2_20", "005_2_80"],
    "campus_backends.toml": ["000_fcl", "001_basis_point", "002_honeycomb"],
    "campus_prediction.toml": ["000_0_20", "001_0_80", "002_1_20", "003_1_80", "004_2_20", "005_2_80"],
}


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_example_sweep_files_are_valid(name):
    """The example sweeps in scenarios/sweeps/ parse and every variant fits its scenario."""
    from ..conftest import TESTS

    spec = load_sweep(TESTS.parent / "scenarios" / "sweeps" / name)
    assert [v.id for v in spec.variants] == EXAMPLES[name]


def test_comparison_plot_lines(sweep_dir, tmp_path):
    """Numeric x sorted on its scale, one line per hue value, failed runs and NaN left out."""
    from immersim.orchestrator.sweep import RunRow, comparison_data, plot_comparison

    (sweep_dir / "steps.toml").write_text('''
scenario = "osc.toml"
[grid]
"m1.k" = [2.0, 1.0]
"simulation.step" = [0.02, 0.01, 0.04]
[[variants]]
name = "default step"
[metrics]
err = { signal = "m1.x", reduce = "max" }
[plot]
x = "simulation.step"
y = "err"
logx = true
''')
    spec = load_sweep(sweep_dir / "steps.toml")
    rows = [RunRow(v.index, v.id, "completed", metrics={"err": 10.0 * v.index}) for v in spec.variants]
    rows[1].status, rows[2].metrics["err"] = "failed", math.nan
    data = comparison_data(spec, rows, spec.plots[0])
    assert data.numeric and data.plotted == 5
    assert data.lines == {"err": {"m1.k=2": ([0.02], [0.0]), "m1.k=1": ([0.01, 0.02, 0.04], [40.0, 30.0, 50.0])}}
    png = plot_comparison(spec, rows, spec.plots[0], tmp_path / "p.png")
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_signal_pattern_brackets_are_literal():
    from immersim.orchestrator.patterns import matches

    names = ["coll.pair[1].x", "coll.pair1.x", "coll.pair[2].x"]
    assert [n for n in names if matches(n, ["coll.pair[1].x"])] == ["coll.pair[1].x"]
    assert [n for n in names if matches(n, ["coll.pair[?].*"])] == ["coll.pair[1].x", "coll.pair[2].x"]
    assert [n for n in names if matches(n, ["coll.pair[[]2].x"])] == ["coll.pair[2].x"]


def test_a_metric_without_signal_fails_the_row_but_keeps_the_others(sweep_dir, tmp_path):
    (sweep_dir / "typo.toml").write_text('''
scenario = "osc.toml"
[[variants]]
name = "one"
[metrics]
x1_max = { signal = "m1.x", reduce = "max" }
typo = { signal = "m1.position", reduce = "max" }
''')
    res = run_sweep(sweep_dir / "typo.toml", tmp_path, workers=1, check=False)
    (row,) = res.rows
    assert (row.status, row.steps) == ("failed", 100)
    assert row.reason == "metric typo: no logged signal matches 'm1.position' (see immersim info --signals 000_one.mcap)"
    assert row.metrics["x1_max"] == read_series(tmp_path / "000_one.mcap", ["m1.x"])["m1.x"][1].max()
    assert math.isnan(row.metrics["typo"])


def test_long_grid_values_get_distinct_short_ids():
    from immersim.orchestrator.sweep import distinct_labels

    scenes = [f"tanks:n={n},tris=5.4k,spacing=10;missile:x=-30,y=0,z=15,pitch=0.41" for n in (1, 10, 5040)]
    assert distinct_labels(scenes) == ["n=1", "n=10", "n=5040"]
    assert distinct_labels(["fcl", "basis_point"]) == ["fcl", "basis_point"]
    assert distinct_labels(["../a/other_network.fmu", "network"]) == ["other_network", "network"]
    assert distinct_labels([0.01, 0.02]) == ["0.01", "0.02"]
