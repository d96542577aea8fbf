"""A corpus of bad scenario files, sweep files, ``--set`` values and CLI arguments.

Every case goes through the ``immersim`` command in this process (``cli.main``) and must give
exit status 2, exactly one stderr line ``immersim: error: <file>: <key path>: <reason>`` that
names the culprit, no traceback and no log record at WARNING or above (in a real process those
would be more stderr lines); none is silently accepted. A good scenario is mutated one key at a
time (wrong type, out of range, missing, misspelled), so the corpus covers every key of the
schema (orchestrator/schema.py) and the FMU-dependent checks (orchestrator/values.py): FMI types
and ranges, causality, tunability, the parameters a unit refuses at initialization.
"""
from __future__ import annotations

import copy
import json
import logging
import math
import subprocess
import sys
from pathlib import Path

import pytest

from immersim.orchestrator.cli import main
from immersim.orchestrator.schema import ScenarioFile, SweepFile
from immersim.orchestrator.values import INT_RANGES, check_value, check_values

NAN, INF = math.nan, math.inf


# -- a minimal TOML writer (inline tables), so each case is a data edit of a good scenario --
def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"


def dump_toml(data: dict) -> str:
    return "".join(f"{json.dumps(k)} = {_toml_value(v)}\n" for k, v in data.items())


def scenario_data(fmus: dict) -> dict:
    """A good scenario: network and platform, a connection, an input, a fault, log, 3D view."""
    return {
        "simulation": {"start": 0.0, "stop": 0.066, "step": 0.033, "algorithm": "gauss-seidel"},
        "units": [{"name": "net", "fmu": str(fmus["network"]),
                   "parameters": {"players": 2, "render_nodes": 1, "entities": 0, "topology": "hybrid_p2p"}},
                  {"name": "plat", "fmu": str(fmus["platform"]), "parameters": {"cueing": "washout", "M": 240.0}}],
        "connections": [{"from": "net.avatar[1].f_x", "to": "plat.cue.f_x"}],
        "inputs": [{"target": "net.avatar[1].throttle", "kind": "step", "at": 0.033, "value": 0.5}],
        "faults": [{"target": "net.latency_scale", "at": 0.033, "value": 1.0}],
        "log": {"include": ["*"], "encoding": "json"},
        "foxglove": {"bodies": [{"name": "top", "position": ["plat.pose.x", "plat.pose.y", 0.0],
                                 "size": [0.76, 0.7, 0.04], "color": [0.2, 0.5, 0.9, 1.0]}]},
    }


def _set(path, value):
    """An edit: set the value at ``path`` (a tuple of keys and indices); DELETE removes it."""
    def edit(d):
        *head, last = path
        for k in head:
            d = d[k]
        if value is DELETE:
            del d[last]
        else:
            d[last] = copy.deepcopy(value)
    return edit


DELETE = object()


def _input(**table):
    return _set(("inputs", 0), {"target": "net.avatar[1].throttle", **table})


def _fault(**table):
    return _set(("faults", 0), {"target": "net.latency_scale", "at": 0.033, **table})


def _body(**table):
    return _set(("foxglove", "bodies", 0), {"name": "top", **table})


def _append(key, table):
    return lambda d: d[key].append(copy.deepcopy(table))


def _only(unit, **params):
    """A scenario of one unit with these parameters (for what the unit checks at initialization)."""
    def edit(d):
        u = next(x for x in d["units"] if x["name"] == unit)
        u["parameters"] = dict(u.get("parameters", {}), **params)
        d["units"] = [u]
        for key in ("connections", "inputs", "faults", "foxglove"):
            d.pop(key, None)
    return edit


def _coll(**params):
    def edit(d):
        d["units"] = [{"name": "coll", "fmu": d["units"][0]["fmu"].replace("network", "collision"),
                       "parameters": {"scene": "box:name=a,sx=1,sy=1,sz=1,dynamic=1;sphere:name=b,r=1,x=5",
                                      "pairs": "a vs b", **params}}]
        for key in ("connections", "inputs", "faults", "foxglove"):
            d.pop(key, None)
    return edit


