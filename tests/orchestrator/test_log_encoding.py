"""The "ros1" log encoding: the same signals as JSON, readable by the ROS 1 reference decoder."""
import numpy as np
import pytest
from mcap.reader import make_reader

from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.execution import RunFailed, run_scenario
from immersim.orchestrator.mcapio import read_info, read_series
from immersim.orchestrator.observers import json_schema, ros1_definition, ros1_struct
from immersim.orchestrator.fmu import VarInfo
from immersim.orchestrator.scenario import load_scenario

from .helpers import oscillator_scenario


def _runs(tmp_path, fmu, extra=""):
    out = {}
    for enc in ("json", "ros1"):
        scn = oscillator_scenario(tmp_path, fmu, step=0.033, stop=2.0, name=f"{enc}.toml",
                                  extra=extra + f'\n[log]\nencoding = "{enc}"\n')
        out[enc] = tmp_path / f"{enc}.mcap"
        run_scenario(scn, out[enc])
    return out


def test_ros1_log_has_the_signals_of_the_json_log(tmp_path, test_fmus):
    """Every signal (times, values, units) read back from a ros1 log equals the JSON log's,
    bit for bit; the units' channels are ros1 (parameters keep JSON) and the file is smaller."""
    logs = _runs(tmp_path, test_fmus["oscillator"])
    a, b = read_series(logs["json"], ["*"]), read_series(logs["ros1"], ["*"])
    assert a.keys() == b.keys() and len(a) >= 4
    for k in a:
        assert np.array_equal(a[k][0], b[k][0]) and np.array_equal(a[k][1], b[k][1]) and a[k][2] == b[k][2], k
    info = read_info(logs["ros1"])
    assert {t: c.encoding for t, c in info.channels.items() if not t.endswith("/parameters")} == \
        {"m1": "ros1", "m2": "ros1"}
    assert info.channels["m1"].count == 62
    assert logs["ros1"].stat().st_size < logs["json"].stat().st_size


def test_ros1_messages_decode_with_the_reference_decoder(tmp_path, test_fmus):
    """mcap_ros1's DecoderFactory (the ROS 1 reference implementation for MCAP) decodes our
    messages from the schema text alone, to the values our reader gives."""
    from mcap_ros1.decoder import DecoderFactory

    logs = _runs(tmp_path, test_fmus["oscillator"])
    ours = read_series(logs["ros1"], ["m1.*"])
    with open(logs["ros1"], "rb") as fh:
        decoded = [(m.log_time, d) for _, _, m, d in
                   make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["m1"])]
    assert len(decoded) == len(ours["m1.x"][0])
    names = [k[3:] for k in ours]
    fields = {n: n.replace(".", "_").replace("[", "_").replace("]", "") for n in names}
    for i, (t, msg) in enumerate(decoded):
        assert t * 1e-9 == ours["m1.x"][0][i]
        for n in names:
            assert float(getattr(msg, fields[n])) == ours[f"m1.{n}"][1][i], n


def test_ros1_definition_names_are_valid_and_unique():
    infos = [VarInfo(n, i, t, "output", "continuous", "m" if t == "Real" else "", None, "d\nmulti  line")
             for i, (n, t) in enumerate([("a.b", "Real"), ("a_b", "Real"), ("pair[1].in_contact", "Boolean"),
                                         ("1x", "Integer"), ("[2]", "Real")])]
    schema = json_schema("u", infos)
    lines = ros1_definition(schema).splitlines()
    assert lines == ["float64 a_b  # a.b [m]: d multi line", "float64 a_b_2  # a_b [m]: d multi line",
                     "bool pair_1_in_contact  # pair[1].in_contact: d multi line",
                     "int32 v_1x  # 1x: d multi line", "float64 v_2  # [2] [m]: d multi line"]
    assert ros1_struct(schema).format == "<dd?id"
    assert ros1_struct(json_schema("u", [VarInfo("s", 0, "String", "output", "", "", None, "")])) is None


@pytest.mark.parametrize("process", [False, True])
def test_ros1_log_of_a_failed_run_keeps_every_completed_step(tmp_path, test_fmus, process):
    """A NaN input at 0.33 s fails step 11: 11 messages (steps 0..10) per unit, written here or
    by a log-writer process (``[log] process``: the steps still waiting in the master's batch
    are sent before the log is closed)."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=1.0, algorithm="gauss-seidel",
                              extra='[[faults]]\ntarget = "m2.x_other"\nat = 0.33\nvalue = nan\n'
                                    f'[log]\nencoding = "ros1"\nprocess = {str(process).lower()}\n')
    out = tmp_path / "fail.mcap"
    with pytest.raises(RunFailed, match=r"after 10 of 31 steps"):
        run_scenario(scn, out)
    info = read_info(out)
    assert info.channels["m2"].count == 11 and info.metadata["run"]["status"] == "failed"
    assert len(read_series(out, ["m2.x"])["m2.x"][0]) == 11


def test_unknown_log_encoding_is_refused(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], extra='[log]\nencoding = "cbor"\n')
    with pytest.raises(ScenarioError, match=r"osc.toml: log.encoding: 'cbor' is not one of json, ros1"):
        load_scenario(scn)


def test_log_table_can_be_overridden(tmp_path, test_fmus):
    """``log.encoding`` (as ``immersim run --set`` and sweeps give it) replaces the file's value."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], extra='[log]\nencoding = "ros1"\n')
    assert load_scenario(scn).log.encoding == "ros1"
    assert load_scenario(scn, {"log.encoding": "json"}).log.encoding == "json"
    with pytest.raises(ScenarioError, match=r"osc.toml: log: unknown key 'colour'"):
        load_scenario(scn, {"log.colour": 1})


def test_diff_compares_values_not_bytes(tmp_path, test_fmus):
    """immersim diff: a JSON and a ros1 log of one run are the same; a run with another
    master algorithm differs, and the first differing sample is named."""
    from immersim.orchestrator.analysis.diff import diff_logs
    from immersim.orchestrator.cli import main

    logs = _runs(tmp_path, test_fmus["oscillator"])
    assert diff_logs(logs["json"], logs["ros1"]).equal
    assert main(["diff", str(logs["json"]), str(logs["ros1"])]) == 0
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=2.0, algorithm="gauss-seidel",
                              name="gs.toml")
    run_scenario(scn, tmp_path / "gs.mcap")
    diff = diff_logs(logs["json"], tmp_path / "gs.mcap", ["m1.x"])
    assert [s.name for s in diff.differing] == ["m1.x"] and diff.differing[0].first_step >= 1
    assert main(["diff", str(logs["json"]), str(tmp_path / "gs.mcap")]) == 1
