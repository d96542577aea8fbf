"""immersim.run: a scenario run from Python with overrides, the same path as ``immersim run``."""
from __future__ import annotations

import os

import pytest

import immersim
from immersim.orchestrator.cli import main
from immersim.orchestrator.errors import ScenarioError

from .conftest import ROOT


def test_run_from_python_and_from_the_command_line(tmp_path, monkeypatch, capsys):
    """immersim.run writes the log where asked (default: results/runs/<stem>.mcap, as the CLI),
    applies the overrides, and read_log reads it back; a bad override is the CLI's error."""
    scenario = ROOT / "scenarios" / "demo.toml"
    log = immersim.run(scenario, {"simulation.stop": 0.33}, tmp_path / "demo.mcap")
    assert log == tmp_path / "demo.mcap"
    df = immersim.read_log(log, ["platform.pose.*"])
    assert len(df) == 11 and df.index[-1] == 0.33
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scenario), "--set", "simulation.stop=0.066", "-q"]) == 0
    default = tmp_path / "results" / "runs" / "demo.mcap"
    assert capsys.readouterr().out.startswith(f"{scenario}: 2 steps to t = 0.066 s -> {os.path.relpath(default)}\n")
    assert immersim.run(scenario, {"simulation.stop": 0.066}) == default.relative_to(tmp_path)
    short = immersim.read_log(default, ["platform.pose.*"])
    assert short.equals(df.iloc[:3])  # the same first steps, bit for bit
    with pytest.raises(ScenarioError, match=r"simulation\.stop"):
        immersim.run(scenario, {"simulation.stop": -1.0})


def test_the_package_names_its_api():
    assert set(immersim.__all__) == {"run", "execute", "read_log", "read_channels", "diff_logs"}
    with pytest.raises(AttributeError, match="module 'immersim' has no attribute 'nothing'"):
        immersim.nothing  # noqa: B018
