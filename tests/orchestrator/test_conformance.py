"""Conformance: the Modelica Association's Reference FMUs (FMI 2.0 and 3.0) run through the
orchestrator give FMPy's ``simulate_fmu`` outputs at every step (Roberts within its solver's
tolerance), Clocks are refused, a unit asking to end the simulation ends the run cleanly."""
import base64
import json
import logging
from pathlib import Path

import fmpy
import numpy as np
import pytest

from immersim.orchestrator import fmi3
from immersim.orchestrator.cli import main
from immersim.orchestrator.errors import FmuLoadError, ImmersimError, ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.mcapio import _messages, channel_schema

ROOT = Path(__file__).resolve().parents[1] / "conformance" / "reference-fmus"

#: (step, stop) per FMU: short runs with the FMU's own step where it has one
RUN = {"BouncingBall": (0.01, 3.0), "Dahlquist": (0.1, 2.0), "Feedthrough": (0.1, 1.0), "Resource": (0.1, 0.5),
       "Stair": (1.0, 12.0), "VanDerPol": (0.1, 2.0), "Roberts": (0.1, 1.0), "StateSpace": (0.1, 1.0)}
FEED_INPUTS = {
    "Float32_continuous_input": 0.1, "Float32_discrete_input": -2.5, "Float64_continuous_input": 1.25,
    "Float64_discrete_input": -3.0, "Int8_input": -7, "UInt8_input": 250, "Int16_input": -30000,
    "UInt16_input": 65000, "Int32_input": -2_000_000_000, "UInt32_input": 4_000_000_000,
    "Int64_input": -9_000_000_000_000_000_000, "UInt64_input": 18_000_000_000_000_000_000,
    "Boolean_input": True, "String_input": "hello", "Enumeration_input": 2}
CASES = [(v, n, {}) for v in ("fmi2", "fmi3") for n in RUN if (ROOT / v / f"{n}.fmu").exists()] + [
    ("fmi2", "BouncingBall", {"h": 2.0, "e": 0.5}), ("fmi3", "BouncingBall", {"h": 2.0, "v": 1.0}),
    ("fmi2", "Dahlquist", {"x": 2.0, "k": 3.0}), ("fmi3", "Dahlquist", {"x": 2.0, "k": 3.0}),
    ("fmi3", "VanDerPol", {"x0": 1.5, "mu": 2.0}),
    ("fmi2", "Feedthrough", {"Float64_continuous_input": 1.25, "Int32_input": -7, "Boolean_input": True,
                             "String_input": "hello", "Enumeration_input": 2, "Float64_fixed_parameter": 4.0}),
    ("fmi3", "Feedthrough", FEED_INPUTS),
]


def log_rows(path: Path, topic: str = "u"):
    """(log time in ns, decoded message) of every message of a channel."""
    msgs, meta, _ = _messages(path)
    return [(m.log_time, channel_schema(s, c)[1](m.data)) for s, c, m in msgs if c.topic == topic], meta


def scenario(tmp_path: Path, fmu: Path, step: float, stop: float, params: dict, extra: str = "") -> Path:
    scn = tmp_path / f"{fmu.stem}.toml"
    text = "".join(f'"{k}" = {_toml(v)}\n' for k, v in params.items())
    scn.write_text(f'[simulation]\nstop = {stop}\nstep = {step}\n[[units]]\nname = "u"\nfmu = "{fmu}"\n'
                   f'[units.parameters]\n{text}{extra}')
    return scn


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)


