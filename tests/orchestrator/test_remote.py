"""Units in worker processes (``process = N``): the same log as in this process, under Jacobi
(stepped in parallel) and Gauss-Seidel, lazy stepping included; errors keep their type and
message; a worker that dies stops the run with a message and the log keeps every step."""
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from immersim.orchestrator.analysis.diff import diff_logs
from immersim.orchestrator.errors import FmuCallError, ScenarioError
from immersim.orchestrator.execution import Execution, RunFailed, run_scenario
from immersim.orchestrator.mcapio import read_info, read_series
from immersim.orchestrator.scenario import load_scenario

from .helpers import oscillator_scenario

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"
#: campus_drive with one [[connections]] table per signal (the same system as the shipped file, whose
#: signal groups a text edit cannot split): the variants below edit single connections
FLAT_CAMPUS = ROOT / "tests" / "scenarios" / "flat" / "campus_drive.toml"


def _same_logs(a: Path, b: Path) -> int:
    """Every signal of logs ``a`` and ``b`` the same, bit for bit (``immersim diff``); how many."""
    d = diff_logs(a, b)
    assert d.equal, str(d)
    return len(d.signals)


@pytest.mark.parametrize("algorithm", ["jacobi", "gauss-seidel"])
def test_worker_units_give_the_same_log(tmp_path, test_fmus, algorithm):
    """Oscillator m2 in worker process 1: every logged signal equals the one-process run, bit
    for bit (the worker runs the same FmuInstance calls in the same order per unit)."""
    logs = {}
    for where, extra in (("here", ""), ("worker", "")):
        scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=2.0, algorithm=algorithm,
                                  extrapolation="linear", name=f"{where}.toml")
        logs[where] = tmp_path / f"{where}.mcap"
        res = run_scenario(scn, logs[where], overrides={"m2:process": 1} if where == "worker" else None)
        assert res.remote_units == (["m2"] if where == "worker" else [])
    assert _same_logs(logs["here"], logs["worker"]) >= 4
    res_info = read_info(logs["worker"])
    assert res_info.channels["m2"].count == 62


@pytest.mark.parametrize("algorithm, where", [("jacobi", {"coll": 1, "plat": 1}),
                                               ("gauss-seidel", {"net": 1, "plat": 2})])
def test_campus_units_in_workers_step_in_parallel_to_the_same_log(tmp_path, algorithm, where):
    """campus_drive (1.5 s; the contacts start later, the bounce at 3.76 s is not reached) with
    units in workers: the log (the 3D view included) equals the one-process run of the same
    algorithm. Jacobi: coll and plat step in one worker while net steps here. Gauss-Seidel
    (net -> coll, plat): net, fed only across the cycle, starts each step in worker 1 while the
    last one is logged; plat (worker 2) steps while coll steps here. The timing reports the
    workers' units and the wait."""
    ov = {"simulation.stop": 1.5, "simulation.algorithm": algorithm, "net:process": 0}
    here, there = tmp_path / "here.mcap", tmp_path / "there.mcap"
    run_scenario(SCEN / "campus_drive.toml", here, overrides=ov)
    res = run_scenario(SCEN / "campus_drive.toml", there,
                       overrides={**ov, **{f"{u}:process": n for u, n in where.items()}})
    assert _same_logs(here, there) > 300
    assert res.remote_units == [u for u in ("net", "coll", "plat") if u in where] and "wait" in res.timing
    assert all(res.timing[f"unit:{u}"] > 0 for u in where) and "(worker)" in res.timing_summary()


def test_gauss_seidel_contact_loop_in_workers_is_the_same(tmp_path):
    """The closed loop through a contact (campus_drive to 4.5 s: avatar 1 bounces off tank_a
    at 3.76 s): Gauss-Seidel with net in a worker gives the one-process log."""
    ov = {"simulation.stop": 4.5}
    here, there = tmp_path / "here.mcap", tmp_path / "there.mcap"
    run_scenario(SCEN / "campus_drive.toml", here, overrides={**ov, "net:process": 0})
    res = run_scenario(SCEN / "campus_drive.toml", there, overrides={**ov, "net:process": 1})
    assert res.remote_units == ["net"]
    _same_logs(here, there)
    jolt = read_series(there, ["net.avatar[[]1].jolt"])["net.avatar[1].jolt"][1]
    assert jolt.max() > 5.0   # the bounce happened


