"""SSP 1.0: export of every shipped scenario and its run give the scenario's log bit for bit; the
export validates against the standard's schema; an SSP written by hand (nested system, system
connectors, linear transformations, parameter values inline and in an .ssv) runs as the
standard says; what the reader cannot run is refused by name."""
import zipfile
from pathlib import Path

import fmpy
import pytest
from mcap.reader import make_reader

from immersim.orchestrator.cli import main
from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.scenario import load_scenario
from immersim.orchestrator.ssp import export_ssp

from .test_conformance import ROOT as REFERENCE, log_rows

SCENARIOS = sorted((Path(__file__).resolve().parents[2] / "scenarios").glob("*.toml"))
SHORT = {"simulation.stop": 0.2}
#: scenarios whose round trip runs over their full length (a few seconds each); the others stop
#: at 0.2 s (their full length is compared by ``benchmarks/bench_ssp.py``)
FULL = {"teleop"}


def messages(path: Path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        msgs = [(c.topic, m.log_time, m.publish_time, m.data) for _, c, m in reader.iter_messages()]
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    return msgs, meta


@pytest.mark.parametrize("toml", SCENARIOS, ids=lambda p: p.stem)
def test_round_trip_gives_the_scenario_log_bit_for_bit(tmp_path, toml):
    """``run scenario.toml`` and ``run exported.ssp``: every message (topic, times, bytes) and
    the run's settings and status are the same; only the file names differ (scenario, FMUs).
    The scenarios of ``FULL`` run to their own stop time (every step of the run compared)."""
    ssp = tmp_path / f"{toml.stem}.ssp"
    full = toml.stem in FULL
    args = [] if full else ["--set", "simulation.stop=0.2"]
    assert main(["export", str(toml), "-o", str(ssp)] + args) == 0
    res = run_scenario(toml, tmp_path / "a.mcap", overrides=None if full else SHORT)
    run_scenario(ssp, tmp_path / "b.mcap")
    a, meta_a = messages(tmp_path / "a.mcap")
    b, meta_b = messages(tmp_path / "b.mcap")
    assert len(a) > 0 and a == b
    if full:   # the whole run: every step to the scenario's stop time
        assert res.status == "completed" and res.t_ns == load_scenario(toml).stop_ns
        assert meta_a["run"]["steps_done"] == meta_a["run"]["steps_total"] == str(res.steps_done)
    assert meta_a["immersim"] == meta_b["immersim"] and meta_a["run"] == meta_b["run"]
    assert meta_a["scenario"]["text"] == meta_b["scenario"]["text"]
    assert [h.split(" sha256=")[1] for h in meta_a["fmus"].values()] == \
        [h.split(" sha256=")[1] for h in meta_b["fmus"].values()]


def test_export_validates_against_the_ssp_schema(tmp_path):
    """The SSD and each .ssv validate against SSP 1.0's XML schemas (as FMPy ships them); the
    scenario inputs are a signal-source FMU connected to their targets."""
    from lxml import etree

    ssp = export_ssp(SCENARIOS[[p.stem for p in SCENARIOS].index("platform_tracking")], tmp_path / "pt.ssp")
    schemas = Path(fmpy.__file__).parent / "ssp" / "schema"
    with zipfile.ZipFile(ssp) as z:
        ssd = etree.fromstring(z.read("SystemStructure.ssd"))
        etree.XMLSchema(file=str(schemas / "SystemStructureDescription.xsd")).assertValid(ssd)
        ssv_schema = etree.XMLSchema(file=str(schemas / "SystemStructureParameterValues.xsd"))
        ssvs = [n for n in z.namelist() if n.endswith(".ssv")]
        assert ssvs == ["resources/plat_y.ssv", "resources/plat_yz.ssv", "resources/inputs.ssv"]
        for name in ssvs:
            ssv_schema.assertValid(etree.fromstring(z.read(name)))
        source = z.extract("resources/immersim_inputs.fmu", tmp_path)
    assert fmpy.validation.validate_fmu(source) == []
    conns = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
             for c in ssd.iter("{*}Connection")]
    assert conns == [("inputs", "u1", "plat_y", "ref.y"), ("inputs", "u2", "plat_yz", "ref.y"),
                     ("inputs", "u3", "plat_yz", "ref.z")]


