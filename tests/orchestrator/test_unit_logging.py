"""A packed unit's Python log records (here the collision scene's summary, logged while the unit
sets up) reach the master once, through the instance's FMI logger, named by the instance; they
do not also propagate into the master's own logging under the packed package's name, and a
second run in the same process does not add a second route."""
import logging
from pathlib import Path

from immersim.orchestrator.cli import main

ROOT = Path(__file__).resolve().parents[2]


class _Records(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.records = []

    def emit(self, record):
        self.records.append(record)


def test_a_units_log_record_arrives_once_through_its_fmi_logger(tmp_path):
    # a handler of our own on the root logger: pytest's capture handler is also attached to
    # every non-propagating logger, so it would see the packed package's records directly
    root, seen = logging.getLogger(), _Records()
    level = root.level
    root.addHandler(seen)
    root.setLevel(logging.DEBUG)
    try:
        for run in range(2):
            seen.records.clear()
            out = tmp_path / f"t{run}.mcap"
            assert main(["run", str(ROOT / "scenarios" / "tank_field.toml"), "-q", "-o", str(out)]) == 0
            scene = [r for r in seen.records if "bodies (" in r.getMessage()]
            assert [r.name for r in scene] == ["immersim.orchestrator.fmu"]
            assert scene[0].getMessage().startswith("unit coll [ok]: scene 'tanks:n=100")
            assert scene[0].levelno == logging.DEBUG
    finally:
        root.removeHandler(seen)
        root.setLevel(level)
    packed = [n for n in logging.root.manager.loggerDict if n.startswith("immersim_") and "." not in n]
    assert packed and all(
        [type(h).__name__ for h in logging.getLogger(n).handlers].count("_FmiLog") == 1 for n in packed)
