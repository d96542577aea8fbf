"""The wheel built from the sdist, installed outside the checkout, runs the shipped scenarios
from an empty folder with FMUs built from its own files into the user's cache folder."""
from __future__ import annotations

import subprocess
import tarfile
import zipfile

import numpy as np

from immersim.orchestrator.mcapio import read_info, read_series
from immersim.orchestrator.execution import run_scenario

from tests.install.isolated import ROOT

UNITS = ("collision", "network", "platform")


def test_sdist_and_wheel_carry_the_units_and_the_example_scenarios(dists_and_env):
    sdist, wheel, _ = dists_and_env
    with tarfile.open(sdist) as t:
        in_sdist = {n.split("/", 1)[1] for n in t.getnames() if "/" in n}
    with zipfile.ZipFile(wheel) as z:
        in_wheel = set(z.namelist())
    for unit in UNITS:
        assert f"fmus/{unit}/{unit}_fmu.py" in in_sdist
        assert f"immersim/fmus/{unit}/{unit}_fmu.py" in in_wheel
    shipped = sorted(p.relative_to(ROOT / "scenarios").as_posix() for p in (ROOT / "scenarios").rglob("*.toml"))
    assert shipped and all(f"scenarios/{s}" in in_sdist and f"immersim/scenarios/{s}" in in_wheel for s in shipped)
    # everything a build packs: the wrapper's common package and every models module
    models = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "models").rglob("*.py") if "__pycache__" not in p.parts)
    assert all(f"immersim/{m}" in in_wheel for m in models)


def test_installed_wheel_runs_every_shipped_scenario_from_an_empty_folder(dists_and_env, tmp_path):
    _, _, env = dists_and_env
    home, cwd = tmp_path / "home", tmp_path / "empty"
    home.mkdir()
    cwd.mkdir()

    def run(*args: str) -> str:
        res = subprocess.run([str(a) for a in args], cwd=cwd, env=env.env(home), capture_output=True, text=True,
                             timeout=300)
        assert res.returncode == 0, res.stderr
        return res.stdout

    probe = ("import sys, immersim, immersim.orchestrator.cli, immersim.models, immersim.fmus.common\n"
             "print('\\n'.join(sorted({getattr(m, '__file__', None) or '' for n, m in sys.modules.items()\n"
             "                           if n == 'immersim' or n.startswith('immersim.')})))")
    files = run(env.python, "-c", probe).split()
    assert len(files) >= 5 and all(f.startswith(str(env.root / "venv")) for f in files), files
    listing = run(env.immersim, "examples")
    assert "demo.toml" in listing and "campus_drive.toml" in listing and "sweeps/platform_ablation.toml" in listing
    run(env.immersim, "examples", "--copy", ".", "demo", "campus_drive")
    # a scenario comes with the files it includes
    assert sorted(p.name for p in cwd.iterdir()) == ["campus_common.toml", "campus_drive.toml", "demo.toml"]

    out = run(env.immersim, "run", "demo.toml", "-q", "-o", "demo.mcap")
    assert "243 steps to t = 8 s" in out
    # FMUs built from the wheel's own files into the user's cache folder
    cache = home / ".cache" / "immersim" / "fmus"
    assert (cache / "platform.fmu").is_file()
    # the same physics as the checkout: every logged signal equal to a run of the checkout
    ref = tmp_path / "checkout_demo.mcap"
    run_scenario(ROOT / "scenarios" / "demo.toml", ref)
    got, want = read_series(cwd / "demo.mcap", ["*"]), read_series(ref, ["*"])
    assert sorted(got) == sorted(want)
    for name, (t, y, _) in want.items():
        np.testing.assert_array_equal(got[name][0], t)
        np.testing.assert_array_equal(got[name][1], y, err_msg=name)

    out = run(env.immersim, "run", "campus_drive.toml", "-q", "-o", "campus.mcap", "--set", "simulation.stop=0.495")
    assert "15 steps to t = 0.495 s" in out
    info = read_info(cwd / "campus.mcap")
    assert info.metadata["run"]["status"] == "completed"
    assert {t.split("/")[0] for t in info.channels} >= {"net", "coll", "plat"}
    assert sorted(p.name for p in cache.glob("*.fmu")) == [f"{u}.fmu" for u in UNITS]

    # every other shipped scenario, two macro steps each, in one process of the wheel's immersim
    run(env.immersim, "examples", "--copy", "all")
    script = (
        "import pathlib, sys\n"
        "from immersim.orchestrator.execution import run_scenario\n"
        "from immersim.orchestrator.scenario import load_scenario\n"
        "for f in sys.argv[1:]:\n"
        "    sc = load_scenario(f)\n"
        "    stop = (sc.start_ns + 2 * sc.step_ns) / 1e9\n"
        "    r = run_scenario(load_scenario(f, {'simulation.stop': stop}), pathlib.Path(f).with_suffix('.mcap'))\n"
        "    print(f, r.status, r.steps_done)\n")
    scenarios = sorted(str(p.relative_to(cwd)) for p in (cwd / "all").rglob("*.toml")
                       if "scenario =" not in p.read_text() and p.name not in ("demo.toml", "campus_drive.toml"))
    assert len(scenarios) >= 6
    lines = run(env.python, "-c", script, *scenarios).splitlines()
    assert lines == [f"{f} completed 2" for f in scenarios]