@pytest.mark.parametrize("version,name,params", CASES, ids=lambda x: x if isinstance(x, str) else "-".join(x) or "default")
def test_reference_fmu_matches_fmpy(tmp_path, version, name, params):
    """Every output at every step equals FMPy's (Roberts: relative 1e-4, its tolerance: FMPy
    adds up its communication points in floating point, the master takes them from integer
    nanoseconds, so the stiff solver's steps differ in the last bit)."""
    fmu = ROOT / version / f"{name}.fmu"
    step, stop = RUN[name]
    out = tmp_path / "run.mcap"
    run_scenario(scenario(tmp_path, fmu, step, stop, params), out)
    rows, meta = log_rows(out)
    md = fmpy.read_model_description(str(fmu))
    outputs = [v.name for v in md.modelVariables if v.causality == "output" and v.type != "Binary"]
    ref = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=stop, output_interval=step,
                            start_values=dict(params), output=outputs)
    assert len(rows) == len(ref)
    np.testing.assert_array_equal([t for t, _ in rows], np.round(ref["time"] * 1e9).astype(np.int64))
    compared = 0
    for o in outputs:
        if o not in ref.dtype.names:   # FMPy records no String
            continue
        col = ref[o]
        if col.ndim > 1:   # an array: its elements o[1], o[2], ...
            ours = np.array([[r[f"{o}[{i + 1}]"] for i in range(col.shape[1])] for _, r in rows])
        else:
            ours = np.array([r[o] for _, r in rows], dtype=col.dtype)
        if name == "Roberts":
            np.testing.assert_allclose(ours, col, rtol=1e-4, atol=1e-12, err_msg=o)
        else:
            np.testing.assert_array_equal(ours, col, err_msg=o)
        compared += 1
    assert compared >= 1


def test_feedthrough_strings_and_binary_logged(tmp_path):
    """String and Binary (FMI 3.0) reach the log: a Binary as base64 text, which the log's
    reader decodes to the bytes the input was given (hex in the scenario, as in the model
    description)."""
    out = tmp_path / "run.mcap"
    run_scenario(scenario(tmp_path, ROOT / "fmi3" / "Feedthrough.fmu", 0.1, 0.3,
                          {"String_input": "hello", "Binary_input": "00ff10"}), out)
    rows, _ = log_rows(out)
    assert all(r["String_output"] == "hello" for _, r in rows)
    assert {r["Binary_output"] for _, r in rows} == {b"\x00\xff\x10"}
    msgs, _, _ = _messages(out)
    raw = [json.loads(m.data) for _, c, m in msgs if c.topic == "u"]
    assert {r["Binary_output"] for r in raw} == {base64.b64encode(b"\x00\xff\x10").decode()} == {"AP8Q"}
    schema = next(channel_schema(s, c)[0] for s, c, _ in msgs if c.topic == "u")
    assert schema["properties"]["Binary_output"]["contentEncoding"] == "base64"
    assert schema["properties"]["UInt64_output"]["fmiType"] == "UInt64"


def test_fmi3_every_type_through_connections(tmp_path):
    """Two FMI 3.0 Feedthrough units, every output of a connected to the input of b of its
    type (Float32 ... UInt64, Boolean, String, Binary, Enumeration; a Float32 input also driven
    by a scenario signal): under Gauss-Seidel + zoh b's outputs equal a's at every step."""
    fmu = ROOT / "fmi3" / "Feedthrough.fmu"
    types = ["Float32_discrete", "Float64_continuous", "Float64_discrete", "Int8", "UInt8", "Int16", "UInt16",
             "Int32", "UInt32", "Int64", "UInt64", "Boolean", "String", "Binary", "Enumeration"]
    conns = "".join(f'[[connections]]\nfrom = "a.{t}_output"\nto = "b.{t}_input"\n' for t in types)
    params = {k: v for k, v in FEED_INPUTS.items()}
    params["Binary_input"] = "0a0b0c"
    body = "".join(f'"{k}" = {_toml(v)}\n' for k, v in params.items())
    scn = tmp_path / "two.toml"
    scn.write_text(f'''[simulation]
stop = 0.5
step = 0.1
extrapolation = "zoh"
[[units]]
name = "a"
fmu = "{fmu}"
[units.parameters]
{body}
[[units]]
name = "b"
fmu = "{fmu}"
{conns}
[[inputs]]
target = "a.Float32_continuous_input"
kind = "ramp"
at = 0.0
slope = 0.3
[[connections]]
from = "a.Float32_continuous_output"
to = "b.Float32_continuous_input"
''')
    out = tmp_path / "two.mcap"
    run_scenario(scn, out)
    a, _ = log_rows(out, "a")
    b, _ = log_rows(out, "b")
    assert len(a) == len(b) == 6
    for (_, ra), (_, rb) in zip(a, b):
        for t in types + ["Float32_continuous"]:
            assert rb[f"{t}_output"] == ra[f"{t}_output"], t
    # the signal at a step's start, held over the step (the FMU outputs its input), as float32
    ramp = [np.float32(0.3 * (max(k - 1, 0) * 100_000_000 / 1e9)).item() for k in range(6)]
    assert [r["Float32_continuous_output"] for _, r in a] == ramp
    assert a[-1][1]["UInt64_output"] == 18_000_000_000_000_000_000
    assert b[-1][1]["Binary_output"] == b"\x0a\x0b\x0c"


