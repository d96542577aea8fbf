"""Reference FMUs in a worker process (``process = 1``) log what they log in the master's
process, record for record: a unit asking to end the simulation (Stair) ends the run cleanly at
that step; Binary, String and 64-bit integers cross the pipe exactly; FMI 3.0 arrays are sized
by the scenario's structural parameters in the worker too; every FMI 3.0 type through
connections to and from a worker unit."""
import os
from pathlib import Path

import pytest
from mcap.stream_reader import StreamReader

from immersim.orchestrator.cli import main
from immersim.orchestrator.errors import ImmersimError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.mcapio import _messages
from immersim.orchestrator.scenario import load_scenario
from immersim.orchestrator.system import check_system

from .test_conformance import CASES, FEED_INPUTS, ROOT, RUN, STATESPACE, log_rows, scenario


def _records(path: Path) -> dict:
    """Schemas, channels and every message (channel, sequence, times, bytes) of a log, and its
    run metadata (status, steps, time, reason)."""
    out = {"Schema": [], "Channel": [], "Message": []}
    with open(path, "rb") as fh:
        for r in StreamReader(fh, emit_chunks=False).records:
            kind = type(r).__name__
            if kind == "Message":
                out[kind].append((r.channel_id, r.sequence, r.log_time, r.publish_time, bytes(r.data)))
            elif kind in out:
                out[kind].append(r)
    out["run"] = _messages(path)[1]["run"]
    return out


def _in_worker(scn: Path, unit: str = "u") -> None:
    scn.write_text(scn.read_text().replace(f'name = "{unit}"\n', f'name = "{unit}"\nprocess = 1\n', 1))


@pytest.mark.parametrize("version,name,params", CASES,
                         ids=lambda x: x if isinstance(x, str) else "-".join(x) or "default")
def test_reference_fmu_in_a_worker_logs_as_in_process(tmp_path, version, name, params):
    """Each case of the conformance table (its outputs FMPy's at every step) in a worker: the
    one-process log, record for record, and the same run status."""
    step, stop = RUN[name]
    scn = scenario(tmp_path, ROOT / version / f"{name}.fmu", step, stop, params)
    here = run_scenario(scn, tmp_path / "here.mcap")
    there = run_scenario(scn, tmp_path / "there.mcap", overrides={"u:process": 1})
    assert there.remote_units == ["u"] and (there.status, there.reason) == (here.status, here.reason)
    assert _records(tmp_path / "there.mcap") == _records(tmp_path / "here.mcap")


@pytest.mark.parametrize("version,algorithm", [("fmi2", "jacobi"), ("fmi3", "jacobi"), ("fmi3", "gauss-seidel")])
def test_worker_unit_asking_to_end_ends_the_run_as_in_process(tmp_path, capsys, version, algorithm):
    """Stair asks to end the simulation in its step to t = 9 s: in a worker as here, exit 0,
    the same status line, the same log record for record (9 steps, status "ended" naming the
    unit and the time)."""
    got = {}
    for where in ("here", "worker"):
        scn = scenario(tmp_path, ROOT / version / "Stair.fmu", 1.0, 12.0, {})
        scn.write_text(scn.read_text().replace("step = 1.0\n", f'step = 1.0\nalgorithm = "{algorithm}"\n'))
        if where == "worker":
            _in_worker(scn)
        out = tmp_path / f"{where}.mcap"
        assert main(["run", str(scn), "-o", str(out), "-q"]) == 0
        lines = capsys.readouterr().out.splitlines()
        got[where] = ([ln for ln in lines if "asked to end" in ln], _records(out))
    assert got["worker"][0] == got["here"][0] == ["unit u asked to end the simulation at t = 9 s"]
    assert got["worker"][1] == got["here"][1]
    assert got["here"][1]["run"]["status"] == "ended" and got["here"][1]["run"]["steps_done"] == "9"
    assert len(got["here"][1]["Message"]) == 10   # t = 0 .. 9 s


@pytest.mark.parametrize("algorithm,where", [("gauss-seidel", {"u": 1, "f": 1}), ("jacobi", {"d": 1}),
                                             ("jacobi", {"u": 1, "f": 2, "d": 1})])