S = "simulation"
# (id, edit, regex the one error line must match after "immersim: error: <file>: ")
SCENARIO_CASES = [
    # [simulation]: every key x wrong type / range
    *[(f"sim.{key}.{name}", _set((S, key), value), rf"simulation\.{key}: {msg}")
      for key in ("start", "stop", "step")
      for name, value, msg in [("string", "abc", "expected a number, got 'abc'"), ("bool", True, "expected a number, got True"),
                               ("nan", NAN, "must be finite, got nan"), ("inf", INF, "must be finite, got inf"),
                               ("huge", 1e300, r"1e\+300 s is outside"), ("array", [1], r"expected a number, got \[1\]"),
                               ("table", {"a": 1}, "expected a number, got"), ("numeric_string", "0.01", "expected a number, got '0.01'")]],
    ("sim.start.2e10", _set((S, "start"), 2e10), r"simulation\.start: 20000000000\.0 s is outside"),
    ("sim.stop.before_start", _set((S, "stop"), 0.0), r"simulation\.stop = 0 s must be after simulation\.start = 0 s"),
    ("sim.stop.negative", _set((S, "stop"), -1.0), r"simulation\.stop = -1 s must be after"),
    ("sim.step.zero", _set((S, "step"), 0.0), r"simulation\.step: must be > 0, got 0\.0"),
    ("sim.step.negative", _set((S, "step"), -0.033), r"simulation\.step: must be > 0, got -0\.033"),
    ("sim.step.below_1ns", _set((S, "step"), 1e-12), r"simulation\.step = 1e-12 s must be > 0 \(at least 1 ns\)"),
    *[(f"sim.algorithm.{i}", _set((S, "algorithm"), v), rf"simulation\.algorithm: {m} is not one of gauss-seidel, jacobi")
      for i, (v, m) in enumerate([("newton", "'newton'"), (1, "1"), (True, "True"), ("Jacobi", "'Jacobi'")])],
    *[(f"sim.extrapolation.{i}", _set((S, "extrapolation"), v), rf"simulation\.extrapolation: {m} is not one of zoh, linear")
      for i, (v, m) in enumerate([("cubic", "'cubic'"), (0, "0"), ("angle", "'angle'")])],
    *[(f"sim.tolerance.{i}", _set((S, "tolerance"), v), rf"simulation\.tolerance: {m}")
      for i, (v, m) in enumerate([("tight", "expected a number, got 'tight'"), (0.0, "must be > 0, got 0.0"),
                                  (-1e-6, "must be > 0, got -1e-06"), (NAN, "must be finite"), (True, "expected a number")])],
    *[(f"sim.lazy.{i}", _set((S, "lazy"), v), rf"simulation\.lazy: expected true or false, got {m}")
      for i, (v, m) in enumerate([(1, "1"), ("yes", "'yes'"), (0.0, "0.0")])],
    ("sim.unknown.stpo", _set((S, "stpo"), 1.0), r"simulation: unknown key 'stpo' \(did you mean 'stop'\?\)"),
    ("sim.unknown.dt", _set((S, "dt"), 1.0), r"simulation: unknown key 'dt' \(expected one of algorithm, extrapolation"),
    ("sim.not_a_table", _set((S,), 5), r"simulation: expected a table, got 5"),
    # top level
    ("top.unknown.unit", _set(("unit",), []), r"unknown key 'unit' \(did you mean 'units'\?\)"),
    ("top.unknown.simulaton", _set(("simulaton",), {}), r"unknown key 'simulaton' \(did you mean 'simulation'\?\)"),
    ("top.description.number", _set(("description",), 5), r"description: expected a string, got 5"),
    ("top.title.array", _set(("title",), ["a"]), r"title: expected a string"),
    # [[units]]
    ("units.missing", _set(("units",), DELETE), r"units: missing \(required\)"),
    ("units.empty", _set(("units",), []), r"units: must not be empty"),
    ("units.number", _set(("units",), 5), r"units: expected an array, got 5"),
    ("units.entry_string", _set(("units", 0), "net"), r"units\[0\]: expected a table, got 'net'"),
    *[(f"units.name.{i}", _set(("units", 1, "name"), v), rf"units\[1\]\.name: must be an identifier .*got {m}")
      for i, (v, m) in enumerate([("my unit", "'my unit'"), (1, "1"), ("", "''"), ("1plat", "'1plat'"), ("a.b", "'a.b'")])],
    ("units.name.missing", _set(("units", 1, "name"), DELETE), r"units\[1\]\.name: missing \(required\)"),
    ("units.name.duplicate", _set(("units", 1, "name"), "net"), r"units\[1\]\.name: duplicate unit instance name 'net'"),
    ("units.fmu.missing", _set(("units", 0, "fmu"), DELETE), r"units\[0\]\.fmu: missing \(required\)"),
    ("units.fmu.empty", _set(("units", 0, "fmu"), " "), r"units\[0\]\.fmu: must not be empty"),
    ("units.fmu.number", _set(("units", 0, "fmu"), 5), r"units\[0\]\.fmu: expected a string, got 5"),
    ("units.fmu.not_found", _set(("units", 0, "fmu"), "nowhere/missing.fmu"), r"unit net: FMU 'nowhere/missing\.fmu' not found"),
    ("units.parameters.number", _set(("units", 0, "parameters"), 5), r"units\[0\]\.parameters: expected a table, got 5"),
    ("units.parameters.array_value", _set(("units", 0, "parameters", "players"), [1, 2]),
     r"units\[0\]\.parameters\.players: expected a number, true/false or a string, got \[1, 2\]"),
    ("units.parameters.table_value", _set(("units", 1, "parameters", "M"), {"v": 1}),
     r"units\[1\]\.parameters\.M: expected a number, true/false or a string"),
    *[(f"units.process.{i}", _set(("units", 0, "process"), v), rf"units\[0\]\.process: must be an integer >= 0 .*got {m}")
      for i, (v, m) in enumerate([(-1, "-1"), ("x", "'x'"), (1.5, "1.5"), (True, "True")])],
    ("units.unknown.parameter", _set(("units", 0, "parameter"), {}), r"units\[0\]: unknown key 'parameter' \(did you mean 'parameters'\?\)"),
    ("units.unknown.fmu_path", _set(("units", 0, "path"), "x.fmu"), r"units\[0\]: unknown key 'path'"),
    # [[connections]]
    ("conn.not_array", _set(("connections",), 5), r"connections: expected an array, got 5"),
    ("conn.arrow", _set(("connections", 0), "net.avatar[1].f_x => plat.cue.f_x"), r"connections\[0\]: .* is not of the form 'unit\.out -> unit\.in'"),
    ("conn.arrow_no_dot", _set(("connections", 0), "net -> plat.cue.f_x"), r"connections\[0\]: 'net' is not of the form 'unit\.variable'"),
    ("conn.entry_number", _set(("connections", 0), 5), r"connections\[0\]: expected a table, got 5"),
    ("conn.from.missing", _set(("connections", 0, "from"), DELETE), r"connections\[0\]\.from: missing \(required\)"),
    ("conn.to.number", _set(("connections", 0, "to"), 5), r"connections\[0\]\.to: expected a 'unit\.variable' string, got 5"),
    ("conn.to.no_dot", _set(("connections", 0, "to"), "plat"), r"connections\[0\]\.to: 'plat' is not of the form"),
    ("conn.from.unknown_unit", _set(("connections", 0, "from"), "nett.avatar[1].f_x"),
     r"connections\[0\]: unknown unit 'nett' in 'nett\.avatar\[1\]\.f_x' \(did you mean 'net'\?\)"),
    *[(f"conn.{key}.{i}", _set(("connections", 0, key), v), rf"connections\[0\]\.{key}: {m}")
      for key in ("gain", "offset")
      for i, (v, m) in enumerate([("big", "expected a number, got 'big'"), (NAN, "must be finite"), (INF, "must be finite"),
                                  (True, "expected a number, got True"), ([1.0], "expected a number")])],
    ("conn.extrapolation.cubic", _set(("connections", 0, "extrapolation"), "cubic"),
     r"connections\[0\]\.extrapolation: 'cubic' is not one of zoh, linear, angle"),
    ("conn.delayed.int", _set(("connections", 0, "delayed"), 1), r"connections\[0\]\.delayed: expected true or false, got 1"),
    ("conn.unknown.gian", _set(("connections", 0, "gian"), 2.0), r"connections\[0\]: unknown key 'gian' \(did you mean 'gain'\?\)"),
    ("conn.twice", _append("connections", {"from": "net.avatar[1].f_y", "to": "plat.cue.f_x"}),
     r"connections\[1\]: input plat\.cue\.f_x is already connected \(connections\[0\]\)"),
    ("conn.unknown_variable", _set(("connections", 0, "from"), "net.avatar[1].fx"), r"unit net \(network\.fmu\) has no variable 'avatar\[1\]\.fx'"),
    ("conn.source_is_input", _set(("connections", 0, "from"), "net.latency_scale"), r"source net\.latency_scale has causality input, expected output"),
    ("conn.destination_is_output", _set(("connections", 0, "to"), "plat.pose.x"), r"destination plat\.pose\.x has causality output, expected input"),
    ("conn.type_mismatch", _set(("connections", 0, "from"), "net.at_rest"), r"type mismatch Boolean -> Real"),
    # [[inputs]]
    ("inputs.not_array", _set(("inputs",), 5), r"inputs: expected an array, got 5"),
    ("inputs.entry_number", _set(("inputs", 0), 5), r"inputs\[0\]: expected a table, got 5"),
    ("inputs.kind.square", _input(kind="square", value=1.0), r"inputs\[0\]: kind 'square' is not one of constant, step, ramp, sine, table"),
    ("inputs.kind.number", _input(kind=5, value=1.0), r"inputs\[0\]: kind '5' is not one of"),
    *[(f"inputs.{kind}.missing.{key}", _input(kind=kind, **{k: v for k, v in full.items() if k != key}),
       rf"inputs\[0\]\.{key}: missing \(required\)")
      for kind, full in [("constant", {"value": 1.0}), ("step", {"at": 1.0, "value": 1.0}), ("ramp", {"at": 1.0, "slope": 1.0}),
                         ("sine", {"amplitude": 1.0, "frequency": 1.0}), ("table", {"times": [0.0], "values": [1.0]})]
      for key in full],
    *[(f"inputs.{kind}.{key}.{name}", _input(kind=kind, **dict(full, **{key: v})), rf"inputs\[0\]\.{key}: {m}")
      for kind, full in [("constant", {"value": 1.0}), ("step", {"at": 1.0, "value": 1.0, "initial": 0.0}),
                         ("ramp", {"at": 1.0, "slope": 1.0, "initial": 0.0}),
                         ("sine", {"amplitude": 1.0, "frequency": 1.0, "offset": 0.0, "phase": 0.0})]
      for key in full
      for name, v, m in [("string", "abc", "expected a number, got 'abc'"), ("numeric_string", "0.01", "expected a number, got '0.01'"),
                         ("bool", True, "expected a number, got True"), ("nan", NAN, "must be finite, got nan"),
                         ("array", [1], r"expected a number, got \[1\]")]],
    ("inputs.step.at_huge", _input(kind="step", at=1e300, value=1.0), r"inputs\[0\]\.at: 1e\+300 s is outside"),
    ("inputs.sine.negative_frequency", _input(kind="sine", amplitude=1.0, frequency=-1.0), r"inputs\[0\]\.frequency: must be >= 0"),
    ("inputs.table.times_number", _input(kind="table", times=5, values=[1.0]), r"inputs\[0\]\.times: expected an array, got 5"),
    ("inputs.table.times_strings", _input(kind="table", times=["0", "1"], values=[1.0, 2.0]), r"inputs\[0\]\.times\[0\]: expected a number, got '0'"),
    ("inputs.table.values_strings", _input(kind="table", times=[0.0, 1.0], values=[1.0, "x"]), r"inputs\[0\]\.values\[1\]: expected a number, got 'x'"),
    ("inputs.table.values_nan", _input(kind="table", times=[0.0, 1.0], values=[1.0, NAN]), r"inputs\[0\]\.values\[1\]: must be finite"),
    ("inputs.table.times_nan", _input(kind="table", times=[0.0, NAN], values=[1.0, 2.0]), r"inputs\[0\]\.times\[1\]: must be finite"),
    ("inputs.table.empty", _input(kind="table", times=[], values=[]), r"inputs\[0\]\.times: must not be empty"),
    ("inputs.table.lengths", _input(kind="table", times=[0.0, 1.0], values=[1.0]), r"inputs\[0\]: 'times' has 2 entries, 'values' 1"),
    ("inputs.table.decreasing", _input(kind="table", times=[0.0, 2.0, 1.0], values=[1.0, 2.0, 3.0]),
     r"inputs\[0\]: 'times' must be increasing: times\[2\] = 1 < times\[1\] = 2"),
    ("inputs.ramp.at_array", _input(kind="ramp", at=[1], slope=1.0), r"inputs\[0\]\.at: expected a number, got \[1\]"),
    ("inputs.misspelled.vlaue", _input(kind="constant", vlaue=1.0), r"inputs\[0\]: unknown key 'vlaue' \(did you mean 'value'\?\)"),
    ("inputs.key_of_another_kind", _input(kind="constant", value=1.0, slope=2.0), r"inputs\[0\]: unknown key 'slope'"),
    ("inputs.target.missing", _set(("inputs", 0, "target"), DELETE), r"inputs\[0\]\.target: missing"),
    ("inputs.target.no_dot", _set(("inputs", 0, "target"), "throttle"), r"inputs\[0\]\.target: 'throttle' is not of the form"),
    ("inputs.target.unknown_unit", _set(("inputs", 0, "target"), "nte.avatar[1].throttle"), r"inputs\[0\]\.target: unknown unit 'nte'"),
    ("inputs.two_on_one_target", _append("inputs", {"target": "net.avatar[1].throttle", "value": 0.1}),
     r"inputs\[1\]\.target: net\.avatar\[1\]\.throttle is already driven by inputs\[0\]"),
    ("inputs.connected_target", _append("inputs", {"target": "plat.cue.f_x", "value": 0.1}),
     r"inputs\[1\]\.target: plat\.cue\.f_x is already driven by connections\[0\]"),
    ("inputs.unknown_variable", _set(("inputs", 0, "target"), "net.avatar[1].trottle"), r"unit net \(network\.fmu\) has no variable 'avatar\[1\]\.trottle'"),
    ("inputs.boolean_target", _set(("inputs", 0, "target"), "net.contact[1].active"), r"input net\.contact\[1\]\.active: scenario signals drive Real inputs, this one is Boolean"),
    ("inputs.output_target", _set(("inputs", 0, "target"), "net.bytes"), r"input net\.bytes: variable has causality output, expected input"),
    ("inputs.parameter_target", _set(("inputs", 0, "target"), "plat.M"), r"input plat\.M: variable has causality parameter, expected input"),
    # [[faults]]
    ("faults.not_array", _set(("faults",), 5), r"faults: expected an array, got 5"),
    ("faults.entry_string", _set(("faults", 0), "x"), r"faults\[0\]: expected a table, got 'x'"),
    ("faults.value.missing", _fault(), r"faults\[0\]\.value: missing \(required\)"),
    ("faults.target.missing", _set(("faults", 0, "target"), DELETE), r"faults\[0\]\.target: missing"),
    ("faults.at.nan", _fault(at=NAN, value=1.0), r"faults\[0\]\.at: must be finite, got nan"),
    ("faults.at.string", _fault(at="1", value=1.0), r"faults\[0\]\.at: expected a number, got '1'"),
    ("faults.at.huge", _fault(at=1e300, value=1.0), r"faults\[0\]\.at: 1e\+300 s is outside"),
    ("faults.value.array", _fault(value=[1.0]), r"faults\[0\]\.value: expected a number, true/false or a string, got \[1\.0\]"),
    ("faults.misspelled.valeu", _fault(valeu=1.0, value=1.0), r"faults\[0\]: unknown key 'valeu' \(did you mean 'value'\?\)"),
    ("faults.target.unknown_unit", _fault(target="plt.M", value=1.0), r"faults\[0\]\.target: unknown unit 'plt' .*did you mean 'plat'"),
    ("faults.real_input.string", _fault(value="abc"), r"faults\[0\]\.value: net\.latency_scale: Real takes a number, got 'abc'"),
    ("faults.real_input.bool", _fault(value=True), r"faults\[0\]\.value: net\.latency_scale: Real takes a number, got True"),
    ("faults.real_input.numeric_string", _fault(value="0.01"), r"faults\[0\]\.value: net\.latency_scale: Real takes a number, got '0\.01'"),
    *[(f"faults.boolean_input.{i}", _fault(target="net.contact[1].active", value=v),
       rf"faults\[0\]\.value: net\.contact\[1\]\.active: Boolean takes true or false, got {m}")
      for i, (v, m) in enumerate([(NAN, "nan"), ("maybe", "'maybe'"), (1, "1"), (0.5, "0.5"), ("true", "'true'")])],
    *[(f"faults.parameter.{p}", _fault(target=f"{u}.{p}", value=v),
       rf"faults\[0\]\.target: {u}\.{p} is a fixed parameter; a fault forces an input or a tunable parameter")
      for u, p, v in [("plat", "M", -5.0), ("plat", "integrator", "euler9"), ("net", "players", 3), ("net", "grid", False)]],
    ("faults.output", _fault(target="net.bytes", value=1), r"fault net\.bytes: only inputs can be forced, causality is output"),
    ("faults.unknown_variable", _fault(target="net.latency", value=1.0), r"unit net \(network\.fmu\) has no variable 'latency'"),
    # [log]
    ("log.not_table", _set(("log",), 5), r"log: expected a table, got 5"),
    ("log.include.string", _set(("log", "include"), "net.*"), r"log\.include: expected an array, got 'net\.\*'"),
    ("log.include.numbers", _set(("log", "include"), [1, 2]), r"log\.include\[0\]: expected a string, got 1"),
    ("log.exclude.number", _set(("log", "exclude"), 5), r"log\.exclude: expected an array, got 5"),
    ("log.parameters.string", _set(("log", "parameters"), "yes"), r"log\.parameters: expected true or false, got 'yes'"),
    ("log.encoding.cbor", _set(("log", "encoding"), "cbor"), r"log\.encoding: 'cbor' is not one of json, ros1"),
    ("log.process.int", _set(("log", "process"), 1), r"log\.process: expected true or false, got 1"),
    ("log.unknown.colour", _set(("log", "colour"), 1), r"log: unknown key 'colour'"),
    ("log.unknown.exclud", _set(("log", "exclud"), []), r"log: unknown key 'exclud' \(did you mean 'exclude'\?\)"),
    ("log.selects_nothing", lambda d: (d["log"].update(include=["nothing.*"]), d.pop("foxglove")),
     r"selects no output of any unit"),
    # [[foxglove.bodies]]
    ("fox.not_table", _set(("foxglove",), 5), r"foxglove: expected a table, got 5"),
    ("fox.bodies.number", _set(("foxglove", "bodies"), 5), r"foxglove\.bodies: expected an array, got 5"),
    ("fox.unknown.body", _set(("foxglove", "body"), []), r"foxglove: unknown key 'body' \(did you mean 'bodies'\?\)"),
    ("fox.name.missing", _set(("foxglove", "bodies", 0, "name"), DELETE), r"foxglove\.bodies\[0\]\.name: missing"),
    ("fox.name.number", _body(name=5), r"foxglove\.bodies\[0\]\.name: expected a string, got 5"),
    ("fox.parent.number", _body(parent=1), r"foxglove\.bodies\[0\]\.parent: expected a string, got 1"),
    *[(f"fox.{key}.{name}", _body(**{key: v}), rf"foxglove\.bodies\[0\]\.{key}{m}")
      for key in ("position", "euler")
      for name, v, m in [("two", [0.0, 0.0], r": must have at least 3 entries, got \[0\.0, 0\.0\]"),
                         ("four", [0.0] * 4, r": must have at most 3 entries"),
                         ("nan", [NAN, 0.0, 0.0], r"\[0\]: must be finite, got nan"), ("inf", [0.0, INF, 0.0], r"\[1\]: must be finite"),
                         ("bool", [0.0, 0.0, True], r"\[2\]: expected a number or a 'unit\.variable' reference, got True"),
                         ("no_dot", ["x", 0.0, 0.0], r"\[0\]: 'x' is not of the form 'unit\.variable'"),
                         ("unknown_unit", ["plt.pose.x", 0.0, 0.0], r"\[0\]: unknown unit 'plt'"),
                         ("number", 5, r": expected an array, got 5")]],
    *[(f"fox.{key}.{name}", _body(**{key: v}), rf"foxglove\.bodies\[0\]\.{key}{m}")
      for key in ("offset", "size")
      for name, v, m in [("nan", [NAN, 0.0, 0.0], r"\[0\]: must be finite, got nan"), ("inf", [0.0, 0.0, -INF], r"\[2\]: must be finite"),
                         ("ref", ["plat.pose.x", 0.0, 0.0], r"\[0\]: expected a number, got 'plat\.pose\.x'"),
                         ("two", [1.0, 1.0], r": must have at least 3 entries")]],
    ("fox.size.negative", _body(size=[1.0, -1.0, 1.0]), r"foxglove\.bodies\[0\]\.size\[1\]: must be >= 0, got -1\.0"),
    ("fox.color.above_one", _body(color=[0.2, 1.5, 0.2, 1.0]), r"foxglove\.bodies\[0\]\.color\[1\]: must be in 0\.\.1, got 1\.5"),
    ("fox.color.three", _body(color=[0.2, 0.5, 0.2]), r"foxglove\.bodies\[0\]\.color: must have at least 4 entries"),
    ("fox.color.nan", _body(color=[0.2, 0.5, NAN, 1.0]), r"foxglove\.bodies\[0\]\.color\[2\]: must be finite"),
    ("fox.shape.cone", _body(shape="cone"), r"foxglove\.bodies\[0\]\.shape: 'cone' is not one of cube, sphere, cylinder"),
    ("fox.order.yxz", _body(order="yxz"), r"foxglove\.bodies\[0\]\.order: 'yxz' is not one of xyz, zyx"),
    ("fox.unknown.colour", _body(colour=[1, 1, 1, 1]), r"foxglove\.bodies\[0\]: unknown key 'colour' \(did you mean 'color'\?\)"),
    ("fox.unknown_variable", _body(position=["plat.pose.q", 0.0, 0.0]), r"foxglove body 'top': unit plat \(platform\.fmu\) has no variable 'pose\.q'"),
    # parameters against the FMU's types and ranges
    *[(f"param.net.players.{name}", _set(("units", 0, "parameters", "players"), v), rf"units\[0\]\.parameters\.players: {m}")
      for name, v, m in [("int32_overflow", 3_000_000_000, r"net\.players: 3000000000 is outside the range -2147483648\.\.2147483647 of this Integer"),
                         ("int32_underflow", -2 ** 31 - 1, r"net\.players: -2147483649 is outside the range"),
                         ("huge", 2 ** 70, r"net\.players: 1180591620717411303424 is outside the range")]],
    *[(f"param.type.{name}", _set(("units", i, "parameters", p), v), rf"parameter {u}\.{p}: type mismatch, the FMU declares {t} but the scenario gives {m}")
      for name, i, u, p, v, t, m in [
          ("int_as_float", 0, "net", "players", 2.0, "Integer", "float 2.0"), ("int_as_string", 0, "net", "players", "2", "Integer", "str '2'"),
          ("int_as_bool", 0, "net", "players", True, "Integer", "bool True"), ("real_as_string", 1, "plat", "M", "240", "Real", "str '240'"),
          ("real_as_bool", 1, "plat", "M", True, "Real", "bool True"), ("string_as_int", 1, "plat", "integrator", 4, "String", "int 4"),
          ("string_as_bool", 1, "plat", "integrator", False, "String", "bool False"), ("bool_as_int", 0, "net", "grid", 1, "Boolean", "int 1"),
          ("bool_as_string", 0, "net", "grid", "true", "Boolean", "str 'true'")]],
    *[(f"param.real.{name}", _set(("units", 1, "parameters", "M"), v), rf"units\[1\]\.parameters\.M: plat\.M: Real value must be finite, got {m}")
      for name, v, m in [("nan", NAN, "nan"), ("inf", INF, "inf"), ("minus_inf", -INF, "-inf")]],
    ("param.unknown", _set(("units", 1, "parameters", "mass"), 1.0), r"unit plat \(platform\.fmu\) has no variable 'mass'"),
    ("param.output", _set(("units", 1, "parameters", "track_err"), 1.0), r"parameter plat\.track_err: variable has causality output"),
    # parameters a unit refuses when initialized: one line naming parameter, value and the unit's reason
    *[(f"init.plat.{p}.{v}", _only("plat", **{p: v}), rf"units\[0\]\.parameters\.{p} = {m}: unit plat refused it at initialization: .*{r}")
      for p, v, m, r in [("M", -240.0, r"-240\.0", "must be > 0"), ("integrator", "euler9", "'euler9'", "'euler9' is not one of"),
                         ("cueing", "roll", "'roll'", "roll"), ("control", "lqr", "'lqr'", "lqr"), ("substeps", 0, "0", "substeps")]],
    *[(f"init.net.{p}.{v}", _only("net", **{p: v}), rf"units\[0\]\.parameters\.{p} = {m}: unit net refused it at initialization: .*{r}")
      for p, v, m, r in [("players", 0, "0", r"parameter players = 0 must be in 1\.\.4"), ("players", 5, "5", "must be in 1..4"),
                         ("loss", 2.0, r"2\.0", r"parameter loss = 2\.0 must be in \[0, 1\)"), ("loss", -0.1, r"-0\.1", "must be in"),
                         ("render_nodes", 0, "0", "must be >= 1"), ("entities", -1, "-1", "must be >= 0"),
                         ("topology", "ring", "'ring'", "must be one of"), ("prediction_order", 3, "3", "must be 0, 1 or 2"),
                         ("latency_ms", -1.0, r"-1\.0", "must be positive"), ("scene_size", 1e300, r"1e\+300", r"must be at most 1e\+06 m"),
                         ("scene_size", 0.0, r"0\.0", "must be positive"), ("ownership", "random", "'random'", "must be one of")]],
    *[(f"init.coll.{name}", _coll(**{p: v}), rf"units\[0\]\.parameters\.{p} = .*: unit coll refused it at initialization: .*{r}")
      for name, p, v, r in [("scene_kind", "scene", "blob:x=1", "unknown kind 'blob'"),
                            ("mesh_missing", "scene", "mesh:file=nowhere.stl", r"nowhere\.stl' does not exist"),
                            ("pair_unknown_body", "pairs", "a vs rocket", "rocket"), ("pair_syntax", "pairs", "a_with_b", "expected 'A vs B'"),
                            ("nine_pairs", "pairs", ";".join(["a vs b"] * 9), "at most"), ("backend", "backend", "gjk", "must be one of")]],
]