STATESPACE = '''[simulation]
stop = 0.5
step = 0.1
[[units]]
name = "a"
fmu = "{fmu}"
parameters = {{ "A[1,1]" = 0.0, "A[1,2]" = 1.0, "A[2,1]" = -1.0, "A[2,2]" = 0.0 }}
[[units]]
name = "b"
fmu = "{fmu}"
[[connections]]
from = "a.y"
to = "b.u"
[[inputs]]
target = "a.u[2]"
value = 0.5
'''


def test_array_variables_connected_whole_and_driven_by_element(tmp_path):
    """StateSpace (arrays sized by structural parameters): a's elements set and driven one by
    one give FMPy's outputs for the same matrices; a.y -> b.u connects the whole vector
    (b.u[i] is Gauss-Seidel's linear mid-step value of a.y[i])."""
    fmu = ROOT / "fmi3" / "StateSpace.fmu"
    scn = tmp_path / "ss.toml"
    scn.write_text(STATESPACE.format(fmu=fmu))
    out = tmp_path / "ss.mcap"
    run_scenario(scn, out)
    a, _ = log_rows(out, "a")
    b, _ = log_rows(out, "b")
    A = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    ref = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=0.5, output_interval=0.1,
                            start_values={"A": sum(A, []), "u": [1.0, 0.5, 3.0]}, output=["y"])
    np.testing.assert_array_equal([[r[f"y[{i}]"] for i in (1, 2, 3)] for _, r in a], ref["y"])
    for k in range(1, len(a)):
        for i in (1, 2, 3):
            assert b[k][1][f"u[{i}]"] == 0.5 * (a[k - 1][1][f"y[{i}]"] + a[k][1][f"y[{i}]"])


def test_a_scenario_input_on_a_whole_array_drives_every_element(tmp_path):
    """``target = "a.u"`` (the whole input vector) with one constant signal: each element u[i]
    is 0.5, so a.y is FMPy's for u = (0.5, 0.5, 0.5) at every step."""
    fmu = ROOT / "fmi3" / "StateSpace.fmu"
    scn = tmp_path / "whole.toml"
    scn.write_text(STATESPACE.format(fmu=fmu).replace('target = "a.u[2]"', 'target = "a.u"'))
    out = tmp_path / "whole.mcap"
    run_scenario(scn, out)
    a, _ = log_rows(out, "a")
    A = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    ref = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", stop_time=0.5, output_interval=0.1,
                            start_values={"A": sum(A, []), "u": [0.5, 0.5, 0.5]}, output=["y"])
    assert all(r[f"u[{i}]"] == 0.5 for _, r in a for i in (1, 2, 3))
    np.testing.assert_array_equal([[r[f"y[{i}]"] for i in (1, 2, 3)] for _, r in a], ref["y"])


