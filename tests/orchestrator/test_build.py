"""The FMU build pipeline: valid FMI 2.0 CS FMUs, incremental builds, several instances,
the same results in FMPy and in OSP libcosim."""
import math
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy.validation import validate_fmu

from immersim.orchestrator.build import build_unit
from immersim.orchestrator.crosscheck import simulate_fmpy, simulate_libcosim
from immersim.orchestrator.errors import BuildError, ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.fmu import read_model

from ..conftest import TESTS


def test_validates_and_declares_units(test_fmus):
    fmu = test_fmus["oscillator"]
    assert validate_fmu(str(fmu)) == []
    md, variables = read_model(fmu, "osc")
    assert md.fmiVersion == "2.0" and md.coSimulation.modelIdentifier == "oscillator"
    assert variables["x"].unit == "m" and variables["v"].unit == "m/s" and variables["k"].unit == "N/m"
    assert variables["x"].causality == "output" and variables["x_other"].causality == "input"
    assert md.coSimulation.canGetAndSetFMUstate


def test_packs_models_so_only_third_party_packages_are_needed(test_fmus):
    z = zipfile.ZipFile(test_fmus["oscillator"])
    names = z.namelist()
    module = z.read("resources/slavemodule.txt").decode()
    tag = module.rsplit("_", 1)[1]
    assert re.fullmatch(r"oscillator_fmu_[0-9a-f]{12}", module) and f"resources/{module}.py" in names
    assert f"resources/immersim_{tag}/models/__init__.py" in names
    assert f"resources/immersim_{tag}/fmus/common/slave.py" in names
    assert "binaries/linux64/oscillator.so" in names
    # the script imports its own packed copy, never the master's immersim
    script = z.read(f"resources/{module}.py").decode()
    assert f"from immersim_{tag}.fmus.common import" in script and "from immersim." not in script


def test_two_builds_of_a_unit_run_their_own_code_in_one_process(tmp_path, test_fmus):
    """An ablation that swaps a unit for another build of it: both builds in one run, each with
    its own code (Python imports a module name once per process; each build has its own)."""
    unit = tmp_path / "oscillator"
    shutil.copytree(TESTS / "units" / "oscillator", unit)
    script = unit / "oscillator_fmu.py"
    text = script.read_text()
    assert text.count("w = math.sqrt((k + kc) / m)") == 1  # a changed model: twice the frequency
    script.write_text(text.replace("w = math.sqrt((k + kc) / m)", "w = 2.0 * math.sqrt((k + kc) / m)"))
    stiff = build_unit(unit, tmp_path / "stiff")
    scn = tmp_path / "two.toml"
    scn.write_text(f'[simulation]\nstop = 0.99\n[[units]]\nname = "soft"\nfmu = "{test_fmus["oscillator"]}"\n'
                   'parameters = { x0 = 1.0 }\n'
                   f'[[units]]\nname = "stiff"\nfmu = "{stiff}"\nparameters = {{ x0 = 1.0 }}\n')
    res = run_scenario(scn, tmp_path / "two.mcap")
    t = 0.99
    for name, w in (("soft", math.sqrt(2.0)), ("stiff", 2.0 * math.sqrt(2.0))):  # x_other = 0: x0 cos(w t)
        assert res.values[name]["x"] == pytest.approx(math.cos(w * t), abs=1e-9)


def test_incremental_build(tmp_path):
    unit = tmp_path / "oscillator"
    shutil.copytree(TESTS / "units" / "oscillator", unit)
    dest = tmp_path / "out"
    fmu = build_unit(unit, dest)
    first = fmu.stat().st_mtime_ns
    assert build_unit(unit, dest).stat().st_mtime_ns == first  # up to date: untouched
    script = unit / "oscillator_fmu.py"
    script.write_text(script.read_text() + "\n# a change\n")
    assert build_unit(unit, dest).stat().st_mtime_ns != first  # sources changed: rebuilt


def test_build_error_names_unit(tmp_path):
    unit = tmp_path / "ghost"
    unit.mkdir()
    with pytest.raises(BuildError, match=r"unit folder .*ghost: no wrapper script ghost_fmu.py"):
        build_unit(unit, tmp_path / "out")