def _campus_parallel(tmp_path) -> Path:
    """campus_drive with its contacts also read `delayed` by the network and the network in
    worker 1: the network and the collision unit then depend on each other only across steps
    and step at the same time (the shipped scene reads the contacts fresh, one process)."""
    import re

    text, n = re.subn(r'(from = "coll\.pair\[\d\]\.\w+"\nto = "net\.contact\[\d\]\.\w+"\n)',
                      r"\1delayed = true\n", FLAT_CAMPUS.read_text())
    assert n == 12
    text, n = re.subn(r'\nname = "net"\nfmu = "network"\n', '\nname = "net"\nfmu = "network"\nprocess = 1\n', text)
    assert n == 1                                  # the network in worker 1
    path = tmp_path / "campus_parallel.toml"
    path.write_text(text)
    return path


def test_posting_ahead_gives_the_same_log(tmp_path, monkeypatch):
    """campus_drive with delayed contacts to 4.5 s (net in a worker, its next step posted as soon as its
    inputs are known, i.e. once coll and net's last step are done): the log of posting only when
    a step is over (``Master.POST_AHEAD = False``), bit for bit."""
    from immersim.orchestrator.master import Master

    ov = {"simulation.stop": 4.5}
    scen = _campus_parallel(tmp_path)
    run_scenario(scen, tmp_path / "ahead.mcap", overrides=ov)
    monkeypatch.setattr(Master, "POST_AHEAD", False)
    run_scenario(scen, tmp_path / "after.mcap", overrides=ov)
    assert _same_logs(tmp_path / "ahead.mcap", tmp_path / "after.mcap") > 300


def test_campus_contacts_read_fresh_respond_one_step_before_delayed_ones(tmp_path):
    """The shipped campus_drive (poses into the collision unit `delayed`, its contacts read
    fresh by the network) against the same scene with the contacts `delayed` too (the two
    units stepping at the same time), to 4.5 s through avatar 1's bounce at 3.76 s: until the
    network responds the logs of the avatars and the platform are equal (nothing reaches the
    network from the collision unit before a contact); the shipped network responds one step
    earlier, with the same jolt to 2 %."""
    import re

    text = FLAT_CAMPUS.read_text()
    late_text, n = re.subn(r'(from = "coll\.pair\[\d\]\.\w+"\nto = "net\.contact\[\d\]\.\w+"\n)',
                           r"\1delayed = true\n", text)
    assert n == 12
    late = tmp_path / "campus_late.toml"
    late.write_text(late_text)
    ov = {"simulation.stop": 4.5, "net:process": 0}
    run_scenario(late, tmp_path / "late.mcap", overrides=ov)
    run_scenario(SCEN / "campus_drive.toml", tmp_path / "shipped.mcap", overrides={"simulation.stop": 4.5})
    a, b = read_series(tmp_path / "late.mcap", ["*"]), read_series(tmp_path / "shipped.mcap", ["*"])
    ja, jb = a["net.avatar[1].jolt"][1], b["net.avatar[1].jolt"][1]
    ka, kb = int(np.argmax(ja > 0)), int(np.argmax(jb > 0))
    assert kb > 0 and ka == kb + 1 and jb[kb] == pytest.approx(ja[ka], rel=0.02) and jb.max() > 5.0
    for k in a:
        if k.startswith(("net.avatar", "net.entity", "plat.stroke", "plat.pose")):
            np.testing.assert_array_equal(b[k][1][:kb], a[k][1][:kb], err_msg=k)


