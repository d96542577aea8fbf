"""Shared fixtures: the built FMUs (built-in units and the test units in tests/units/)."""
from __future__ import annotations

from pathlib import Path

import pytest

from immersim.orchestrator.build import build_all, build_unit, default_build_dir, unit_names

TESTS = Path(__file__).parent


@pytest.fixture(scope="session")
def built_fmus() -> dict:
    """Unit name -> path of its FMU, built incrementally into the default build folder
    (``make test`` has already built them, so this is a cheap up-to-date check)."""
    names = unit_names()
    return dict(zip(names, build_all(names, default_build_dir())))


@pytest.fixture(scope="session")
def test_fmus(tmp_path_factory) -> dict:
    """Test unit name -> FMU path for the units under tests/units/."""
    dest = tmp_path_factory.mktemp("test_fmus")
    return {d.name: build_unit(d, dest) for d in sorted((TESTS / "units").iterdir())
            if (d / f"{d.name}_fmu.py").exists()}