def _run(argv, capsys, caplog):
    """``immersim argv`` in this process: (exit status, stderr lines)."""
    caplog.set_level(logging.DEBUG, logger="immersim")
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    errors = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert not errors, f"log records (WARNING or above) besides the error line: {[r.getMessage() for r in errors]}"
    return rc, err.splitlines()


def _assert_one_line(rc, lines, pattern, where=""):
    assert "Traceback" not in "\n".join(lines)
    assert rc == 2, (rc, lines)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"immersim: error: {where}"), lines[0]
    import re
    assert re.search(pattern, lines[0]), (pattern, lines[0])


@pytest.fixture(scope="module")
def fmus(built_fmus):
    return built_fmus


@pytest.fixture
def good(tmp_path, fmus):
    return scenario_data(fmus)


def test_the_good_scenario_runs(tmp_path, good, capsys, caplog):
    """The corpus' base scenario is accepted: every case below differs from it by one edit."""
    path = tmp_path / "good.toml"
    path.write_text(dump_toml(good))
    rc, lines = _run(["run", path, "-o", tmp_path / "good.mcap", "-q"], capsys, caplog)
    assert rc == 0 and lines == []


@pytest.mark.parametrize("edit,pattern", [c[1:] for c in SCENARIO_CASES], ids=[c[0] for c in SCENARIO_CASES])
def test_bad_scenario(tmp_path, good, edit, pattern, capsys, caplog):
    edit(good)
    path = tmp_path / "bad.toml"
    path.write_text(dump_toml(good))
    rc, lines = _run(["run", path, "-o", tmp_path / "bad.mcap", "-q"], capsys, caplog)
    _assert_one_line(rc, lines, pattern, where=f"{path}: " if "FMU" not in pattern and "unit net: " not in pattern else "")
    assert not (tmp_path / "bad.mcap").exists()   # refused at load: nothing ran, no log