def test_several_instances_and_libcosim_agree(test_fmus):
    fmu = test_fmus["oscillator"]
    start = {"x0": 1.0, "x_other": 0.5, "k": 2.0}
    ours = simulate_fmpy(fmu, start, 60, ["x", "v"], instances=3)
    other = simulate_libcosim(fmu, start, 60, ["x", "v"], instances=3)
    for a in ours + other:
        np.testing.assert_allclose(a["x"], ours[0]["x"], rtol=0, atol=1e-14)
    # the exact solution for a held input: x_eq + (x0 - x_eq) cos(w t)
    w = np.sqrt(3.0)
    t = 0.033 * np.arange(1, 61)
    x_eq = 0.5 / 3.0
    np.testing.assert_allclose(ours[0]["x"], x_eq + (1 - x_eq) * np.cos(w * t), atol=1e-12)


def test_fmu_state_round_trip(test_fmus):
    """canGetAndSetFMUstate is honoured: restoring a state replays the same trajectory."""
    from immersim.orchestrator.fmu import FmuInstance

    inst = FmuInstance("s", test_fmus["oscillator"])
    try:
        inst.initialize(0, None, {"x0": 1.0, "x_other": 0.2})
        for k in range(5):
            inst.do_step(k * 33_000_000, 33_000_000)
        state = inst.fmu.getFMUState()
        inst.do_step(5 * 33_000_000, 33_000_000)
        after = inst.get_values(["x", "v"])
        inst.fmu.setFMUState(state)
        inst.t_ns = 5 * 33_000_000
        inst.do_step(5 * 33_000_000, 33_000_000)
        assert inst.get_values(["x", "v"]) == after
    finally:
        inst.terminate()


def test_instances_of_one_fmu_share_one_extraction(test_fmus, tmp_path):
    """Instances in one run load one extracted copy (the FMU allows several per process) and
    stay independent: each follows its own closed-form trajectory."""
    from immersim.orchestrator.fmu import FmuInstance

    a = FmuInstance("a", test_fmus["oscillator"], tmp_path / "a")
    b = FmuInstance("b", test_fmus["oscillator"], tmp_path / "b")
    c = FmuInstance("c", test_fmus["oscillator"], tmp_path / "elsewhere" / "c")
    try:
        assert not a.model_description.coSimulation.canBeInstantiatedOnlyOncePerProcess
        assert str(a.unzip_dir) == str(b.unzip_dir) == str(tmp_path / "a") != str(c.unzip_dir)
        a.initialize(0, None, {"x0": 1.0})
        b.initialize(0, None, {"x0": -0.5})
        for k in range(30):
            a.do_step(k * 33_000_000, 33_000_000)
            b.do_step(k * 33_000_000, 33_000_000)
        t = 30 * 0.033
        w = np.sqrt(2.0)  # m = k = kc = 1, x_other = 0
        np.testing.assert_allclose(a.get_values(["x"])[0], np.cos(w * t), atol=1e-12)
        np.testing.assert_allclose(b.get_values(["x"])[0], -0.5 * np.cos(w * t), atol=1e-12)
    finally:
        for inst in (a, b, c):
            inst.terminate()


def test_exception_left_by_an_in_process_fmu_is_a_typed_error(test_fmus, tmp_path):
    """A per-step FMI call that raises a Python exception (a pythonfmu FMU is called without
    releasing the GIL, so an error it leaves set surfaces in the caller) is reported as a
    failed call naming unit, function and time."""
    from immersim.orchestrator.errors import FmuCallError
    from immersim.orchestrator.fmu import FmuInstance

    inst = FmuInstance("u", test_fmus["oscillator"], tmp_path / "u")
    try:
        assert inst.in_process_python
        inst.initialize(0, None, {"x0": 1.0})
        inst.do_step(0, 33_000_000)

        def broken(*args):
            raise ValueError("left set by the FMU")

        inst._do_step = broken
        with pytest.raises(FmuCallError, match=r"unit u: fmi2DoStep .* at t = 0.033 s: ValueError: left set by the FMU"):
            inst.do_step(33_000_000, 33_000_000)
    finally:
        inst.terminate()


