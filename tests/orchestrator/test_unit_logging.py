"""A packed unit's Python log records (here the collision scene's summary, logged while the unit
sets up) reach the master once, through the instance's FMI logger, named by the instance; they
do not also propagate into the master's own logging under the packed package's name."""
import logging
from pathlib import Path

from immersim.orchestrator.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_a_units_log_record_arrives_once_through_its_fmi_logger(tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    assert main(["run", str(ROOT / "scenarios" / "tank_field.toml"), "-q", "-o", str(tmp_path / "t.mcap")]) == 0
    scene = [r for r in caplog.records if "bodies (" in r.getMessage()]
    from_unit = [r for r in scene if r.name == "immersim.orchestrator.fmu"]
    assert len(from_unit) == 1 and from_unit[0].getMessage().startswith("unit coll [ok]: scene 'tanks:n=100")
    assert from_unit[0].levelno == logging.DEBUG
    assert not [r for r in scene if r.name.startswith("immersim_")]
