"""Small formulas of the log reader, the scenario value checks and the sweep's failure line."""
from types import SimpleNamespace

import numpy as np

from immersim.orchestrator.analysis.logs import ChannelData
from immersim.orchestrator.sweep.core import failure_message
from immersim.orchestrator.values import _int


def test_channel_time_in_seconds_is_the_log_time_in_ns_over_1e9():
    ch = ChannelData("m", np.array([0, 33_000_000, 66_000_000, 10 ** 12], np.int64))
    np.testing.assert_array_equal(ch.t, [0.0, 0.033, 0.066, 1000.0])


def test_declared_integer_bounds_parse_or_are_absent():
    assert _int("7") == 7 and _int(-3) == -3 and _int("0") == 0
    assert _int(None) is None and _int("x") is None


def test_sweep_failure_line_counts_the_runs_not_shown():
    rows = [SimpleNamespace(id=f"{k:03d}", status="failed", reason=f"r{k}") for k in range(7)]
    result = SimpleNamespace(failed=rows, rows=rows + [SimpleNamespace(id="007", status="completed", reason="")],
                             spec=SimpleNamespace(file="s.toml"), summary="out/summary.csv")
    line = failure_message(result, shown=5)
    assert line == ("sweep s.toml: 7 of 8 runs did not complete (000: failed: r0; 001: failed: r1; 002: failed: r2; "
                    "003: failed: r3; 004: failed: r4; and 2 more); summary: out/summary.csv")
    assert "more" not in failure_message(result, shown=7)


def test_metric_units_come_from_the_logged_signal_and_booleans_are_shares(tmp_path, test_fmus):
    """A metric over a Real signal has the signal's unit; over a Boolean (the mean: a share of
    steps) the unit 1; a metric without a signal has none."""
    from immersim.orchestrator.analysis.runs import Run, RunSet
    from immersim.orchestrator.execution import run_scenario

    p = tmp_path / "u.toml"
    p.write_text(f'[simulation]\nstop = 0.099\n[[units]]\nname = "m1"\nfmu = "{test_fmus["oscillator"]}"\n')
    out = tmp_path / "u.mcap"
    run_scenario(p, out)
    rs = RunSet([Run("a", out)], metrics={"xmax": {"signal": "m1.x"}, "rest": {"signal": "m1.at_rest"},
                                          "other": {}})
    assert (rs.metric_unit("xmax"), rs.metric_unit("rest"), rs.metric_unit("other")) == ("m", "1", "")


def test_report_table_of_sweep_runs_has_the_point_keys_fixed_columns_and_metrics(tmp_path):
    from immersim.orchestrator.analysis.report import _table
    from immersim.orchestrator.analysis.runs import Run, RunSet

    runs = [Run(f"r{k}", tmp_path / f"{k}.mcap", point={"plat.k": str(k)},
                row={"id": f"00{k}", "status": "completed", "steps": "30", "t_end_s": "0.99",
                     "wall_time_s": "0.1", "xmax": str(0.5 * k)}) for k in range(2)]
    heads, rows = _table(RunSet(runs, keys=["plat.k"], metrics={"xmax": {}}))
    assert heads == ["id", "plat.k", "status", "steps", "t_end_s", "wall_time_s", "xmax"]
    assert [c[0] for c in rows[1]] == ["1", "1", "completed", "30", "0.99", "0.1", "0.5"]   # numbers shown as numbers


def test_the_log_is_written_in_process_unless_log_process_is_set(tmp_path, test_fmus):
    from immersim.orchestrator.execution import Execution
    from immersim.orchestrator.logwriter import LogProcess, LogWriter

    kinds = {}
    for process in ("false", "true"):
        p = tmp_path / f"p{process}.toml"
        p.write_text(f'[simulation]\nstop = 0.099\n[[units]]\nname = "m1"\nfmu = "{test_fmus["oscillator"]}"\n'
                     f'[log]\nprocess = {process}\n')
        ex = Execution(p, tmp_path / f"p{process}.mcap")
        ex.run()
        kinds[process] = type(ex.observer)
    assert kinds == {"false": LogWriter, "true": LogProcess}