# -- --set values on the command line ------------------------------------------------------
SET_CASES = [
    ("no_equals", ["plat.M"], r"--set 'plat\.M': expected UNIT\.PARAM=VALUE"),
    ("no_unit", ["nounit.M=1.0"], r"override 'nounit\.M': no unit 'nounit'"),
    ("unit_typo", ["plt.M=1.0"], r"override 'plt\.M': no unit 'plt' .*\(did you mean 'plat'\?\)"),
    ("empty_param", ["plat.=1"], r"override 'plat\.': not of the form"),
    ("bad_field", ["plat:color=1"], r"override 'plat:color': not of the form"),
    ("stop_huge", ["simulation.stop=1e300"], r"simulation\.stop \(set by override 'simulation\.stop'\): 1e\+300 s is outside"),
    ("start_huge", ["simulation.start=2e10"], r"simulation\.start \(set by override 'simulation\.start'\): 20000000000\.0 s is outside"),
    ("start_nan", ["simulation.start=nan"], r"simulation\.start \(set by override 'simulation\.start'\): must be finite"),
    ("step_zero", ["simulation.step=0"], r"simulation\.step \(set by override 'simulation\.step'\): must be > 0"),
    ("step_word", ["simulation.step=fast"], r"simulation\.step \(set by override 'simulation\.step'\): expected a number, got 'fast'"),
    ("algorithm", ["simulation.algorithm=euler"], r"simulation\.algorithm \(set by override 'simulation\.algorithm'\): 'euler' is not one of"),
    ("tolerance_word", ["simulation.tolerance=tight"], r"simulation\.tolerance \(set by override .*\): expected a number, got 'tight'"),
    ("lazy_word", ["simulation.lazy=maybe"], r"simulation\.lazy \(set by override .*\): expected true or false, got 'maybe'"),
    ("sim_unknown", ["simulation.stpo=1"], r"simulation: unknown key 'stpo' \(did you mean 'stop'\?\)"),
    ("log_encoding", ["log.encoding=cbor"], r"log\.encoding \(set by override 'log\.encoding'\): 'cbor' is not one of json, ros1"),
    ("log_include_string", ["log.include=net.*"], r"log\.include \(set by override 'log\.include'\): expected an array"),
    ("log_unknown", ["log.colour=1"], r"log: unknown key 'colour'"),
    ("process_negative", ["net:process=-1"], r"units\[0\]\.process \(set by override 'net:process'\): must be an integer >= 0"),
    ("process_word", ["net:process=two"], r"units\[0\]\.process \(set by override 'net:process'\): must be an integer >= 0"),
    ("process_no_unit", ["nx:process=1"], r"override 'nx:process': no unit 'nx'"),
    ("fmu_missing", ["net:fmu=nowhere/x.fmu"], r"unit net: FMU 'nowhere/x\.fmu' not found"),
    ("param_type", ["plat.M=heavy"], r"parameter plat\.M: type mismatch, the FMU declares Real but the scenario gives str 'heavy'"),
    ("param_numeric_string", ['plat.M="0.01"'], r"parameter plat\.M: type mismatch, .* str '0\.01'"),
    ("param_bool_for_real", ["plat.M=true"], r"parameter plat\.M: type mismatch, .* bool True"),
    ("param_int_range", ["net.players=3000000000"], r"units\[0\]\.parameters\.players: net\.players: 3000000000 is outside the range"),
    ("param_array", ["plat.M=[1, 2]"], r"units\[1\]\.parameters\.M \(set by override 'plat\.M'\): expected a number, true/false or a string"),
    ("param_nan", ["plat.M=nan"], r"units\[1\]\.parameters\.M: plat\.M: Real value must be finite, got nan"),
    ("param_refused", ["plat.M=-240.0"], r"units\[1\]\.parameters\.M = -240\.0: unit plat refused it at initialization: .*must be > 0"),
    ("param_unknown", ["plat.mass=1.0"], r"unit plat \(platform\.fmu\) has no variable 'mass'"),
    ("scene_size", ["net.scene_size=1e300"], r"units\[0\]\.parameters\.scene_size = 1e\+300: unit net refused it at initialization"),
    ("refused_in_a_worker", ["net:process=1", "net.players=0"],
     r"units\[0\]\.parameters\.players = 0: unit net refused it at initialization: parameter players = 0 must be in 1\.\.4"),
    ("empty_key", ["=5"], r"override '': not of the form"),
    ("table_key", ["simulation=1"], r"override 'simulation': not of the form"),
]