def test_array_sizes_follow_structural_parameters():
    """The elements of an array are those its structural parameters give (start values by
    default, a scenario's values otherwise). Note: the Reference FMUs 0.0.41 StateSpace refuses
    any fmi3SetUInt64 of its structural parameters (it advances its value index before checking
    nValues), so a run can only use the default sizes (FMPy fails the same way)."""
    md = fmpy.read_model_description(str(ROOT / "fmi3" / "StateSpace.fmu"))
    default = fmi3.variables(md)
    assert [n for n in default if n.startswith("y[")] == ["y[1]", "y[2]", "y[3]"]
    assert default["A[2,3]"].index == 5 and default["A[2,3]"].shape == (3, 3) and default["u[3]"].start == 3.0
    small = fmi3.variables(md, {"m": 1, "n": 2, "r": 4})
    assert [n for n in small if n.startswith("B[")] == ["B[1,1]", "B[2,1]"]
    assert len([n for n in small if n.startswith("y[")]) == 4 and "x[3]" not in small


def test_array_size_mismatch_is_refused(tmp_path):
    fmu = ROOT / "fmi3" / "StateSpace.fmu"
    scn = tmp_path / "bad.toml"
    scn.write_text(STATESPACE.format(fmu=fmu).replace('to = "b.u"', 'to = "b.A"'))
    with pytest.raises(ScenarioError, match=r"connection a\.y -> b\.A: 3 elements -> 9 elements"):
        run_scenario(scn)


def test_clocks_refused_at_load(tmp_path):
    scn = scenario(tmp_path, ROOT / "fmi3" / "Clocks.fmu", 0.1, 1.0, {})
    with pytest.raises(FmuLoadError, match=r"unit u: .*Clocks\.fmu supports FMI 3\.0 scheduled execution only"):
        run_scenario(scn)


@pytest.mark.parametrize("version", ["fmi2", "fmi3"])
def test_unit_asking_to_end_ends_the_run_cleanly(tmp_path, version, capsys):
    """Stair asks to terminate in its step to t = 9 s: exit 0, that step logged (FMPy's last
    row), the run status names the unit and the time."""
    out = tmp_path / "stair.mcap"
    scn = scenario(tmp_path, ROOT / version / "Stair.fmu", 1.0, 12.0, {})
    assert main(["run", str(scn), "-o", str(out), "-q"]) == 0
    assert "unit u asked to end the simulation at t = 9 s" in capsys.readouterr().out
    rows, meta = log_rows(out)
    assert meta["run"]["status"] == "ended" and meta["run"]["steps_done"] == "9"
    assert meta["run"]["reason"] == "unit u asked to end the simulation at t = 9 s"
    ref = fmpy.simulate_fmu(str(ROOT / version / "Stair.fmu"), fmi_type="CoSimulation", stop_time=12.0,
                            output_interval=1.0, output=["counter"])
    assert [t for t, _ in rows] == [int(t * 1e9) for t in ref["time"]]
    assert [r["counter"] for _, r in rows] == list(ref["counter"])


def test_after_an_error_the_unit_is_only_freed(tmp_path, caplog):
    """StateSpace refuses its structural parameter (see above) with an error at set-up: the run
    fails naming unit, function and message, and the master frees both instances without
    fmi3Terminate (the errored one, and the one never initialized): no "Illegal call sequence"."""
    scn = tmp_path / "ss.toml"
    scn.write_text(STATESPACE.format(fmu=ROOT / "fmi3" / "StateSpace.fmu").replace('"A[1,1]" = 0.0', "m = 2"))
    with caplog.at_level(logging.DEBUG, logger="immersim.orchestrator.fmu"):
        with pytest.raises(ImmersimError, match=r"Expected nValues >= 2 but was 1"):
            run_scenario(scn, tmp_path / "err.mcap")
    assert "Expected nValues" in caplog.text and "Illegal call sequence" not in caplog.text