def test_chained_unit_steps_in_its_worker_to_the_same_log(tmp_path, monkeypatch):
    """campus_drive to 4.5 s (through avatar 1's bounce, its jolt on the platform) with plat in
    net's worker: plat reads only net, fresh, so it is chained to it (its worker gathers its
    inputs and steps it right after net, posted with it); the log equals the one-process log
    bit for bit, and the same with chaining off (plat's inputs gathered here)."""
    from immersim.orchestrator.master import Master

    ov = {"simulation.stop": 4.5}
    scen = _campus_parallel(tmp_path)
    here, chained, unchained = (tmp_path / f"{n}.mcap" for n in ("here", "chained", "unchained"))
    run_scenario(scen, here, overrides={**ov, "net:process": 0})
    ex = Execution(scen, chained, overrides={**ov, "plat:process": 1})
    ex.run()
    assert [s.name for s in ex.master._chained] == ["plat"] and ex.master.slots["plat"].links.chained
    assert _same_logs(here, chained) > 300
    monkeypatch.setattr(Master, "CHAIN", False)
    ex = Execution(scen, unchained, overrides={**ov, "plat:process": 1})
    ex.run()
    assert ex.master._chained == []
    _same_logs(here, unchained)
    assert read_series(chained, ["plat.jolt"])["plat.jolt"][1].max() > 5.0   # the bounce reached the platform


def test_a_worker_unit_is_posted_before_its_last_reply_is_taken(tmp_path, monkeypatch):
    """campus_drive with delayed contacts (net in worker 1, its outputs through shared memory): net's
    next step is posted as soon as the collision unit has stepped, while net's own reply of
    the step may still be outstanding (two posts in flight, two shared buffers in turn); never
    more than two."""
    from immersim.orchestrator.transport import RemoteInstance

    in_flight = []
    post_step = RemoteInstance.post_step

    def counting(self, *args, **kwargs):
        post_step(self, *args, **kwargs)
        in_flight.append(len(self._out))

    monkeypatch.setattr(RemoteInstance, "post_step", counting)
    run_scenario(_campus_parallel(tmp_path), tmp_path / "q.mcap", overrides={"simulation.stop": 2.0})
    assert max(in_flight) == 2 and min(in_flight) >= 1 and len(in_flight) == 61


@pytest.mark.parametrize("algorithm, where", [("jacobi", {"coll": 1, "plat": 2}),
                                               ("gauss-seidel", {"net": 1, "plat": 2}),
                                               ("gauss-seidel", {"net": 1, "plat": 1})])
def test_lazy_worker_units_match_eager(tmp_path, algorithm, where):
    """A unit in a worker may be stepped lazily (its worker decides the skip and catches up,
    a chained unit too: plat in net's worker): the same log as eager stepping."""
    ov = {"simulation.stop": 3.0, "simulation.algorithm": algorithm, **{f"{u}:process": n for u, n in where.items()}}
    lazy_log, eager_log = tmp_path / "lazy.mcap", tmp_path / "eager.mcap"
    ex = Execution(SCEN / "campus_idle.toml", lazy_log, overrides={**ov, "simulation.lazy": True})
    ex.run()
    assert all(ex.master.slots[u].skipped_steps > 50 for u in where)
    run_scenario(SCEN / "campus_idle.toml", eager_log, overrides={**ov, "simulation.lazy": False})
    _same_logs(lazy_log, eager_log)


def test_error_in_a_worker_unit_keeps_type_message_and_log(tmp_path, test_fmus):
    """The NaN fault of test_runs.test_error_mid_run..., m2 in a worker: the same message."""
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=1.0, algorithm="gauss-seidel",
                              extra='[[faults]]\ntarget = "m2.x_other"\nat = 0.33\nvalue = nan\n')
    out = tmp_path / "fail.mcap"
    with pytest.raises(RunFailed, match=r"failed at t = 0.33 s after 10 of 31 steps: unit m2: fmi2DoStep returned "
                                        r"discard at t = 0.33 s: FmuInputError: m2: input x_other = nan at t = 0.33 s") as e:
        run_scenario(scn, out, overrides={"m2:process": 1})
    assert isinstance(e.value.__cause__, FmuCallError) and e.value.__cause__.unit == "m2"
    info = read_info(out)
    assert info.channels["m2"].count == 11 and info.metadata["run"]["status"] == "failed"


