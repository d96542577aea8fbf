"""Helpers of the stress suite (tests/stress and benchmarks/bench_stress.py).

* :func:`dumps` writes a scenario dict as TOML (the subset scenarios use);
* :func:`check_log` reads an MCAP log back and checks every logged number is finite and
  that the log holds one message per completed step;
* :func:`run_checked` runs a scenario and returns a :class:`Outcome`: completed, or failed
  with a message naming the unit and the time -- anything else (a raw exception, NaN in the
  log) fails the caller's assertion.
* scenario builders for the three units with parameters drawn inside documented ranges.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional

from immersim.orchestrator.execution import RunFailed, run_scenario


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int,)):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def dumps(sc: Dict[str, Any]) -> str:
    """TOML text of a scenario dict: ``simulation``, ``units`` (with ``parameters``),
    ``connections``, ``inputs``, ``faults`` and ``log``."""
    out: List[str] = []
    if "description" in sc:
        out.append(f"description = {_value(sc['description'])}")
    for table in ("simulation", "log"):
        if table in sc:
            out.append(f"[{table}]")
            out += [f"{k} = {_value(v)}" for k, v in sc[table].items()]
    for u in sc.get("units", []):
        out.append("[[units]]")
        out += [f"{k} = {_value(v)}" for k, v in u.items() if k != "parameters"]
        if u.get("parameters"):
            out.append("[units.parameters]")
            out += [f"{_value(k)} = {_value(v)}" for k, v in u["parameters"].items()]
    for arr in ("connections", "inputs", "faults"):
        for item in sc.get(arr, []):
            out.append(f"[[{arr}]]")
            out += [f"{k} = {_value(v)}" for k, v in item.items()]
    return "\n".join(out) + "\n"


def write_scenario(sc: Dict[str, Any], path: Path) -> Path:
    path.write_text(dumps(sc))
    return path


@dataclass
class LogCheck:
    """What :func:`check_log` found in a log."""

    messages: Dict[str, int] = field(default_factory=dict)
    run: Dict[str, str] = field(default_factory=dict)
    nonfinite: List[str] = field(default_factory=list)
    values: int = 0


def _numbers(obj, prefix=""):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{prefix}.{k}" if prefix else k)
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{prefix}[{i}]")
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield prefix, float(obj)


def check_log(path: Path) -> LogCheck:
    """Read every message of an MCAP log (strict JSON-with-NaN decoding, or the "ros1" packing)
    and every metadata record; list any non-finite number."""
    from mcap.reader import make_reader

    from immersim.orchestrator.mcapio import channel_schema

    res = LogCheck()
    decoders = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages():
            res.messages[channel.topic] = res.messages.get(channel.topic, 0) + 1
            if channel.message_encoding == "json":
                obj = json.loads(message.data)  # json accepts NaN/Infinity tokens: we look for them
            else:   # a packed ("ros1") channel: its numbers as they are
                decode = decoders.get(channel.id) or decoders.setdefault(channel.id, channel_schema(schema, channel)[1])
                obj = decode(message.data)
            for name, x in _numbers(obj):
                res.values += 1
                if not math.isfinite(x):
                    res.nonfinite.append(f"{channel.topic}.{name} = {x} at {message.log_time / 1e9:g} s")
        for md in reader.iter_metadata():
            if md.name == "run":
                res.run = dict(md.metadata)
    return res


@dataclass
class Outcome:
    completed: bool
    steps_done: int
    message: str
    log: Optional[LogCheck]


def run_checked(scenario: Path, mcap: Path, overrides: Optional[Dict[str, Any]] = None) -> Outcome:
    """Run; a failure must be a :class:`RunFailed` (clear message), never another exception.
    The log is read back either way."""
    try:
        res = run_scenario(scenario, mcap, overrides=overrides)
        out = Outcome(True, res.steps_done, "", None)
    except RunFailed as exc:
        out = Outcome(False, exc.result.steps_done, str(exc), None)
    if mcap.exists():
        out.log = check_log(mcap)
    return out


def assert_sound(out: Outcome, units: List[str]) -> None:
    """The stress property: the log holds no non-finite number, one message per completed
    step (plus the initial one) for each unit channel, and a failure names a unit and a time."""
    assert out.log is not None, "no log written"
    assert not out.log.nonfinite, f"non-finite values reached the log: {out.log.nonfinite[:5]}"
    for u in units:
        assert out.log.messages.get(u) == out.steps_done + 1, (u, out.log.messages, out.steps_done)
    if out.completed:
        assert out.log.run.get("status") == "completed", out.log.run
    else:
        assert out.log.run.get("status") == "failed", out.log.run
        assert any(f"unit {u}" in out.message for u in units), out.message
        assert "t = " in out.message, out.message


# -- scenario builders (parameters inside the documented ranges of fmus/*/README.md) ---------

def platform_scenario(params: Dict[str, Any], cues: Dict[str, float], stop: float, step: float = 0.033,
                      name: str = "p") -> Dict[str, Any]:
    """One platform in washout cueing; ``cues`` maps ``cue.*``/``jolt`` to sine amplitudes
    (frequency 0.5 Hz, the jolt as a 2-step pulse at stop/2)."""
    inputs = []
    for var, amp in cues.items():
        if var == "jolt":
            inputs.append({"target": f"{name}.jolt", "kind": "table",
                           "times": [0.0, stop / 2 - 1e-3, stop / 2, stop / 2 + 2 * step, stop / 2 + 2 * step + 1e-3],
                           "values": [0.0, 0.0, amp, amp, 0.0]})
        else:
            inputs.append({"target": f"{name}.{var}", "kind": "sine", "amplitude": amp, "frequency": 0.5})
    return {"simulation": {"stop": stop, "step": step},
            "units": [{"name": name, "fmu": "platform", "parameters": dict(params)}],
            "inputs": inputs}


def network_scenario(params: Dict[str, Any], throttle: List[float], steer: List[float], stop: float,
                     latency_burst: float = 1.0, name: str = "net") -> Dict[str, Any]:
    """One network unit; player i drives with constant throttle[i] and a sine steer[i];
    ``latency_scale`` jumps to ``latency_burst`` at stop/2."""
    inputs = []
    for i, (th, st) in enumerate(zip(throttle, steer), start=1):
        inputs.append({"target": f"{name}.avatar[{i}].throttle", "kind": "constant", "value": th})
        inputs.append({"target": f"{name}.avatar[{i}].steer", "kind": "sine", "amplitude": st, "frequency": 0.4})
    inputs.append({"target": f"{name}.latency_scale", "kind": "step", "at": stop / 2, "value": latency_burst,
                   "initial": 1.0})
    return {"simulation": {"stop": stop},
            "units": [{"name": name, "fmu": "network", "parameters": dict(params)}],
            "inputs": inputs}


def collision_scenario(scene: str, pairs: str, motion: Dict[str, Dict[str, float]], stop: float,
                       params: Optional[Dict[str, Any]] = None, name: str = "coll") -> Dict[str, Any]:
    """One collision unit; ``motion`` maps ``body[i].x`` etc. to ramp slopes / initial values."""
    inputs = [{"target": f"{name}.{var}", "kind": "ramp", "at": 0.0, "slope": m["slope"],
               "initial": m.get("initial", 0.0)} for var, m in motion.items()]
    return {"simulation": {"stop": stop},
            "units": [{"name": name, "fmu": "collision",
                       "parameters": dict({"scene": scene, "pairs": pairs}, **(params or {}))}],
            "inputs": inputs}


BIPYRAMID_OBJ = "\n".join(
    ["v 0 0 1", "v 0 0 -1"]
    + [f"v {math.cos(2 * math.pi * k / 5):.9f} {math.sin(2 * math.pi * k / 5):.9f} 0" for k in range(5)]
    + [f"f 1 {3 + k} {3 + (k + 1) % 5}" for k in range(5)]
    + [f"f 2 {3 + (k + 1) % 5} {3 + k}" for k in range(5)]) + "\n"
"""A closed pentagonal bipyramid: 7 vertices, exactly 10 triangles (the smallest mesh of the range)."""