def test_an_end_asked_in_or_out_of_a_worker_ends_every_unit_at_that_step(tmp_path, algorithm, where):
    """Stair (u) feeding a Feedthrough (f) beside a Dahlquist (d): whichever units run in
    workers (f stepped by u's worker after it; a worker unit posted ahead while the unit here
    ends; Stair in one worker, f in another), the log and status of the one-process run."""
    scn = tmp_path / "three.toml"
    scn.write_text("[simulation]\nstop = 12.0\nstep = 1.0\n" + "".join(
        f'[[units]]\nname = "{u}"\nfmu = "{ROOT / "fmi3" / f"{n}.fmu"}"\n'
        for u, n in (("u", "Stair"), ("d", "Dahlquist"), ("f", "Feedthrough")))
        + '[[connections]]\nfrom = "u.counter"\nto = "f.Int32_input"\n')
    ov = {"simulation.algorithm": algorithm}
    here = run_scenario(scn, tmp_path / "here.mcap", overrides=ov)
    ov_there = {**ov, **{f"{u}:process": n for u, n in where.items()}}
    there = run_scenario(scn, tmp_path / "there.mcap", overrides=ov_there)
    assert sorted(there.remote_units) == sorted(where)
    assert (there.status, there.steps_done) == (here.status, 9)
    assert there.reason == here.reason == "unit u asked to end the simulation at t = 9 s"
    f, _ = log_rows(tmp_path / "there.mcap", "f")
    u, _ = log_rows(tmp_path / "there.mcap", "u")
    assert len(f) == 10 and {r["Int32_output"] for _, r in f} <= {r["counter"] for _, r in u} | {0}
    assert _records(tmp_path / "there.mcap") == _records(tmp_path / "here.mcap")


def test_worker_unit_asking_to_end_through_the_socket(tmp_path, monkeypatch):
    """Without shared memory (machines that do not keep the order of stores) the end comes back
    with the step's reply through the socket: the same log."""
    from immersim.orchestrator.transport import shm

    scn = scenario(tmp_path, ROOT / "fmi3" / "Stair.fmu", 1.0, 12.0, {})
    run_scenario(scn, tmp_path / "here.mcap")
    _in_worker(scn)
    monkeypatch.setattr(shm, "STORE_ORDERED", False)
    res = run_scenario(scn, tmp_path / "socket.mcap")
    assert (res.status, res.steps_done, res.reason) == ("ended", 9, "unit u asked to end the simulation at t = 9 s")
    assert _records(tmp_path / "socket.mcap") == _records(tmp_path / "here.mcap")


def test_binary_and_64_bit_integers_cross_the_worker_pipe_exactly(tmp_path):
    """Feedthrough without its String (the outputs could go through the float64 shared buffer):
    a Binary (changed by a fault at 0.2 s), Int64 2**53 + 1 and UInt64 2**64 - 1 (no float64
    holds them) come back from the worker as set, and the log equals the one-process log."""
    params = {k: v for k, v in FEED_INPUTS.items() if k != "String_input"}
    params.update(Binary_input="00ff1000", Int64_input=2**53 + 1, UInt64_input=2**64 - 1)
    extra = ('[log]\nexclude = ["u.String_*"]\n'
             '[[faults]]\ntarget = "u.Binary_input"\nat = 0.2\nvalue = "c0ffee"\n')
    for where in ("here", "worker"):
        scn = scenario(tmp_path, ROOT / "fmi3" / "Feedthrough.fmu", 0.1, 0.5, params, extra=extra)
        if where == "worker":
            _in_worker(scn)
        run_scenario(scn, tmp_path / f"{where}.mcap")
    rows, _ = log_rows(tmp_path / "worker.mcap")
    assert [r["Binary_output"] for _, r in rows] == [b"\x00\xff\x10\x00"] * 3 + [b"\xc0\xff\xee"] * 3
    assert {(r["Int64_output"], r["UInt64_output"]) for _, r in rows} == {(2**53 + 1, 2**64 - 1)}
    assert _records(tmp_path / "worker.mcap") == _records(tmp_path / "here.mcap")


@pytest.mark.parametrize("worker_unit", ["a", "b"])
def test_every_fmi3_type_through_connections_to_a_worker(tmp_path, worker_unit):
    """Two Feedthrough units, every output of a connected to b's input of its type (String and
    Binary included), one of them in a worker: the one-process log, record for record."""
    fmu = ROOT / "fmi3" / "Feedthrough.fmu"
    types = ["Float32_continuous", "Float32_discrete", "Float64_continuous", "Float64_discrete", "Int8", "UInt8",
             "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Boolean", "String", "Binary", "Enumeration"]
    params = dict(FEED_INPUTS, Binary_input="0a0b0c", Int64_input=-(2**63), UInt64_input=2**64 - 1)
    body = "".join(f'"{k}" = {v!r}\n'.replace("True", "true") if not isinstance(v, str) else f'"{k}" = "{v}"\n'
                   for k, v in params.items())
    conns = "".join(f'[[connections]]\nfrom = "a.{t}_output"\nto = "b.{t}_input"\n' for t in types)
    text = (f'[simulation]\nstop = 0.5\nstep = 0.1\n[[units]]\nname = "a"\nfmu = "{fmu}"\n[units.parameters]\n{body}'
            f'[[units]]\nname = "b"\nfmu = "{fmu}"\n{conns}'
            '[[inputs]]\ntarget = "a.Float64_continuous_input"\nkind = "ramp"\nat = 0.0\nslope = 0.3\n')
    for where in ("here", "worker"):
        scn = tmp_path / f"{where}.toml"
        scn.write_text(text)
        if where == "worker":
            _in_worker(scn, worker_unit)
        run_scenario(scn, tmp_path / f"{where}.mcap")
    b, _ = log_rows(tmp_path / "worker.mcap", "b")
    assert b[-1][1]["Binary_output"] == b"\x0a\x0b\x0c" and b[-1][1]["Int64_output"] == -(2**63)
    assert _records(tmp_path / "worker.mcap") == _records(tmp_path / "here.mcap")


