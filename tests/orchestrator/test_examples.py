"""``immersim examples``: the shipped scenarios are the repository's scenarios/, copies keep
the layout (a sweep file still finds its base scenario), nothing is overwritten."""
from __future__ import annotations

from pathlib import Path

import pytest

from immersim.orchestrator.cli import main as cli_main
from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.examples import copy_examples, examples_dir, list_examples
from immersim.orchestrator.sweep import load_sweep

ROOT = Path(__file__).resolve().parents[2]


def test_the_shipped_examples_are_the_scenarios_folder():
    assert examples_dir() == (ROOT / "scenarios").resolve()
    names = [e.name for e in list_examples()]
    want = sorted(p.relative_to(ROOT / "scenarios").as_posix() for p in (ROOT / "scenarios").rglob("*.toml"))
    assert sorted(names) == want
    assert names.index("demo.toml") < names.index("sweeps/platform_ablation.toml")  # scenarios first
    demo = next(e for e in list_examples() if e.name == "demo.toml")
    assert demo.title.startswith("demo: washout cueing")


def test_a_copied_sweep_brings_its_base_scenario_and_loads(tmp_path):
    written = copy_examples(tmp_path, ["sweeps/platform_ablation", "demo"])
    assert sorted(p.relative_to(tmp_path).as_posix() for p in written) == [
        "demo.toml", "sweeps/platform_ablation.toml", "sweeps/platform_pose.toml"]
    assert (tmp_path / "demo.toml").read_bytes() == (ROOT / "scenarios" / "demo.toml").read_bytes()
    spec = load_sweep(tmp_path / "sweeps" / "platform_ablation.toml")
    assert spec.scenario == (tmp_path / "sweeps" / "platform_pose.toml").resolve() and len(spec.variants) == 5


def test_copy_refuses_unknown_names_and_existing_files(tmp_path, capsys):
    with pytest.raises(ScenarioError, match=r"^examples: no shipped scenario 'nope' \(see immersim examples\)$"):
        copy_examples(tmp_path, ["demo", "nope"])
    assert not any(tmp_path.iterdir())
    (tmp_path / "campus_drive.toml").write_text("mine")
    assert cli_main(["examples", "--copy", str(tmp_path), "demo", "campus_drive"]) == 2
    err = capsys.readouterr().err
    assert err == f"immersim: error: examples: {tmp_path / 'campus_drive.toml'} exists already; nothing copied\n"
    assert (tmp_path / "campus_drive.toml").read_text() == "mine" and not (tmp_path / "demo.toml").exists()


def test_cli_lists_names_and_titles(capsys):
    assert cli_main(["examples"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(list_examples())
    assert any(line.startswith("sweeps/platform_ablation.toml") and line.endswith("platform: controller x integrator")
               for line in lines)