def test_forget_python_code_drops_what_was_imported_from_the_folder(tmp_path):
    """Modules imported from a folder through a sys.path entry spelled through a symlink (a
    package, its submodule, a namespace package and its module) are dropped with that entry,
    given the folder's real path; modules and entries elsewhere stay."""
    import importlib
    import sys

    from immersim.orchestrator.fmu import forget_python_code

    folder = tmp_path / "extracted"
    (folder / "pkg_forget_t").mkdir(parents=True)
    (folder / "pkg_forget_t" / "__init__.py").write_text("")
    (folder / "pkg_forget_t" / "sub.py").write_text("X = 1\n")
    (folder / "ns_forget_t").mkdir()
    (folder / "ns_forget_t" / "mod.py").write_text("Y = 2\n")
    link = tmp_path / "link"
    link.symlink_to(folder)
    sys.path.insert(0, str(link))
    try:
        importlib.import_module("pkg_forget_t.sub")
        importlib.import_module("ns_forget_t.mod")
        assert sys.modules["pkg_forget_t.sub"].__file__.startswith(str(link))
        before = set(sys.modules) - {"pkg_forget_t", "pkg_forget_t.sub", "ns_forget_t", "ns_forget_t.mod"}
        path_before = [p for p in sys.path if p != str(link)]
        assert forget_python_code(folder.resolve()) == 4
        assert not {"pkg_forget_t", "pkg_forget_t.sub", "ns_forget_t", "ns_forget_t.mod"} & set(sys.modules)
        assert before <= set(sys.modules) and sys.path == path_before
        assert forget_python_code(folder) == 0
    finally:
        if str(link) in sys.path:
            sys.path.remove(str(link))


# -- sized builds: capacities as build options ------------------------------------------------
@pytest.fixture(scope="module")
def sized(tmp_path_factory):
    """The network unit at its default size (4 players) and at 8; collision at 16 bodies/16 pairs."""
    from immersim.orchestrator.build import build_all

    dest = tmp_path_factory.mktemp("sized")
    return {"network": build_all(["network"], dest)[0],
            "network8": build_all(["network"], dest, options={"players": 8})[0],
            "collision16": build_all(["collision"], dest, options={"bodies": 16, "pairs": 16})[0],
            "dest": dest}


def _names(fmu):
    return list(read_model(fmu, "u")[1])


def test_sized_builds_validate_and_declare_their_capacity(sized):
    from immersim.fmus.collision.collision_fmu import PAIR_REALS, POSE
    from immersim.fmus.network.network_fmu import AVATAR_FIELDS

    assert sized["network8"].name == "network-players8.fmu" and sized["collision16"].name == "collision-bodies16-pairs16.fmu"
    for key in ("network", "network8", "collision16"):
        assert validate_fmu(str(sized[key])) == [], key
    four, eight = _names(sized["network"]), _names(sized["network8"])
    per_player = 6 + len(AVATAR_FIELDS) + 2    # inputs throttle, steer, contact.{active,nx,ny,depth}; outputs
    assert len(eight) - len(four) == 4 * per_player
    assert "avatar[8].jolt_acc" in eight and "contact[8].depth" in eight and "perceived[8].y" in eight
    assert "avatar[5].x" not in four and "avatar[9].x" not in eight and "entity[16].z" in eight
    # the players added at the end of each block, the default's variables in their order
    assert [n for n in eight if n in set(four)] == four
    md8 = read_model(sized["network8"], "u")[1]
    assert md8["avatar[8].throttle"].causality == "input" and md8["avatar[8].x"].unit == "m"
    coll = _names(sized["collision16"])
    assert sum(n.startswith("body[") for n in coll) == 16 * len(POSE)
    assert sum(n.startswith("pair[") for n in coll) == 16 * (1 + len(PAIR_REALS))


def test_sized_builds_are_cached_by_their_options(sized):
    from immersim.orchestrator.build import build_all

    dest, fmu = sized["dest"], sized["network8"]
    first = fmu.stat().st_mtime_ns
    assert build_all(["network"], dest, options={"players": 8})[0].stat().st_mtime_ns == first   # up to date
    # options equal to the defaults are the default build
    assert build_all(["network"], dest, options={"players": 4, "entity_outputs": 16})[0] == sized["network"]
    # each size packs its own code under its own name (the options are part of the digest)
    tags = {zipfile.ZipFile(sized[k]).read("resources/slavemodule.txt") for k in ("network", "network8")}
    assert len(tags) == 2
    chosen = [n for n in zipfile.ZipFile(fmu).namelist() if n.endswith("build_options.json")]
    assert len(chosen) == 1 and b'"players": 8' in zipfile.ZipFile(fmu).read(chosen[0])
    assert not any(n.endswith("build_options.json") for n in zipfile.ZipFile(sized["network"]).namelist())