@pytest.mark.parametrize("sets,pattern", [c[1:] for c in SET_CASES], ids=[c[0] for c in SET_CASES])
def test_bad_set_value(tmp_path, good, sets, pattern, capsys, caplog):
    path = tmp_path / "s.toml"
    path.write_text(dump_toml(good))
    argv = ["run", path, "-o", tmp_path / "s.mcap", "-q"] + [x for s in sets for x in ("--set", s)]
    rc, lines = _run(argv, capsys, caplog)
    _assert_one_line(rc, lines, pattern)
    assert not (tmp_path / "s.mcap").exists()


# -- the scenario file itself --------------------------------------------------------------
FILE_CASES = [
    ("folder", lambda p: p.mkdir(), r"bad\.toml: is a folder, not a scenario file"),
    ("missing", lambda p: None, r"scenario file .*bad\.toml does not exist"),
    ("not_utf8", lambda p: p.write_bytes(b'title = "\xff\xfe"\n'), r"bad\.toml: not a UTF-8 text file \(byte 0xff at offset 9\)"),
    ("binary", lambda p: p.write_bytes(bytes(range(256))), r"bad\.toml: not a UTF-8 text file"),
    ("invalid_toml", lambda p: p.write_text("[simulation\nstop = 1\n"), r"bad\.toml: invalid TOML"),
    ("empty", lambda p: p.write_text(""), r"bad\.toml: units: missing \(required\)"),
    ("array_of_units_as_table", lambda p: p.write_text('[units]\nname = "a"\n'), r"bad\.toml: units: expected an array"),
]


