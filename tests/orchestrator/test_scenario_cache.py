"""The checked-scenario cache (orchestrator/scenariocache.py): a scenario read again is the one
its check made, without importing the schema; any change of its texts or overrides checks it
again; a damaged entry or a failed check is never used."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from immersim.orchestrator import scenariocache
from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.scenario import load_scenario, parse_scenario, tomllib

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("IMMERSIM_SCENARIO_CACHE", str(folder))
    return folder


@pytest.fixture
def campus(tmp_path):
    """campus_drive and the file it includes, copied (so that a test may edit them)."""
    for name in ("campus_drive.toml", "campus_common.toml"):
        (tmp_path / name).write_text((SCENARIOS / name).read_text())
    return tmp_path / "campus_drive.toml"


def checked(path, overrides=None):
    text = path.read_text()
    return parse_scenario(tomllib.loads(text), path, text, overrides)


def test_a_hit_is_the_checked_scenario(cache, campus):
    first = load_scenario(campus)
    assert len(list(cache.glob("*.pickle"))) == 1
    again = load_scenario(campus)
    assert again is not first and again == first == checked(campus)
    for loc in (("units", 1, "parameters", "scene"), ("connections", 3, "from"), ("log",)):
        assert again.where(*loc) == first.where(*loc)
    assert again.where("units", 1) != again.where("connections", 0)   # includes still named where written


def test_a_changed_include_or_override_is_checked_again(cache, campus):
    load_scenario(campus)
    common = campus.parent / "campus_common.toml"
    common.write_text(common.read_text().replace("seed = 0", "seed = 5"))
    sc = load_scenario(campus)
    assert sc == checked(campus) and sc.unit("net").parameters["seed"] == 5
    over = {"net.entities": 3}
    assert load_scenario(campus, over).unit("net").parameters["entities"] == 3
    assert load_scenario(campus).unit("net").parameters["entities"] == 8
    common.unlink()
    with pytest.raises(ScenarioError):
        load_scenario(campus)


def test_a_failed_check_is_not_stored(cache, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[simulation]\nstop = -1.0\n[[units]]\nname = "a"\nfmu = "x.fmu"\n')
    for _ in range(2):
        with pytest.raises(ScenarioError):
            load_scenario(bad)
    assert not list(cache.glob("*.pickle"))


def test_a_damaged_entry_is_checked_again_and_replaced(cache, campus):
    first = load_scenario(campus)
    entry, = cache.glob("*.pickle")
    entry.write_bytes(entry.read_bytes()[:100])
    assert load_scenario(campus) == first
    assert scenariocache.load(campus, campus.read_text()) == first


def test_the_cache_turned_off(tmp_path, campus, monkeypatch):
    monkeypatch.setenv("IMMERSIM_SCENARIO_CACHE", "0")
    assert load_scenario(campus) == checked(campus)
    assert scenariocache.cache_root() is None and scenariocache.load(campus, campus.read_text()) is None


def test_a_hit_imports_no_schema(cache, campus):
    code = ("import sys; from immersim.orchestrator.scenario import load_scenario; "
            f"load_scenario({str(campus)!r}); print('pydantic' in sys.modules)")
    env = dict(os.environ, IMMERSIM_SCENARIO_CACHE=str(cache))
    seen = [subprocess.check_output([sys.executable, "-c", code], env=env, text=True).strip() for _ in range(2)]
    assert seen == ["True", "False"]


def test_the_entries_used_last_are_kept(cache, campus, tmp_path, monkeypatch):
    monkeypatch.setattr(scenariocache, "KEEP", 3)
    load_scenario(campus)
    for k in range(4):
        load_scenario(campus, {"net.entities": k})   # stored
        load_scenario(campus)                          # used: kept
    assert len(list(cache.glob("*.pickle"))) == 3
    assert scenariocache.load(campus, campus.read_text()) is not None
    assert scenariocache.load(campus, campus.read_text(), {"net.entities": 0}) is None