def test_a_sized_network_runs_in_fmpy_and_libcosim_as_in_our_master(sized):
    """FMPy's own master, OSP libcosim and ours step the 8-player FMU to the same values;
    players 5-8 drive (constant throttle 0.1 p: the faster the larger p)."""
    from fmpy import simulate_fmu

    from immersim.orchestrator.crosscheck import simulate_fmpy, simulate_libcosim

    fmu, n = sized["network8"], 30
    start = {"players": 8, "render_nodes": 2, **{f"avatar[{p}].throttle": 0.1 * p for p in range(1, 9)}}
    outs = [f"avatar[{p}].{c}" for p in range(1, 9) for c in ("x", "y", "vx", "vy")]
    theirs = simulate_fmu(str(fmu), start_values=start, stop_time=n * 0.033, step_size=0.033,
                          output_interval=0.033, output=outs)
    ours = simulate_fmpy(fmu, start, n, outs)[0]
    osp = simulate_libcosim(fmu, start, n, outs)[0]
    for name in outs:
        np.testing.assert_array_equal(theirs[name][1:], ours[name], err_msg=name)
        np.testing.assert_array_equal(osp[name], ours[name], err_msg=name)
    speed = [math.hypot(ours[f"avatar[{p}].vx"][-1], ours[f"avatar[{p}].vy"][-1]) for p in range(1, 9)]
    assert speed[0] > 0.1 and all(np.diff(speed) > 0)


def test_build_options_refused_in_one_line(tmp_path, capsys):
    from immersim.orchestrator.cli import main

    for args, line in (
            (["network", "--option", "player=8"],
             "unit network: unknown build option 'player' (options: players, entity_outputs)"),
            (["network", "--option", "players=33"], "unit network: build option players = 33 must be in 1..32"),
            (["collision", "--option", "pairs=0"], "unit collision: build option pairs = 0 must be in 1..64"),
            (["network", "--option", "players=eight"], "--option players=eight: expected NAME=INTEGER, e.g. players=8"),
            (["platform", "--option", "players=8"], "unit platform: takes no build options (got 'players')"),
            (["--option", "players=8"],
             "build options need the units they size: name them (immersim build network --option ...)")):
        assert main(["build", *args, "-d", str(tmp_path)]) == 2, args
        assert capsys.readouterr().err == f"immersim: error: {line}\n"
    assert not list(tmp_path.glob("*.fmu"))


def test_a_scenario_sizes_its_units(tmp_path, sized, monkeypatch):
    monkeypatch.setenv("IMMERSIM_BUILD_DIR", str(sized["dest"]))
    scn = tmp_path / "eight.toml"
    body = ('[simulation]\nstop = 0.099\n[[units]]\nname = "net"\nfmu = "network"\nbuild = {{ {} }}\n'
            '[units.parameters]\nplayers = 8\n[[inputs]]\ntarget = "net.avatar[8].throttle"\nkind = "constant"\nvalue = 1.0\n')
    scn.write_text(body.format("players = 8"))
    res = run_scenario(scn, tmp_path / "eight.mcap")
    assert res.status == "completed" and res.values["net"]["avatar[8].vx"] ** 2 + res.values["net"]["avatar[8].vy"] ** 2 > 0
    for build, err, message in (
            ("players = 9.5", ScenarioError, r"units\[0\]\.build\.players: a build option is an integer"),
            ("players = 40", BuildError, rf"^{re.escape(str(scn))}: unit net \(network\): build option players = 40 "
                                          r"must be in 1\.\.32$"),
            ("seats = 8", BuildError, r"unit net \(network\): unknown build option 'seats' \(options: players, ")):
        scn.write_text(body.format(build))
        with pytest.raises(err, match=message):
            run_scenario(scn, tmp_path / "bad.mcap")
    # the default build holds 4 players: a scenario asking for more is told which option sizes it
    scn.write_text(body.format("").replace("build = {  }\n", "").split("[[inputs]]")[0])
    with pytest.raises(Exception, match=r"parameter players = 8 must be in 1\.\.4 \(build option players\)"):
        run_scenario(scn, tmp_path / "four.mcap")
    # and a variable beyond its capacity is refused with how the unit was built
    scn.write_text(body.format("").replace("build = {  }\n", "").replace("players = 8\n", "players = 4\n"))
    with pytest.raises(ScenarioError, match=re.escape(
            "unit net (network.fmu) has no variable 'avatar[8].throttle'; did you mean avatar[1].throttle, "
            "avatar[2].throttle, avatar[3].throttle? (built with players = 4, entity_outputs = 16; build = { ... } "
            "in its [[units]] table sizes it)")):
        run_scenario(scn, tmp_path / "four.mcap")