@pytest.mark.parametrize("make,pattern", [c[1:] for c in FILE_CASES], ids=[c[0] for c in FILE_CASES])
def test_bad_scenario_file(tmp_path, make, pattern, capsys, caplog):
    path = tmp_path / "bad.toml"
    make(path)
    rc, lines = _run(["run", path, "-o", tmp_path / "b.mcap", "-q"], capsys, caplog)
    _assert_one_line(rc, lines, pattern)


# -- sweep files and sweep arguments -------------------------------------------------------
def sweep_data() -> dict:
    return {"scenario": "base.toml", "grid": {"plat.M": [200.0, 240.0]},
            "variants": [{"name": "light", "plat.M": 180.0}],
            "metrics": {"err": {"signal": "plat.track_err", "reduce": "max", "after": 0.0}, "wall": "wall_time"},
            "plot": {"x": "plat.M", "y": ["err"]}}


SWEEP_CASES = [
    ("scenario.missing", _set(("scenario",), DELETE), r"scenario: missing \(required\)"),
    ("scenario.number", _set(("scenario",), 1), r"scenario: expected a string, got 1"),
    ("scenario.not_found", _set(("scenario",), "nope.toml"), r"scenario: 'nope\.toml' does not exist"),
    ("scenario.folder", _set(("scenario",), "."), r"scenario: '\.' is not a file"),
    ("scenario.bad_scenario", _set(("scenario",), "broken.toml"), r"variant 000_200 .*broken\.toml: simulation\.stop: must be finite"),
    ("unknown.runs", _set(("runs",), 3), r"unknown key 'runs'"),
    ("unknown.grids", _set(("grids",), {}), r"unknown key 'grids' \(did you mean 'grid'\?\)"),
    ("grid.number", _set(("grid",), 5), r"grid: expected a table, got 5"),
    ("grid.value_not_list", _set(("grid", "plat.M"), 2.0), r"grid\['plat\.M'\]: expected an array, got 2\.0"),
    ("grid.empty_list", _set(("grid", "plat.M"), []), r"grid\['plat\.M'\]: must not be empty"),
    ("grid.list_of_lists", _set(("grid", "plat.M"), [[1.0]]), r"grid\['plat\.M'\]\[0\]: expected a number, true/false or a string"),
    ("grid.sim_key", _set(("grid", "simulation.dt"), [0.1]), r"grid key 'simulation\.dt': unknown simulation setting"),
    ("grid.not_override", _set(("grid", "stiffness"), [1]), r"grid key 'stiffness': 'stiffness' is not an override key"),
    ("grid.no_unit", _set(("grid", "mx.k"), [1.0]), r"override 'mx\.k': no unit 'mx'"),
    ("grid.bad_value", _set(("grid", "simulation.step"), [0.033, -1.0]), r"simulation\.step \(set by override 'simulation\.step'\): must be > 0"),
    ("grid.type_for_fmu", _set(("grid", "plat.M"), [240.0, "heavy"]),
     r"variant 001_heavy \{'plat\.M': 'heavy'\}: .*parameter plat\.M: type mismatch, the FMU declares Real"),
    ("grid.int_range", _set(("grid", "net.players"), [2, 2 ** 40]), r"variant 00\d_200_1099511627776 .*net\.players: 1099511627776 is outside"),
    ("variants.number", _set(("variants",), 5), r"variants: expected an array, got 5"),
    ("variants.entry", _set(("variants", 0), "x"), r"variants\[0\]: expected a table, got 'x'"),
    ("variants.name_number", _set(("variants", 0, "name"), 5), r"variants\[0\]\.name: expected a string, got 5"),
    ("variants.name_blank", _set(("variants", 0, "name"), " "), r"variants\[0\]\.name: must not be empty"),
    ("variants.duplicate", _append("variants", {"name": "light"}), r"variants\[1\]: duplicate variant name 'light'"),
    ("variants.list_value", _set(("variants", 0, "plat.M"), [1, 2]), r"variants\[0\]: key 'plat\.M': expected a single value"),
    ("variants.bad_key", _set(("variants", 0, "stiffness"), 1), r"'stiffness' is not an override key"),
    ("metrics.number", _set(("metrics",), 5), r"metrics: expected a table, got 5"),
    ("metrics.after_nan", _set(("metrics", "err", "after"), NAN), r"metrics\.err\.after: must be finite, got nan"),
    ("metrics.after_string", _set(("metrics", "err", "after"), "1"), r"metrics\.err\.after: expected a number, got '1'"),
    ("metrics.after_inf", _set(("metrics", "err", "after"), INF), r"metrics\.err\.after: must be finite, got inf"),
    ("metrics.reduce", _set(("metrics", "err", "reduce"), "median"), r"metrics\.err\.reduce: 'median' is not one of max, min"),
    ("metrics.signal_no_dot", _set(("metrics", "err", "signal"), "x"), r"metrics\.err\.signal: 'x' is not of the form"),
    ("metrics.signal_missing", _set(("metrics", "err", "signal"), DELETE), r"metrics\.err\.signal: missing"),
    ("metrics.unknown_key", _set(("metrics", "err", "window"), 1), r"metrics\.err: unknown key 'window'"),
    ("metrics.misspelled", _set(("metrics", "err", "reduec"), "max"), r"metrics\.err: unknown key 'reduec' \(did you mean 'reduce'\?\)"),
    ("metrics.builtin_unknown", _set(("metrics", "wall"), "cpu"), r"metrics\.wall: unknown built-in metric 'cpu'"),
    ("metrics.entry_number", _set(("metrics", "wall"), 5), r"metrics\.wall: expected a table, got 5"),
    ("metrics.name_taken", _set(("metrics", "status"), "steps"), r"metrics\.status: the name 'status' is already a summary column"),
    ("plot.number", _set(("plot",), 5), r"plot: expected a table, got 5"),
    ("plot.x_missing", _set(("plot", "x"), DELETE), r"plot\.x: missing \(required\)"),
    ("plot.y_unknown", _set(("plot", "y"), "nope"), r"plot\.y: 'nope' is not an override key or metric"),
    ("plot.logx_string", _set(("plot", "logx"), "yes"), r"plot\.logx: expected true or false, got 'yes'"),
    ("plot.unknown_key", _set(("plot", "colour"), "red"), r"plot: unknown key 'colour'"),
    ("plot.array_entry", _set(("plot",), [{"x": "plat.M"}]), r"plot\[0\]\.y: missing \(required\)"),
]