def test_a_worker_that_dies_stops_the_run_and_the_log_keeps_every_step(tmp_path, test_fmus):
    """SIGKILL to the worker after step 5 is logged. Step 6 was posted before the log was
    written (pipelined), so the worker may have answered it already: the run fails at step 6 or
    7 with the worker's exit code, and the log holds every completed step."""
    import re

    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"], step=0.033, stop=3.0, algorithm="jacobi")
    out = tmp_path / "killed.mcap"
    ex = Execution(load_scenario(scn, {"m2:process": 1}), out)

    def kill_at_step_5(k, t_ns):
        if k == 5:
            proc = ex.system.workers[1].proc
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()

    ex.observers.append(kill_at_step_5)
    with pytest.raises(RunFailed) as e:
        ex.run()
    m = re.search(r"after (\d+) of 91 steps: unit m2: fmi2DoStep/read returned fatal at t = ([\d.]+) s: "
                  r"worker process 1 \(pid \d+\) ended with exit code -9", str(e.value))
    assert m, str(e.value)
    done = int(m.group(1))
    assert done in (5, 6) and float(m.group(2)) == pytest.approx(done * 0.033)
    info = read_info(out)
    assert info.channels["m1"].count == info.channels["m2"].count == done + 1   # steps 0..done
    assert info.metadata["run"]["status"] == "failed"