def test_structural_parameters_size_the_arrays_of_a_worker_unit(tmp_path):
    """StateSpace with m = 1, n = 2, r = 4 from the scenario: the worker's instance has the
    arrays the master checked the scenario against (y[4] of shape (4,), no u[2])."""
    scn = tmp_path / "ss.toml"
    fmu = ROOT / "fmi3" / "StateSpace.fmu"
    scn.write_text(STATESPACE.format(fmu=fmu).replace('"A[1,1]" = 0.0', "m = 1, n = 2, r = 4")
                   .replace('name = "b"\n', 'name = "b"\nparameters = { m = 4 }\n').replace("a.u[2]", "a.u[1]"))
    system = check_system(load_scenario(scn, {"a:process": 1}))
    system.instantiate()
    try:
        a = system.instances["a"]
        assert a.remote and a.variables == system.variables["a"]
        y4 = a.worker.call("a", "call", "var", ("y[4]",))
        assert y4 == system.variables["a"]["y[4]"] and y4.shape == (4,) and y4.index == 3
        with pytest.raises(KeyError):
            a.worker.call("a", "call", "var", ("u[2]",))
    finally:
        system.terminate()


def test_a_structural_parameter_refused_in_a_worker_fails_as_in_process(tmp_path):
    """StateSpace (0.0.41) refuses any value of its structural parameters (see the conformance
    tests): in a worker the run fails with the message of the one-process run."""
    scn = tmp_path / "ss.toml"
    scn.write_text(STATESPACE.format(fmu=ROOT / "fmi3" / "StateSpace.fmu").replace('"A[1,1]" = 0.0', "m = 2"))
    messages = []
    for ov in (None, {"a:process": 1}):
        with pytest.raises(ImmersimError, match=r"Expected nValues >= 2 but was 1") as e:
            run_scenario(scn, tmp_path / "err.mcap", overrides=ov)
        messages.append(str(e.value))
    assert messages[0] == messages[1]


def test_an_fmu_returning_early_in_a_worker_completes_each_macro_step(tmp_path, monkeypatch):
    """BouncingBall (FMI 3.0) made to return early at each bounce in the worker (instantiated
    with ``earlyReturnAllowed = true`` there, and its early returns logged to a file, through a
    ``sitecustomize`` on the worker's path):
    the worker calls it again to each step's end, as the master's process does, so the log is
    the one of the run without early returns, record for record."""
    fmu, (step, stop) = ROOT / "fmi3" / "BouncingBall.fmu", RUN["BouncingBall"]
    scn = scenario(tmp_path, fmu, step, stop, {})
    run_scenario(scn, tmp_path / "plain.mcap")
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(
        "from fmpy.fmi3 import FMU3Slave\n"
        "_instantiate = FMU3Slave.instantiate\n"
        "def instantiate(self, **kw):\n"
        "    open(%r, 'a').write('early return allowed\\n')\n"
        "    return _instantiate(self, earlyReturnAllowed=True, **kw)\n"
        "FMU3Slave.instantiate = instantiate\n"
        "import logging\n"
        "_log = logging.getLogger('immersim.orchestrator.fmi3')\n"
        "_log.setLevel(logging.DEBUG)\n"
        "_log.addHandler(logging.FileHandler(%r))\n" % (str(tmp_path / "marker"), str(tmp_path / "early.log")))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")])))
    res = run_scenario(scn, tmp_path / "early.mcap", overrides={"u:process": 1})
    assert (tmp_path / "marker").read_text() == "early return allowed\n"   # the worker's instance, once
    early = [ln for ln in (tmp_path / "early.log").read_text().splitlines() if "fmi3DoStep returned early" in ln]
    assert len(early) >= 3   # the bounces (see the conformance test of early return)
    assert res.status == "completed" and res.remote_units == ["u"]
    assert _records(tmp_path / "early.mcap") == _records(tmp_path / "plain.mcap")