@pytest.fixture
def sweep_dir(tmp_path, good):
    good["simulation"]["stop"] = 0.033
    (tmp_path / "base.toml").write_text(dump_toml(good))
    broken = copy.deepcopy(good)
    broken["simulation"]["stop"] = INF
    (tmp_path / "broken.toml").write_text(dump_toml(broken))
    return tmp_path


@pytest.mark.parametrize("edit,pattern", [c[1:] for c in SWEEP_CASES], ids=[c[0] for c in SWEEP_CASES])
def test_bad_sweep(sweep_dir, edit, pattern, capsys, caplog):
    data = sweep_data()
    edit(data)
    path = sweep_dir / "sweep.toml"
    path.write_text(dump_toml(data))
    rc, lines = _run(["sweep", path, "-o", sweep_dir / "out", "-q", "-j", "1"], capsys, caplog)
    _assert_one_line(rc, lines, pattern, where=f"{path}: ")
    assert not (sweep_dir / "out").exists()


SWEEP_FILE_CASES = [
    ("folder", lambda p: p.mkdir(), r"sweep\.toml: is a folder, not a sweep file"),
    ("missing", lambda p: None, r"sweep file .*sweep\.toml does not exist"),
    ("binary", lambda p: p.write_bytes(bytes(range(256))), r"sweep\.toml: not a UTF-8 text file"),
    ("invalid_toml", lambda p: p.write_text("[grid\n"), r"sweep\.toml: invalid TOML"),
    ("nothing_to_run", lambda p: p.write_text('scenario = "base.toml"\n'), r"nothing to run: give a \[grid\] or \[\[variants\]\]"),
]


@pytest.mark.parametrize("make,pattern", [c[1:] for c in SWEEP_FILE_CASES], ids=[c[0] for c in SWEEP_FILE_CASES])
def test_bad_sweep_file(sweep_dir, make, pattern, capsys, caplog):
    path = sweep_dir / "sweep.toml"
    make(path)
    rc, lines = _run(["sweep", path, "-o", sweep_dir / "out", "-q"], capsys, caplog)
    _assert_one_line(rc, lines, pattern)


@pytest.mark.parametrize("workers", ["0", "-2"])
def test_bad_worker_count(sweep_dir, workers, capsys, caplog):
    path = sweep_dir / "sweep.toml"
    path.write_text(dump_toml(sweep_data()))
    rc, lines = _run(["sweep", path, "-o", sweep_dir / "out", "-q", "-j", workers], capsys, caplog)
    _assert_one_line(rc, lines, rf"--workers must be >= 1, got {workers}")


def test_unreadable_scenario_file(tmp_path, good, monkeypatch, capsys, caplog):
    """(Permissions do not stop root, so the read itself is made to fail.)"""
    path = tmp_path / "locked.toml"
    path.write_text(dump_toml(good))

    def refuse(self):
        raise PermissionError(13, "Permission denied", str(self))
    monkeypatch.setattr(Path, "read_bytes", refuse)
    rc, lines = _run(["run", path, "-q"], capsys, caplog)
    _assert_one_line(rc, lines, r"locked\.toml: cannot read the scenario file: Permission denied")


@pytest.mark.parametrize("address", ["not a url", "tcp://host", "http://host:8786", "host:port", "tcp://:8786"])
def test_bad_scheduler_address(sweep_dir, address, capsys, caplog):
    path = sweep_dir / "sweep.toml"
    path.write_text(dump_toml(sweep_data()))
    rc, lines = _run(["sweep", path, "-o", sweep_dir / "out", "-q", "--scheduler", address], capsys, caplog)
    _assert_one_line(rc, lines, rf"--scheduler '{address}' is not a Dask scheduler address")


def test_corpus_size():
    """The issue asks for at least 250 bad scenario, sweep and --set cases here."""
    n = (len(SCENARIO_CASES) + len(SET_CASES) + len(FILE_CASES) + len(SWEEP_CASES) + len(SWEEP_FILE_CASES) + 5 + 2 + 1
         + len(FEEDTHROUGH_CASES))
    assert n >= 250, n
    assert len({c[0] for c in SCENARIO_CASES}) == len(SCENARIO_CASES)


# -- FMI 3.0 and FMI 2.0 integer widths: the Reference FMUs' Feedthrough ---------------------
REFERENCE = Path(__file__).resolve().parents[1] / "conformance" / "reference-fmus"


def feedthrough(version: str, parameters: dict, faults: list) -> dict:
    return {"simulation": {"stop": 0.1, "step": 0.01},
            "units": [{"name": "ft", "fmu": str(REFERENCE / version / "Feedthrough.fmu"), "parameters": parameters}],
            "faults": [{"target": f"ft.{var}", "at": 0.05, "value": value} for var, value in faults]}


_RANGE = r"units\[0\]\.parameters\.{v}: ft\.{v}: {x} is outside the range {lo}\.\.{hi} of this {t} variable"
FEEDTHROUGH_CASES = [
    *[(f"fmi3.start.{t}.{x}", "fmi3", {f"{t}_input": x}, [],
       _RANGE.format(v=f"{t}_input", x=x, lo=INT_RANGES[t][0], hi=INT_RANGES[t][1], t=t))
      for t, x in [("Int8", 300), ("Int8", -129), ("UInt8", -1), ("UInt8", 256), ("Int16", 40000), ("UInt16", 65536),
                   ("Int32", 2 ** 31), ("UInt32", -1), ("UInt32", 2 ** 32), ("UInt64", -1)]],
    ("fmi3.start.Int8.float", "fmi3", {"Int8_input": 1.5}, [], r"parameter ft\.Int8_input: type mismatch, the FMU declares Int8"),
    ("fmi3.fault.Int8", "fmi3", {}, [("Int8_input", 300)], r"faults\[0\]\.value: ft\.Int8_input: 300 is outside the range -128\.\.127"),
    ("fmi3.fault.UInt16", "fmi3", {}, [("UInt16_input", -5)], r"faults\[0\]\.value: ft\.UInt16_input: -5 is outside the range 0\.\.65535"),
    ("fmi3.fault.Int64_float", "fmi3", {}, [("Int64_input", 2.0)], r"faults\[0\]\.value: ft\.Int64_input: Int64 takes an integer, got 2\.0"),
    ("fmi3.fault.Boolean_nan", "fmi3", {}, [("Boolean_input", NAN)], r"faults\[0\]\.value: ft\.Boolean_input: Boolean takes true or false, got nan"),
    ("fmi3.fault.String_number", "fmi3", {}, [("String_input", 5)], r"faults\[0\]\.value: ft\.String_input: String takes a string, got 5"),
    ("fmi3.fault.Float32_string", "fmi3", {}, [("Float32_continuous_input", "x")], r"ft\.Float32_continuous_input: Float32 takes a number, got 'x'"),
    ("fmi3.start.Float32_huge", "fmi3", {"Float32_continuous_input": 1e39}, [],
     r"ft\.Float32_continuous_input: 1e\+39 is outside the Float32 range \+-3\.4028235e\+38"),
    ("fmi3.fault.fixed_parameter", "fmi3", {}, [("Float64_fixed_parameter", 2.0)],
     r"faults\[0\]\.target: ft\.Float64_fixed_parameter is a fixed parameter"),
    ("fmi3.fault.tunable_nan", "fmi3", {}, [("Float64_tunable_parameter", NAN)],
     r"faults\[0\]\.value: ft\.Float64_tunable_parameter: Float64 value must be finite, got nan"),
    ("fmi2.start.Int32", "fmi2", {"Int32_input": 3_000_000_000}, [],
     r"units\[0\]\.parameters\.Int32_input: ft\.Int32_input: 3000000000 is outside the range -2147483648\.\.2147483647 of this Integer"),
    ("fmi2.start.Enumeration", "fmi2", {"Enumeration_input": -2 ** 31 - 1}, [], r"ft\.Enumeration_input: -2147483649 is outside the range"),
    ("fmi2.fault.Int32", "fmi2", {}, [("Int32_input", -3_000_000_000)], r"faults\[0\]\.value: ft\.Int32_input: -3000000000 is outside"),
    ("fmi2.fault.Boolean", "fmi2", {}, [("Boolean_input", "maybe")], r"ft\.Boolean_input: Boolean takes true or false, got 'maybe'"),
    ("fmi2.fault.fixed_parameter", "fmi2", {}, [("Float64_fixed_parameter", 1.0)], r"ft\.Float64_fixed_parameter is a fixed parameter"),
]