def test_a_sweep_ships_the_sized_build(tmp_path, sized, monkeypatch):
    """A sweep's tasks carry the FMU their scenario builds (the sized one), not the default."""
    from types import SimpleNamespace

    from immersim.orchestrator.sweep.shipping import attach_inputs

    monkeypatch.setenv("IMMERSIM_BUILD_DIR", str(sized["dest"]))
    scn = tmp_path / "eight.toml"
    scn.write_text('[[units]]\nname = "net"\nfmu = "network"\nbuild = { players = 8 }\n'
                   '[[units]]\nname = "net4"\nfmu = "network"\n')
    tasks = [SimpleNamespace(overrides={}, index=0)]
    blobs, failed = attach_inputs(tasks, scn)
    assert not failed and len(blobs) == 2
    assert tasks[0].fmus["net"][1] == str(sized["network8"]) and tasks[0].fmus["net4"][1] == str(sized["network"])


@pytest.mark.parametrize("unit", ["network", "collision"])
def test_the_unit_readme_lists_its_build_options(unit):
    """The README's table of build options is the one generated from the wrapper's declaration."""
    import importlib

    from immersim.fmus.common import options_table

    wrapper = importlib.import_module(f"immersim.fmus.{unit}.{unit}_fmu")
    assert len(wrapper.BUILD_OPTIONS) == 2
    assert options_table(wrapper.BUILD_OPTIONS) in (TESTS.parent / "fmus" / unit / "README.md").read_text()


@pytest.mark.parametrize("unit, options, count", [
    ("network", {"players": 1, "entity_outputs": 0}, 32 + 22 * 1 + 3 * 0),
    ("network", {"players": 32, "entity_outputs": 64}, 32 + 22 * 32 + 3 * 64),
    ("collision", {"bodies": 1, "pairs": 1}, 14 + 6 * 1 + 11 * 1),
    ("collision", {"bodies": 64, "pairs": 64}, 14 + 6 * 64 + 11 * 64)])
def test_the_smallest_and_largest_builds_validate(tmp_path, unit, options, count):
    """Either end of each option's range: a valid model description with the variables it
    sizes (network: 22 per player, 3 per entity output; collision: 6 per body, 11 per pair)."""
    from immersim.orchestrator.build import build_all

    fmu = build_all([unit], tmp_path, options=options)[0]
    assert validate_fmu(str(fmu)) == [] and len(_names(fmu)) == count


@pytest.mark.parametrize("unit", ["network", "collision"])
def test_the_build_reads_the_options_the_wrapper_declares(unit):
    """The build reads BUILD_OPTIONS from the wrapper's source (without importing its model):
    the same declarations the wrapper itself sizes its variables from."""
    import importlib

    from immersim.orchestrator.build import declared_options

    wrapper = importlib.import_module(f"immersim.fmus.{unit}.{unit}_fmu")
    assert declared_options(Path(wrapper.__file__)) == wrapper.BUILD_OPTIONS


def test_a_size_built_again_after_another_importer_ran_it(tmp_path, sized):
    """libcosim ran the sized FMU in this process from a folder it has since removed; the
    packed package stays imported under the build's name. A second build of that size (into
    another folder) imports it again and must still declare 8 players."""
    from immersim.orchestrator.build import build_all
    from immersim.orchestrator.crosscheck import simulate_libcosim

    simulate_libcosim(sized["network8"], {"players": 8}, 2, ["avatar[8].x"])
    again = build_all(["network"], tmp_path, options={"players": 8})[0]
    assert _names(again) == _names(sized["network8"])
