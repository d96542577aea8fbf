"""The scenario format's shorthand (signal groups, parameter lists, scene tables, includes):
what it expands to, its one-line errors, and that the shipped campus files written with it are
the systems of their flat forms (tests/scenarios/flat/) and log the same bytes."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from mcap.reader import make_reader

from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.expand import names
from immersim.orchestrator.scenario import load_scenario, parse_override
from immersim.orchestrator.sweep import load_sweep

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"
FLAT = Path(__file__).resolve().parent / "flat"

OSC = '[[units]]\nname = "a"\nfmu = "platform"\n[[units]]\nname = "b"\nfmu = "platform"\n'


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


# -- names ---------------------------------------------------------------------------------
def test_a_group_expands_in_writing_order_the_leftmost_part_slowest():
    assert names("net.avatar[1..2].{x,y,yaw}") == [
        "net.avatar[1].x", "net.avatar[1].y", "net.avatar[1].yaw",
        "net.avatar[2].x", "net.avatar[2].y", "net.avatar[2].yaw"]
    assert names("coll.body[5..8].z") == [f"coll.body[{j}].z" for j in range(5, 9)]
    assert names("plat.cue.{ f_x , w_z }") == ["plat.cue.f_x", "plat.cue.w_z"]
    assert names("u.A[1,3]") == ["u.A[1,3]"]                    # an FMI 3.0 array element is one name
    assert names("plat.stroke[3]") == ["plat.stroke[3]"]        # a plain element name is one name


@pytest.mark.parametrize("pattern, message", [
    ("net.avatar[3..1].x", r"'net\.avatar\[3\.\.1\]\.x': the range \[3\.\.1\] is empty \(it must count up\)"),
    ("net.avatar[1].{x,,y}", r"an empty name in \{x,,y\}"),
    ("net.avatar[1..n].x", r"is not a signal group \(write \[a\.\.b\] with integers a <= b, or \{a,b,c\}\)"),
    ("net.avatar[1].{x,y", r"is not a signal group"),
])
def test_a_malformed_group_is_refused(pattern, message):
    with pytest.raises(ValueError, match=message):
        names(pattern)


# -- connections ---------------------------------------------------------------------------
def test_a_connection_group_is_one_connection_per_signal_with_its_options(tmp_path):
    sc = load_scenario(write(tmp_path, OSC + '[[connections]]\nfrom = "a.pose.{x,y,alpha}"\n'
                                             'to = "b.cue.{f_x,f_y,w_z}"\ndelayed = true\n'
                                             'gain = { f_y = 2.0 }\nextrapolation = { w_z = "zoh" }\n'))
    got = [(c.src_var, c.dst_var, c.gain, c.extrapolation, c.delayed) for c in sc.connections]
    assert got == [("pose.x", "cue.f_x", 1.0, None, True), ("pose.y", "cue.f_y", 2.0, None, True),
                   ("pose.alpha", "cue.w_z", 1.0, "zoh", True)]


@pytest.mark.parametrize("text, message", [
    pytest.param(OSC + '[[connections]]\nfrom = "a.pose.x"\nto = "b.cue.f_x"\n'
                       '[[connections]]\nfrom = "a.stroke[1..3]"\nto = "b.cue.{f_x,f_y}"\n',
                 r"^.*s\.toml: connections\[1\]: 'from' 'a\.stroke\[1\.\.3\]' names 3 "
                 r"signals, 'to' 'b\.cue\.\{f_x,f_y\}' names 2: they must name as many$", id="count_mismatch_table"),
    pytest.param('connections = ["a.stroke[1..2] -> b.cue.f_x"]\n' + OSC,
                 r"s\.toml: connections\[0\]: the left side 'a\.stroke\[1\.\.2\]' names 2 "
                 r"signals, the right side 'b\.cue\.f_x' names 1", id="count_mismatch_string"),
    pytest.param(OSC + '[[connections]]\nfrom = "a.pose.{x,y}"\nto = "b.cue.{f_x,f_y}"\n'
                       'extrapolation = { f_z = "zoh" }\n',
                 r"s\.toml: connections\[0\]\.extrapolation: 'f_z' names no signal of this "
                 r"connection \(its destinations end in f_x, f_y\)", id="option_table_names_no_signal"),
    pytest.param(OSC + '[[connections]]\nfrom = "a.pose.{x,y}"\nto = "b.cue.{f_x,f_y}"\n'
                       'extrapolation = { f_y = "cubic" }\n',
                 r"s\.toml: connections\[0\]\.extrapolation: 'cubic' is not one of zoh, "
                 r"linear, angle", id="member_bad_option"),
    pytest.param(OSC + '[[connections]]\nfrom = "a.pose.{x,y}"\nto = "b.cue.{f_x,f_x}"\n',
                 r"s\.toml: connections\[0\]: input b\.cue\.f_x is already connected "
                 r"\(connections\[0\]\)", id="member_already_connected"),
])
def test_a_group_error_names_the_file_and_the_entry_as_written(tmp_path, text, message):
    """A count mismatch names both counts; an option table must name signals of the group; an
    error in one member of a group names the entry as written."""
    with pytest.raises(ScenarioError, match=message):
        load_scenario(write(tmp_path, text))


def test_an_input_target_group_drives_each_signal(tmp_path):
    sc = load_scenario(write(tmp_path, OSC + '[[inputs]]\ntarget = "b.cue.{f_x,f_y}"\nkind = "step"\nat = 1.0\n'
                                             'value = 2.0\n'))
    assert [(s.var, s.kind, s.params) for s in sc.inputs] == [("cue.f_x", "step", {"at": 1.0, "value": 2.0}),
                                                              ("cue.f_y", "step", {"at": 1.0, "value": 2.0})]


# -- parameters ----------------------------------------------------------------------------
def test_parameter_groups_and_lists(tmp_path):
    sc = load_scenario(write(tmp_path, '[[units]]\nname = "c"\nfmu = "collision"\n[units.parameters]\n'
                                       '"body[1..2].{x,y}" = [1.0, 2.0, 3.0, 4.0]\n"body[1..2].z" = 2.5\n'
                                       'scene = [{ kind = "box", name = "a", sx = 4, sz = 4.4, dynamic = true },\n'
                                       '         { kind = "tank", y = "57.30" }, { kind = "missile" }]\n'
                                       'pairs = ["a vs tank_0", "missile vs any tank*"]\n'))
    assert sc.units[0].parameters == {
        "body[1].x": 1.0, "body[1].y": 2.0, "body[2].x": 3.0, "body[2].y": 4.0, "body[1].z": 2.5, "body[2].z": 2.5,
        "scene": "box:name=a,sx=4,sz=4.4,dynamic=1;tank:y=57.30;missile", "pairs": "a vs tank_0; missile vs any tank*"}


@pytest.mark.parametrize("line, message", [
    ('"body[1..2].{x,y}" = [1.0, 2.0, 3.0]', r"s\.toml: units\[0\]\.parameters\['body\[1\.\.2\]\.\{x,y\}'\]: the key "
                                              r"names 4 variables, the array has 3 values: give one value, or one per "
                                              r"variable"),
    ('"body[1..2].x" = 1.0\n"body[2].x" = 2.0', r"s\.toml: units\[0\]\.parameters\['body\[2\]\.x'\]: 'body\[2\]\.x' is "
                                                 r"set twice \(also by 'body\[1\.\.2\]\.x'\)"),
    ('scene = [{ name = "a" }]', r"s\.toml: units\[0\]\.parameters\.scene\[0\]: an item needs kind = \"\.\.\.\""),
    ('scene = [{ kind = "box", sx = [1, 2] }]', r"s\.toml: units\[0\]\.parameters\.scene\[0\]\.sx: expected a number, "
                                                 r"true/false or a string"),
])
def test_a_bad_parameter_group_or_list_is_one_line(tmp_path, line, message):
    path = write(tmp_path, f'[[units]]\nname = "c"\nfmu = "collision"\n[units.parameters]\n{line}\n')
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path)


# -- include -------------------------------------------------------------------------------
def test_an_included_file_is_a_fallback_merged_under_the_file(tmp_path):
    write(tmp_path, '[simulation]\nstop = 2.0\nstep = 0.01\n' + OSC.replace('name = "b"\nfmu = "platform"\n',
          'name = "b"\nfmu = "platform"\n[units.parameters]\nM = 200.0\nintegrator = "rk4"\n') +
          '[[connections]]\nfrom = "a.pose.x"\nto = "b.cue.f_x"\n', "common.toml")
    sc = load_scenario(write(tmp_path, 'include = "common.toml"\n[simulation]\nstop = 1.0\n'
                                       '[[units]]\nname = "b"\n[units.parameters]\nM = 250.0\n'
                                       '[[units]]\nname = "c"\nfmu = "network"\n'
                                       '[[connections]]\nfrom = "a.pose.y"\nto = "b.cue.f_y"\n'))
    assert (sc.stop_ns, sc.step_ns) == (1_000_000_000, 10_000_000)
    assert [(u.name, u.fmu, u.parameters) for u in sc.units] == [
        ("b", "platform", {"M": 250.0, "integrator": "rk4"}), ("c", "network", {}), ("a", "platform", {})]
    assert [c.dst_var for c in sc.connections] == ["cue.f_y", "cue.f_x"]
    assert list(sc.included) == [str(tmp_path / "common.toml")]


def test_an_error_in_an_included_file_names_that_file(tmp_path):
    write(tmp_path, OSC + '[[connections]]\nfrom = "a.pose.x"\nto = "b.cue.f_x"\ngain = "two"\n', "common.toml")
    with pytest.raises(ScenarioError, match=r"common\.toml: connections\[0\]\.gain: expected a number, got 'two'"):
        load_scenario(write(tmp_path, 'include = ["common.toml"]\n'))


def test_a_missing_include_and_a_cycle_are_one_line(tmp_path):
    with pytest.raises(ScenarioError, match=r"^.*s\.toml: include: 'nope\.toml' does not exist \(looked for .*nope\.toml\)$"):
        load_scenario(write(tmp_path, 'include = ["nope.toml"]\n' + OSC))
    write(tmp_path, 'include = ["s.toml"]\n', "b.toml")
    with pytest.raises(ScenarioError, match=r"^.*b\.toml: include: 's\.toml' includes itself \(s\.toml -> b\.toml -> "
                                            r"s\.toml\)$"):
        load_scenario(write(tmp_path, 'include = ["b.toml"]\n' + OSC))
    with pytest.raises(ScenarioError, match=r"s\.toml: include: expected a file name or an array of file names, got 3"):
        load_scenario(write(tmp_path, 'include = 3\n' + OSC))


# -- overrides: one reader for --set and sweeps --------------------------------------------
def test_one_override_reader_for_set_and_sweeps(tmp_path):
    assert parse_override("plat:process") == ("process", "plat", "")
    assert parse_override("plat.washout.k_t") == ("parameters", "plat", "washout.k_t")
    assert parse_override("simulation.stop") == ("simulation", "", "stop")
    with pytest.raises(ScenarioError, match=r"override 'plat:speed': not of the form 'unit\.param', 'unit:fmu', "
                                            r"'unit:process', 'simulation\.<key>' or 'log\.<key>'"):
        parse_override("plat:speed")
    sweep = write(tmp_path, f'scenario = "{SCEN / "sweeps" / "platform_pose.toml"}"\n'
                            '[grid]\n"plat:process" = [0, 1]\n"log.encoding" = ["json"]\n', "sw.toml")
    spec = load_sweep(sweep)
    assert [v.overrides for v in spec.variants] == [{"plat:process": 0, "log.encoding": "json"},
                                                   {"plat:process": 1, "log.encoding": "json"}]


# -- the shipped campus files against their flat forms -------------------------------------
def _system(sc):
    return {f.name: getattr(sc, f.name) for f in dataclasses.fields(sc) if f.name not in ("file", "text", "included", "place")}


@pytest.mark.parametrize("name", ["campus_drive", "campus_idle"])
def test_campus_files_are_their_flat_systems(name):
    new, flat = load_scenario(SCEN / f"{name}.toml"), load_scenario(FLAT / f"{name}.toml")
    assert _system(new) == _system(flat)
    assert [list(u.parameters.items()) for u in new.units] != [] and all(
        u.parameters == v.parameters for u, v in zip(new.units, flat.units))


def _records(path: Path):
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        channels = sorted((c.topic, c.message_encoding, summary.schemas[c.schema_id].data if c.schema_id else b"")
                          for c in summary.channels.values())
        return channels, [(c.topic, m.sequence, m.log_time, m.data) for _, c, m in reader.iter_messages()]


@pytest.mark.parametrize("name, stop, encoding", [("campus_drive", 4.0, "ros1"), ("campus_idle", 8.0, "json")])
def test_campus_files_log_the_bytes_of_their_flat_forms(tmp_path, name, stop, encoding):
    ov = {"simulation.stop": stop, "log.encoding": encoding}
    run_scenario(SCEN / f"{name}.toml", tmp_path / "new.mcap", overrides=ov)
    run_scenario(FLAT / f"{name}.toml", tmp_path / "flat.mcap", overrides=ov)
    new, flat = _records(tmp_path / "new.mcap"), _records(tmp_path / "flat.mcap")
    assert len(new[1]) > 300 and new == flat


def test_a_shipped_scenario_carries_its_included_files(tmp_path):
    """A sweep run on a worker without the client's folders gets the included files' texts."""
    from immersim.orchestrator.sweep.runs import RunTask
    from immersim.orchestrator.sweep.shipping import attach_inputs, shipped_scenario

    write(tmp_path, OSC, "common.toml")
    scn = write(tmp_path, 'include = ["common.toml"]\n[simulation]\nstop = 0.1\n')
    task = RunTask(str(scn), {"b.M": 250.0}, str(tmp_path / "x.mcap"), [])
    files, failed = attach_inputs([task], scn)
    assert not failed and list(task.included) == [str(tmp_path / "common.toml")]
    (tmp_path / "common.toml").unlink()
    sc = shipped_scenario(task, files)
    assert [(u.name, u.parameters) for u in sc.units] == [("a", {}), ("b", {"M": 250.0})]


def test_an_override_sets_one_variable_of_a_group_or_a_whole_group():
    sc = load_scenario(SCEN / "campus_drive.toml", {"coll.body[2].z": 3.0, "coll.body[5..6].z": [0.5, 0.7]})
    params = sc.unit("coll").parameters
    assert [params[f"body[{j}].z"] for j in (1, 2, 3, 5, 6, 7)] == [2.5, 3.0, 2.5, 0.5, 0.7, 1.0]
    with pytest.raises(ScenarioError, match=r"override 'coll\.body\[1\.\.2\]\.z': names 2 variables, the array has 3"):
        load_scenario(SCEN / "campus_drive.toml", {"coll.body[1..2].z": [1.0, 2.0, 3.0]})


@pytest.mark.parametrize("text, message", [
    ('[[connections]]\nfrom = "a.stroke[1..3]"\nto = "b.cue.{f_x,f_y}"\n', r"s\.toml: connections\[0\]: 'from' "
     r"'a\.stroke\[1\.\.3\]' names 3 signals, 'to' 'b\.cue\.\{f_x,f_y\}' names 2: they must name as many"),
    ('[[connections]]\nfrom = "a.pose.{x,y}"\nto = "b.cue.{f_x,f_yy}"\n', r"s\.toml: connections\[0\]\.to: connection "
     r"a\.pose\.y -> b\.cue\.f_yy: unit b \(platform\.fmu\) has no variable 'cue\.f_yy'"),
])
def test_the_command_line_reports_a_group_error_in_one_line(tmp_path, capsys, text, message):
    """``immersim run``: exit status 2, one line ``immersim: error: <file>: <key>: ...``, no traceback."""
    import re

    from immersim.orchestrator.cli import main

    rc = main(["run", str(write(tmp_path, OSC + text)), "-o", str(tmp_path / "x.mcap"), "-q"])
    lines = capsys.readouterr().err.splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("immersim: error: "), (rc, lines)
    assert re.search(message, lines[0]), lines[0]


def test_a_one_member_range_is_one_name():
    assert names("coll.body[4..4].z") == ["coll.body[4].z"]


def test_an_error_in_an_included_array_entry_names_that_file_and_its_index(tmp_path):
    """The included file's connections follow the file's own; an error in either names the file
    and the index it was written at."""
    write(tmp_path, '[[connections]]\nfrom = "a.pose.x"\nto = "b.cue.f_x"\ngain = "two"\n', "common.toml")
    with pytest.raises(ScenarioError, match=r"common\.toml: connections\[0\]\.gain: expected a number, got 'two'"):
        load_scenario(write(tmp_path, 'include = ["common.toml"]\n' + OSC +
                            '[[connections]]\nfrom = "a.pose.y"\nto = "b.cue.f_y"\n'))
    write(tmp_path, '[[connections]]\nfrom = "a.pose.x"\nto = "b.cue.f_x"\n', "common.toml")
    with pytest.raises(ScenarioError, match=r"s\.toml: connections\[0\]\.gain: expected a number, got 'three'"):
        load_scenario(write(tmp_path, 'include = ["common.toml"]\n' + OSC +
                            '[[connections]]\nfrom = "a.pose.y"\nto = "b.cue.f_y"\ngain = "three"\n'))