@pytest.mark.parametrize("version,parameters,faults,pattern", [c[1:] for c in FEEDTHROUGH_CASES],
                         ids=[c[0] for c in FEEDTHROUGH_CASES])
def test_bad_integer_width_or_type(tmp_path, version, parameters, faults, pattern, capsys, caplog):
    path = tmp_path / "ft.toml"
    path.write_text(dump_toml(feedthrough(version, parameters, faults)))
    rc, lines = _run(["run", path, "-o", tmp_path / "ft.mcap", "-q"], capsys, caplog)
    _assert_one_line(rc, lines, pattern, where=f"{path}: ")


def test_integers_at_the_bounds_of_their_type_pass_through_unchanged(tmp_path, capsys, caplog):
    """Feedthrough copies each input to its output: the extreme values of each FMI 3.0 integer
    type (the start values, then faults from 0.05 s) reach the log exactly, and a fault into a
    tunable parameter is accepted."""
    from immersim.orchestrator.mcapio import read_series

    start = {"Int8_input": 127, "UInt8_input": 255, "Int16_input": -32768, "UInt32_input": 2 ** 32 - 1,
             "Int64_input": 2 ** 63 - 1}
    faults = [("Int8_input", -128), ("UInt8_input", 0), ("Int16_input", 32767), ("Int64_input", -2 ** 63),
              ("Float64_tunable_parameter", 7.5)]
    path = tmp_path / "ft.toml"
    path.write_text(dump_toml(feedthrough("fmi3", start, faults)))
    rc, lines = _run(["run", path, "-o", tmp_path / "ft.mcap", "-q"], capsys, caplog)
    assert rc == 0 and lines == []
    after = dict(faults)
    series = read_series(tmp_path / "ft.mcap", [f"ft.{n.replace('input', 'output')}" for n in start])
    for name, first in start.items():
        t, y, _ = series[f"ft.{name.replace('input', 'output')}"]
        assert len(t) == 11
        assert list(y[:6]) == [float(first)] * 6        # read back as float64
        assert list(y[6:]) == [float(after.get(name, first))] * 5


# -- the FMI type table and the checks the corpus cannot reach with the shipped units -------
@pytest.mark.parametrize("fmi_type", sorted(INT_RANGES))
def test_integers_are_refused_outside_their_type_never_wrapped(fmi_type):
    lo, hi = INT_RANGES[fmi_type]
    assert check_value(lo, fmi_type) is None and check_value(hi, fmi_type) is None
    for bad in (lo - 1, hi + 1):
        assert check_value(bad, fmi_type) == f"{bad} is outside the range {lo}..{hi} of this {fmi_type} variable"
    assert check_value(1.0, fmi_type) == f"{fmi_type} takes an integer, got 1.0"
    assert check_value(True, fmi_type) == f"{fmi_type} takes an integer, got True"


def test_fmi3_widths_and_declared_bounds():
    assert check_value(300, "Int8") == "300 is outside the range -128..127 of this Int8 variable"  # not 44
    assert check_value(-1, "UInt64") == "-1 is outside the range 0..18446744073709551615 of this UInt64 variable"
    assert check_value(2 ** 64 - 1, "UInt64") is None
    assert check_value(5, "Integer", (0, 4)) == "5 is outside the range 0..4 of this Integer variable"
    assert check_value(NAN, "Float64", non_finite=True) is None       # a fault into a Real input
    assert check_value(NAN, "Float32") == "Float32 value must be finite, got nan"
    assert check_value(10 ** 400, "Real") == f"{10 ** 400!r}"[:57] + "... is too large for Real"


class _Var:
    def __init__(self, type_, causality, variability):
        self.type, self.causality, self.variability = type_, causality, variability


def _Scenario(faults):
    from immersim.orchestrator.scenario import FaultSpec, LogSpec, Scenario, UnitSpec
    return Scenario(Path("s.toml"), "", [UnitSpec("u", "u.fmu", {})], [], [],
                    [FaultSpec("u", name, 0, value) for name, value in faults], LogSpec())


def test_a_fault_may_force_a_tunable_parameter_only(monkeypatch):
    import immersim.orchestrator.values as values
    from immersim.orchestrator.errors import ScenarioError

    monkeypatch.setattr(values, "declared_bounds", lambda path, unit: {})
    variables = {"u": {"k": _Var("Real", "parameter", "tunable"), "n": _Var("Integer", "parameter", "fixed")}}
    check_values(_Scenario([("k", 2.0)]), variables, {"u": Path("u.fmu")})
    with pytest.raises(ScenarioError, match=r"s\.toml: faults\[0\]\.value: u\.k: Real value must be finite, got nan"):
        check_values(_Scenario([("k", NAN)]), variables, {"u": Path("u.fmu")})   # NaN only into an input
    with pytest.raises(ScenarioError, match=r"s\.toml: faults\[0\]\.target: u\.n is a fixed parameter"):
        check_values(_Scenario([("n", 2)]), variables, {"u": Path("u.fmu")})


def test_schema_models_are_the_only_keys():
    """The schema is the documentation of the keys: every table refuses keys it does not declare,
    and its lists of names are those the code uses."""
    from immersim.orchestrator.schema import REDUCE_NAMES
    from immersim.orchestrator.sweep.common import REDUCERS

    assert set(ScenarioFile.model_fields) >= {"simulation", "units", "connections", "inputs", "faults", "log", "foxglove"}
    assert set(SweepFile.model_fields) >= {"scenario", "grid", "variants", "metrics", "plot"}
    assert REDUCE_NAMES == tuple(REDUCERS)


# -- a few through a real process: the whole stderr is one line --------------------------
@pytest.mark.parametrize("argv_tail,pattern", [
    (["--set", "plat.M=-240.0"], r"units\[1\]\.parameters\.M = -240\.0: unit plat refused it at initialization"),
    (["--set", "simulation.stop=1e300"], r"simulation\.stop \(set by override 'simulation\.stop'\)"),
    (["--set", "net.players=3000000000"], r"net\.players: 3000000000 is outside the range"),
])
def test_one_line_from_a_real_process(tmp_path, good, argv_tail, pattern):
    import re

    path = tmp_path / "p.toml"
    path.write_text(dump_toml(good))
    proc = subprocess.run([sys.executable, "-m", "immersim.orchestrator.cli", "run", str(path), "-q",
                           "-o", str(tmp_path / "p.mcap")] + argv_tail,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("immersim: error: "), proc.stderr
    assert re.search(pattern, proc.stderr), proc.stderr
