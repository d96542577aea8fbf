"""immersim.read_log and immersim convert: every signal of a log, bit for bit, with its unit."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

import immersim
from immersim.orchestrator.analysis.convert import convert_log
from immersim.orchestrator.cli import main
from immersim.orchestrator.mcapio import LogReadError, read_info, read_series


def _same(x: np.ndarray, y: np.ndarray) -> bool:
    return np.array_equal(x, y, equal_nan=x.dtype.kind == "f")


def test_read_log_of_campus_drive_is_the_logged_values(campus_sweep):
    """A ros1 campus_drive log: one column per numeric signal of every unit, the values of the
    per-message struct decoder (read_series) bit for bit, units as the channel schemas say,
    the time index k * 33 ms exactly (the last step shortened to end at stop)."""
    log = campus_sweep / "000_fcl.mcap"
    df = immersim.read_log(log)
    series = read_series(log, ["*"])
    assert sorted(df.columns) == sorted(series) and len(series) > 300
    for name, (t, y, unit) in series.items():
        assert np.array_equal(df[name].to_numpy(dtype=float), y, equal_nan=True), name
        assert df.attrs["units"][name] == unit, name
    info = read_info(log)
    steps = len(df) - 1
    assert steps == int(info.metadata["run"]["steps_done"]) == 122  # ceil(4.0 / 0.033)
    t_ns = np.minimum(np.arange(steps + 1) * 33_000_000, 4_000_000_000)  # the last step ends at stop
    assert np.array_equal(df.attrs["t_ns"], t_ns) and np.array_equal(df.index.to_numpy(), t_ns / 1e9)
    assert df["coll.pair[1].in_contact"].dtype == bool and df.attrs["types"]["coll.pair[1].in_contact"] == "boolean"
    assert df.attrs["units"]["plat.stroke[1]"] == "m"
    assert df.attrs["units"]["net.avatar[1].jolt"] == info.channels["net"].unit_of("avatar[1].jolt") == "m/s"


def test_arrays_per_channel_keep_the_logged_types(osc_log):
    """frame=False: per channel its times in ns and one array per variable; a pattern picks
    signals (brackets literal); a JSON log gives the same frame as the same run in ros1."""
    ch = immersim.read_log(osc_log, ["m1.*"], frame=False)
    assert list(ch) == ["m1"]
    m1 = ch["m1"]
    assert m1.values["at_rest"].dtype == bool and m1.values["x"].dtype == np.float64
    assert m1.units["v"] == "m/s" and m1.types["at_rest"] == "boolean"
    assert np.array_equal(m1.t_ns, np.arange(31) * 33_000_000)
    assert m1.values["x"][0] == 1.0  # x0 = 1
    with pytest.raises(LogReadError, match=r"osc.mcap: no signal matches nothing\.\*"):
        immersim.read_log(osc_log, ["nothing.*"])
    with pytest.raises(LogReadError, match=r"log file .*missing.mcap does not exist"):
        immersim.read_log(osc_log.with_name("missing.mcap"))


def test_convert_to_csv_and_parquet_reads_back_bit_for_bit(osc_log, tmp_path, capsys):
    """CSV (header with units) and Parquet (units in the field metadata) hold the DataFrame's
    values exactly; an unknown format is one error line."""
    df = immersim.read_log(osc_log)
    assert main(["convert", str(osc_log), "-o", str(tmp_path / "run.csv")]) == 0
    csv = pd.read_csv(tmp_path / "run.csv", index_col=0)
    assert list(csv.columns)[:3] == ["m1.x_other [m]", "m1.x [m]", "m1.v [m/s]"] and csv.index.name == "t [s]"
    assert _same(csv.index.to_numpy(), df.index.to_numpy())
    for i, name in enumerate(df.columns):
        assert _same(csv.iloc[:, i].to_numpy(), df[name].to_numpy()), name
    out = convert_log(osc_log, tmp_path / "run.parquet", ["m2.*"])
    table = pq.read_table(out)
    assert table.schema.field("m2.v").metadata == {b"unit": b"m/s", b"type": b"number"}
    assert table.schema.field("t").metadata[b"unit"] == b"s"
    back = pd.read_parquet(out)
    assert list(back.columns) == [c for c in df.columns if c.startswith("m2.")]
    for name in back.columns:
        assert _same(back[name].to_numpy(), df[name].to_numpy()), name
    capsys.readouterr()
    assert main(["convert", str(osc_log), "-o", str(tmp_path / "run.xlsx")]) == 2
    assert capsys.readouterr().err == \
        f"immersim: error: {tmp_path / 'run.xlsx'}: unknown output format '.xlsx' (use .csv or .parquet)\n"


def test_fmi3_widths_read_back_in_both_encodings(tmp_path):
    """An FMI 3.0 log (the reference Feedthrough: UInt64 beyond int64, Float32, Int8 ...) reads
    back with each variable at the width the log writer packed it: the ros1 and JSON logs give
    the same values, and the values of read_series."""
    from pathlib import Path

    from immersim.orchestrator.execution import run_scenario

    root = Path(__file__).resolve().parents[1]
    fmu = root / "conformance" / "reference-fmus" / "fmi3" / "Feedthrough.fmu"
    toml = tmp_path / "feed.toml"
    logs = {}
    for enc in ("json", "ros1"):
        toml.write_text(f'[simulation]\nstep = 0.1\nstop = 0.3\n[[units]]\nname = "u"\nfmu = "{fmu.as_posix()}"\n'
                        '[units.parameters]\nUInt64_input = 18000000000000000000\nInt8_input = -7\n'
                        f'[log]\nencoding = "{enc}"\nexclude = ["u.String_*", "u.Binary_*"]\n')
        logs[enc] = tmp_path / f"{enc}.mcap"
        run_scenario(toml, logs[enc])
    a, b = immersim.read_channels(logs["json"])["u"], immersim.read_channels(logs["ros1"])["u"]
    series = read_series(logs["ros1"], ["u.*"])
    assert b.values["UInt64_output"].dtype == np.uint64 and b.values["Float32_continuous_output"].dtype == np.float32
    assert a.values.keys() == b.values.keys() and len(a.values) == 28
    for k in a.values:
        assert np.array_equal(a.values[k].astype(np.float64), b.values[k].astype(np.float64)), k
        assert np.array_equal(b.values[k].astype(np.float64), series[f"u.{k}"][1]), k
    assert b.values["UInt64_output"][-1] == 18_000_000_000_000_000_000
    assert b.values["Int8_output"][-1] == -7