HAND_SSD = '''<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription version="1.0" name="hand"
    xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription"
    xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon"
    xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">
  <ssd:System name="root">
    <ssd:Elements>
      <ssd:Component name="src" source="resources/Feedthrough.fmu">
        <ssd:Connectors>
          <ssd:Connector name="Float64_continuous_output" kind="output"><ssc:Real/></ssd:Connector>
        </ssd:Connectors>
        <ssd:ParameterBindings>
          <ssd:ParameterBinding source="resources/src.ssv" prefix="src."/>
        </ssd:ParameterBindings>
      </ssd:Component>
      <ssd:System name="sub">
        <ssd:Connectors>
          <ssd:Connector name="x_in" kind="input"><ssc:Real/></ssd:Connector>
        </ssd:Connectors>
        <ssd:Elements>
          <ssd:Component name="b" type="application/x-fmu-sharedlibrary" source="resources/Feedthrough.fmu">
            <ssd:Connectors>
              <ssd:Connector name="Float64_continuous_input" kind="input"><ssc:Real/></ssd:Connector>
            </ssd:Connectors>
            <ssd:ParameterBindings>
              <ssd:ParameterBinding>
                <ssd:ParameterValues>
                  <ssv:ParameterSet version="1.0" name="b">
                    <ssv:Parameters>
                      <ssv:Parameter name="Int32_input"><ssv:Integer value="7"/></ssv:Parameter>
                      <ssv:Parameter name="Boolean_input"><ssv:Boolean value="true"/></ssv:Parameter>
                    </ssv:Parameters>
                  </ssv:ParameterSet>
                </ssd:ParameterValues>
              </ssd:ParameterBinding>
            </ssd:ParameterBindings>
          </ssd:Component>
        </ssd:Elements>
        <ssd:Connections>
          <ssd:Connection startConnector="x_in" endElement="b" endConnector="Float64_continuous_input">
            <ssc:LinearTransformation factor="3" offset="-0.5"/>
          </ssd:Connection>
        </ssd:Connections>
      </ssd:System>
    </ssd:Elements>
    <ssd:Connections>
      <ssd:Connection startElement="src" startConnector="Float64_continuous_output" endElement="sub" endConnector="x_in">
        <ssc:LinearTransformation factor="2" offset="1"/>
      </ssd:Connection>
    </ssd:Connections>
  </ssd:System>
  <ssd:DefaultExperiment startTime="0" stopTime="0.5"/>
</ssd:SystemStructureDescription>
'''
HAND_SSV = '''<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet version="1.0" name="src" xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues">
  <ssv:Parameters>
    <ssv:Parameter name="src.Float64_continuous_input"><ssv:Real value="1.5"/></ssv:Parameter>
  </ssv:Parameters>
</ssv:ParameterSet>
'''


def hand_ssp(tmp_path: Path, ssd: str = HAND_SSD) -> Path:
    path = tmp_path / "hand.ssp"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("SystemStructure.ssd", ssd)
        z.writestr("resources/src.ssv", HAND_SSV)
        z.write(REFERENCE / "fmi2" / "Feedthrough.fmu", "resources/Feedthrough.fmu")
    return path


def test_hand_written_ssp_runs_as_the_standard_says(tmp_path):
    """Nested system flattened (unit sub-b), the two linear transformations composed
    (b.in = 3 (2 src.out + 1) - 0.5), parameters from an .ssv with a prefix and from inline
    values, the DefaultExperiment's stop with the FMU's own step (Feedthrough: none, so 33 ms)."""
    ssp = hand_ssp(tmp_path)
    sc = load_scenario(ssp)
    assert [u.name for u in sc.units] == ["src", "sub-b"]
    assert sc.units[0].parameters == {"Float64_continuous_input": 1.5}
    assert sc.units[1].parameters == {"Int32_input": 7, "Boolean_input": True}
    (c,) = sc.connections
    assert (str(c), c.gain, c.offset) == ("src.Float64_continuous_output -> sub-b.Float64_continuous_input (x 6 + 2.5)",
                                          6.0, 2.5)
    out = tmp_path / "hand.mcap"
    res = run_scenario(ssp, out)
    assert res.t_ns == 500_000_000
    rows, _ = log_rows(out, "sub-b")
    assert len(rows) == res.steps_done + 1 and res.steps_done == 16
    assert all(r["Float64_continuous_output"] == 3 * (2 * 1.5 + 1) - 0.5 for _, r in rows)
    assert all(r["Int32_output"] == 7 and r["Boolean_output"] is True for _, r in rows)


@pytest.mark.parametrize("edit,message", [
    (("</ssd:Connections>\n  </ssd:System>\n  <ssd:Default",
      "</ssd:Connections>\n    <ssd:SignalDictionaries/>\n  </ssd:System>\n  <ssd:Default"),
     r"system 'root': ssd:SignalDictionaries is not supported"),
    (('<ssc:LinearTransformation factor="2" offset="1"/>',
      '<ssc:BooleanMappingTransformation><ssc:MapEntry source="true" target="false"/></ssc:BooleanMappingTransformation>'),
     r"connection src\.Float64_continuous_output -> sub\.x_in: BooleanMappingTransformation is not supported "
     r"\(linear transformations only\)"),
    (('<ssd:ParameterBinding source="resources/src.ssv" prefix="src."/>',
      '<ssd:ParameterBinding source="resources/src.ssv"><ssd:ParameterMapping/></ssd:ParameterBinding>'),
     r"component 'src': ssd:ParameterMapping is not supported"),
    (('endElement="b" endConnector="Float64_continuous_input"', 'endElement="b" endConnector="nope"'),
     r"connection x_in -> b\.nope: b\.nope is not a declared connector of system 'sub'"),
])
def test_unsupported_ssd_content_is_refused_by_name(tmp_path, edit, message):
    ssp = hand_ssp(tmp_path, HAND_SSD.replace(*edit))
    with pytest.raises(ScenarioError, match=r"hand\.ssp: SystemStructure\.ssd: " + message):
        load_scenario(ssp)