def test_bad_process_number_is_refused(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"])
    with pytest.raises(ScenarioError, match=r"osc.toml: units\[0\].process \(set by override 'm1:process'\): must be an integer >= 0"):
        load_scenario(scn, {"m1:process": -1})
    with pytest.raises(ScenarioError, match=r"override 'mx:process': no unit 'mx'"):
        load_scenario(scn, {"mx:process": 1})


def test_replies_are_routed_to_their_unit(tmp_path, test_fmus):
    """Two units of one worker posted as one batch and collected in the other order: each gets
    its own outputs (a reply read for another unit is kept for it)."""
    from immersim.orchestrator.transport import RemoteInstance, WorkerProcess

    w = WorkerProcess(1)
    try:
        insts = {n: RemoteInstance(n, test_fmus["oscillator"], tmp_path / n, w) for n in ("a", "b")}
        for n, inst in insts.items():
            inst.start_loading()
        for n, inst in insts.items():
            inst.finish_loading()
            inst.initialize(0, None, {"x0": 1.0 if n == "a" else -2.0})
        readers = {n: inst.reader(["x"]) for n, inst in insts.items()}
        for inst in insts.values():
            inst.do_step(0, 33_000_000)
            inst.post(hold=True)
        w.flush()
        xb, xa = readers["b"].read()[0], readers["a"].read()[0]
        assert xa > 0.9 and xb < -1.8     # a started at 1, b at -2: not swapped
    finally:
        for inst in insts.values():
            inst.terminate()
        w.close()


def test_mailbox_keeps_the_order_and_wakes_a_blocked_worker(tmp_path, test_fmus):
    """The master's messages go through the worker's shared-memory mailbox: a message too long
    for a slot (a batch of 5000 queued input sets) goes through the socket only after the
    mailbox's earlier messages (else its step would run before the step posted first and the
    FMU's time check would refuse it), and a worker blocked on its socket after ``spin_s`` of
    silence is woken by the next post. Unit a, stepped that way, ends where unit b, stepped
    plainly in the same worker, does."""
    import pickle
    import time

    from immersim.orchestrator.transport import RemoteConfig, RemoteInstance, WorkerProcess

    w = WorkerProcess(1, RemoteConfig(spin_s=0.001))
    insts = {n: RemoteInstance(n, test_fmus["oscillator"], tmp_path / n, w) for n in ("a", "b")}
    h = 33_000_000
    try:
        assert w._box is not None
        for inst in insts.values():
            inst.start_loading()
        for inst in insts.values():
            inst.finish_loading()
            inst.initialize(0, None, {"x0": 1.0})
        readers = {n: inst.reader(["x", "v"]) for n, inst in insts.items()}
        a, b = insts["a"], insts["b"]
        a.do_step(0, h)
        a.post(read=False)                                  # through the mailbox
        a.do_step(h, h)
        a.queue += [("set", {"x_other": 0.0}) for _ in range(5000)]
        assert not w._box.fits(len(pickle.dumps(("run", "a", a.queue, True, 0), 5)))
        readers["a"].read()                                 # through the socket, after the first step
        deadline = time.monotonic() + 5.0                   # the worker blocks on its socket after spin_s
        while w._box.head[2] != 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert w._box.head[2] == 1
        a.do_step(2 * h, h)
        xa = readers["a"].read()                            # woken by this post: the reply comes
        # (whether the worker is still awake now is a race: after spin_s without a message it
        # blocks on its socket again, which takes 1 ms here)
        for k in range(3):
            b.do_step(k * h, h)
        xb = readers["b"].read()                            # one message: the three steps and the read
        assert xa == xb and xa[0] < 1.0
    finally:
        for inst in insts.values():
            inst.terminate()
        w.close()


def test_without_shared_memory_the_socket_gives_the_same_log(tmp_path, monkeypatch):
    """Where the machine does not keep the order of stores (``shm.STORE_ORDERED`` False: ARM,
    POWER) no shared-memory channel is made: the messages and outputs go through the socket,
    and campus_drive with delayed contacts (net in a worker, posted ahead) logs the same to 4.5 s."""
    from immersim.orchestrator.transport import shm

    ov = {"simulation.stop": 4.5}
    scen = _campus_parallel(tmp_path)
    run_scenario(scen, tmp_path / "shm.mcap", overrides=ov)
    monkeypatch.setattr(shm, "STORE_ORDERED", False)

    def refuse(self, *args):
        raise AssertionError("a shared-memory channel was made")

    monkeypatch.setattr(shm.Mailbox, "__init__", refuse)
    monkeypatch.setattr(shm.SharedValues, "__init__", refuse)
    res = run_scenario(scen, tmp_path / "socket.mcap", overrides=ov)
    assert res.remote_units == ["net"]
    assert _same_logs(tmp_path / "shm.mcap", tmp_path / "socket.mcap") > 300


@pytest.mark.parametrize("exc", [ValueError("bad value 3"), ZeroDivisionError("division by zero"),
                                 KeyError("x.y")])
def test_a_builtin_error_from_a_worker_keeps_its_type_and_message(exc):
    """The documented rule of the pipe: a builtin exception comes back as the same builtin type
    with the same text (KeyError's quoting included), not as a RuntimeError naming it."""
    from immersim.orchestrator.transport.process import portable, rebuild

    back = rebuild(portable(exc))
    assert type(back) is type(exc)
    assert str(back) == str(exc)


def test_an_error_of_no_known_module_becomes_a_runtime_error_naming_its_type():
    from immersim.orchestrator.transport.process import rebuild

    back = rebuild(("somepkg.mod", "Oddity", "went odd", {}))
    assert type(back) is RuntimeError and str(back) == "Oddity: went odd"


def test_in_process_and_worker_units_implement_the_instance_protocol(tmp_path, test_fmus):
    """The master algorithm knows units through ``Instance``: an FMU loaded here and one in a
    worker both implement it; only the worker's implements ``WorkerStepping``."""
    from immersim.orchestrator.fmu import FmuInstance
    from immersim.orchestrator.instance import Instance, WorkerStepping
    from immersim.orchestrator.transport import RemoteInstance, WorkerProcess

    local = FmuInstance("a", test_fmus["oscillator"], tmp_path / "a")
    w = WorkerProcess(1)
    try:
        remote = RemoteInstance("b", test_fmus["oscillator"], tmp_path / "b", w)
        remote.start_loading()
        remote.finish_loading()
        assert isinstance(local, Instance) and not isinstance(local, WorkerStepping) and not local.remote
        assert isinstance(remote, Instance) and isinstance(remote, WorkerStepping) and remote.remote
        for inst in (local, remote):
            inst.initialize(0, None, {"x0": 1.0})
        readers = [inst.reader(["x", "v"]) for inst in (local, remote)]
        for k in range(3):
            for inst in (local, remote):
                inst.do_step(k * 33_000_000, 33_000_000)
            assert readers[0].read() == readers[1].read()
    finally:
        local.terminate()
        remote.terminate()
        w.close()
