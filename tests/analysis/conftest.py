"""Logs for the analysis tests: the shipped campus_drive backend sweep (cut to 4 s: the
missile hit at ~3 s and avatar 1's bounce off tank_a at ~3.8 s are inside), an oscillator
run, and a copy of a log with one signal changed from a known step."""
from __future__ import annotations

from pathlib import Path

import orjson
import pytest

from immersim.orchestrator.execution import run_scenario

from ..orchestrator.helpers import oscillator_scenario

ROOT = Path(__file__).resolve().parents[2]
CAMPUS_STOP = 4.0
CAMPUS = ROOT / "scenarios" / "campus_drive.toml"


@pytest.fixture(scope="session")
def campus_sweep(tmp_path_factory, built_fmus) -> Path:
    """Output folder of ``scenarios/sweeps/campus_backends.toml`` (fcl, basis_point,
    honeycomb) run to ``CAMPUS_STOP`` s: the shipped sweep file with the scenario path made
    absolute and ``simulation.stop`` added to its grid."""
    from immersim.orchestrator.sweep import run_sweep

    tmp = tmp_path_factory.mktemp("campus_sweep")
    text = (ROOT / "scenarios" / "sweeps" / "campus_backends.toml").read_text()
    scenario = CAMPUS.as_posix()
    text = text.replace('scenario = "../campus_drive.toml"', f'scenario = "{scenario}"')
    text = text.replace("[grid]\n", f'[grid]\n"simulation.stop" = [{CAMPUS_STOP}]\n', 1)
    sweep = tmp / "campus_backends.toml"
    sweep.write_text(text)
    run_sweep(sweep, tmp / "out", workers=2, progress=False)
    return tmp / "out"


@pytest.fixture(scope="session")
def osc_log(tmp_path_factory, test_fmus) -> Path:
    """Two coupled oscillators, 30 steps of 0.033 s, JSON log."""
    tmp = tmp_path_factory.mktemp("osc")
    scn = oscillator_scenario(tmp, test_fmus["oscillator"], step=0.033, stop=0.99,
                              extra='\n[log]\nencoding = "json"\n')
    return run_scenario(scn, tmp / "osc.mcap").output


def rewrite_log(src: Path, dst: Path, change) -> Path:
    """Copy the MCAP log ``src`` to ``dst`` message by message (JSON channels), calling
    ``change(topic, sample_index, obj)`` on every decoded unit message (it edits ``obj`` in place)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    counts = {}
    with open(src, "rb") as fin, open(dst, "wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout)
        writer.start()
        schemas, channels = {}, {}
        for schema, channel, message in reader.iter_messages():
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                               schemas[schema.id], channel.metadata)
            data = message.data
            if channel.message_encoding == "json" and not channel.topic.endswith("/parameters"):
                k = counts[channel.topic] = counts.get(channel.topic, -1) + 1
                obj = orjson.loads(data)
                change(channel.topic, k, obj)
                data = orjson.dumps(obj)
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        for md in reader.iter_metadata():
            writer.add_metadata(md.name, md.metadata)
        writer.finish()
    return dst