def test_default_experiment_fills_what_the_scenario_omits(tmp_path):
    """No [simulation] table: BouncingBall's DefaultExperiment gives stop 3 s and step 0.01 s;
    Roberts' its start 1e-5 s and tolerance 1e-4 (FMPy uses them alike: same rows above)."""
    from immersim.orchestrator.scenario import load_scenario
    from immersim.orchestrator.system import check_system

    scn = tmp_path / "bb.toml"
    scn.write_text(f'[[units]]\nname = "u"\nfmu = "{ROOT / "fmi3" / "BouncingBall.fmu"}"\n')
    sc = load_scenario(scn)
    check_system(sc)
    assert (sc.start_ns, sc.stop_ns, sc.step_ns, sc.n_steps, sc.tolerance) == (0, 3 * 10**9, 10**7, 300, None)
    scn.write_text(f'[simulation]\nstop = 1.0\n[[units]]\nname = "u"\nfmu = "{ROOT / "fmi3" / "Roberts.fmu"}"\n')
    sc = load_scenario(scn)
    check_system(sc)
    assert (sc.start_ns, sc.stop_ns, sc.tolerance) == (10_000, 10**9, 1e-4)


def test_fmi3_widths_in_the_ros1_encoding(tmp_path):
    """The "ros1" log packs each FMI 3.0 type at its own width (UInt64 structural parameters as
    uint64, Float32 as float32): Feedthrough without its String (which keeps a channel JSON) and
    Binary reads back the values of the JSON log, the ROS 1 definition names the widths."""
    from immersim.orchestrator.mcapio import read_info, read_series

    fmu = ROOT / "fmi3" / "Feedthrough.fmu"
    wide = {k: v for k, v in FEED_INPUTS.items() if k != "String_input"}
    logs = {}
    for enc in ("json", "ros1"):
        scn = scenario(tmp_path, fmu, 0.1, 0.3, wide, extra=f'[log]\nencoding = "{enc}"\n'
                       'exclude = ["u.String_*", "u.Binary_*"]\n')
        logs[enc] = tmp_path / f"{enc}.mcap"
        run_scenario(scn, logs[enc])
    assert read_info(logs["ros1"]).channels["u"].encoding == "ros1"
    a, b = read_series(logs["json"], ["u.*"]), read_series(logs["ros1"], ["u.*"])
    assert a.keys() == b.keys() and len(a) == 28   # 14 inputs and 14 outputs
    for k in a:
        np.testing.assert_array_equal(a[k][1], b[k][1], err_msg=k)
    assert b["u.UInt64_output"][1][-1] == float(18_000_000_000_000_000_000)   # (read_series gives floats)
    msgs, _, _ = _messages(logs["ros1"])
    definition = next(s.data.decode() for s, c, _ in msgs if c.topic == "u")
    assert "uint64 UInt64_output" in definition and "float32 Float32_continuous_output" in definition


def test_fmi3_binary_is_uint8_array_in_the_ros1_encoding(tmp_path):
    """A Binary is a ROS 1 ``uint8[]`` (uint32 length, then the bytes) in a "ros1" log: the
    ROS 1 reference decoder (mcap_ros1) gives the bytes the input was given, every field of
    Feedthrough's channel (without its String, which keeps a channel JSON) as our readers
    give them, and our readers give the same values from the ros1 and the JSON log."""
    from mcap.reader import make_reader
    from mcap_ros1.decoder import DecoderFactory

    from immersim.orchestrator.analysis.diff import diff_logs
    from immersim.orchestrator.analysis.logs import read_channels

    fmu = ROOT / "fmi3" / "Feedthrough.fmu"
    params = {k: v for k, v in FEED_INPUTS.items() if k != "String_input"}
    params["Binary_input"] = "00ff1000"   # zero bytes first and last: not a C string
    logs = {}
    for enc in ("json", "ros1"):
        scn = scenario(tmp_path, fmu, 0.1, 0.5, params, extra=f'[log]\nencoding = "{enc}"\nexclude = ["u.String_*"]\n'
                       '[[faults]]\ntarget = "u.Binary_input"\nat = 0.2\nvalue = "c0ffee"\n')
        logs[enc] = tmp_path / f"{enc}.mcap"
        run_scenario(scn, logs[enc])
    expect = [b"\x00\xff\x10\x00"] * 3 + [b"\xc0\xff\xee"] * 3   # t = 0 .. 0.5 s; the fault at 0.2 s
    with open(logs["ros1"], "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        (channel,) = [c for c in reader.get_summary().channels.values() if c.topic == "u"]
        definition = reader.get_summary().schemas[channel.schema_id].data.decode()
        decoded = [d for _, _, _, d in reader.iter_decoded_messages(topics=["u"])]
    assert channel.message_encoding == "ros1" and "uint8[] Binary_output" in definition
    assert [bytes(d.Binary_output) for d in decoded] == [bytes(d.Binary_input) for d in decoded] == expect
    ours = {enc: read_channels(logs[enc], ["u.*"])["u"] for enc in logs}
    assert list(ours["ros1"].values["Binary_output"]) == list(ours["json"].values["Binary_output"]) == expect
    for name, values in ours["ros1"].values.items():
        ref = [getattr(d, name) for d in decoded]
        assert [bytes(x) for x in ref] == list(values) if name.startswith("Binary") else \
            np.array_equal(np.asarray(ref, dtype=values.dtype), values), name
    assert len(ours["ros1"].values) == 30 and diff_logs(logs["json"], logs["ros1"]).equal
    rows, _ = log_rows(logs["ros1"])
    assert [r["Binary_output"] for _, r in rows] == expect


def test_an_fmu_returning_early_completes_each_macro_step(tmp_path, monkeypatch, caplog):
    """The master does not allow early return; BouncingBall (FMI 3.0) made to return early
    anyway (instantiated with ``earlyReturnAllowed = true``: it then stops its step at each
    bounce) is called again from where it stopped to the step's end: the log is bit for bit
    the one of the run without early returns, and the early returns are the bounces of a ball
    dropped from 1 m (g = 9.81 m/s2, e = 0.7): t1 = sqrt(2 h / g), t2 = t1 + 2 e sqrt(2 g h) / g
    (within the FMU's own solver, explicit Euler in steps of 1 ms: 2 ms on t1, 10 ms on t2)."""
    from fmpy.fmi3 import FMU3Slave

    fmu, (step, stop) = ROOT / "fmi3" / "BouncingBall.fmu", RUN["BouncingBall"]
    run_scenario(scenario(tmp_path, fmu, step, stop, {}), tmp_path / "plain.mcap")
    instantiate = FMU3Slave.instantiate
    monkeypatch.setattr(FMU3Slave, "instantiate", lambda self, **kw: instantiate(self, earlyReturnAllowed=True, **kw))
    with caplog.at_level(logging.DEBUG, logger="immersim.orchestrator.fmi3"):
        res = run_scenario(scenario(tmp_path, fmu, step, stop, {}), tmp_path / "early.mcap")
    assert res.status == "completed" and res.t_ns == 3_000_000_000
    early = [float(r.getMessage().split("early at t = ")[1].split(" s")[0]) for r in caplog.records
             if "fmi3DoStep returned early" in r.getMessage()]
    t1 = np.sqrt(2 * 1.0 / 9.81)
    t2 = t1 + 2 * 0.7 * np.sqrt(2 * 9.81 * 1.0) / 9.81
    assert len(early) >= 3 and abs(early[0] - t1) < 2e-3 and abs(early[1] - t2) < 1e-2, early
    plain, early_rows = log_rows(tmp_path / "plain.mcap")[0], log_rows(tmp_path / "early.mcap")[0]
    assert len(plain) == res.steps_done + 1 and plain == early_rows

