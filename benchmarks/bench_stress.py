"""Long stress cases -> ``results/stress/``.

The fast cases run in ``make test`` (``tests/stress/``); this script runs the long ones:

* **random** -- hypothesis-driven random scenarios of each unit with parameters inside the
  documented ranges (more examples and longer runs than the tests), plus random closed-loop
  campus drives (network -> collision -> network, network -> platform);
* **long** -- 1000 s runs of the platform (washout of a random drive) and of the network
  (4 players, latency 2 s, loss 50 %) and their boundedness;
* **meshes** -- a probe crossing a tank of 10 .. 200k triangles (bipyramid OBJ, box, spheres,
  the thesis's tanks, 100k and 200k tanks);
* **sigint** -- SIGINT at random instants of ``immersim run`` (including during start-up);
* **signals** -- SIGINT, SIGTERM and SIGHUP, 50 random instants each (start-up included), with
  the log in the master's process, in a log-writer process, or a unit in a worker process: exit
  128 + signal, one line, a CRC-checked log holding exactly the completed steps, no leftovers;
* **segfault** -- a unit that segfaults or aborts at a random time (10 tries): exit 1, one line
  naming it and the time, a CRC-checked log of exactly the completed steps, no leftovers;
* **supervision** -- what the supervising parent of ``immersim run`` costs: campus_drive with
  and without it (``IMMERSIM_SUPERVISE=0``), interleaved, medians of loop and wall time.

Property everywhere: a run completes, or it fails with a clear message naming the unit and
the time; in both cases the MCAP log holds only finite numbers and one message per completed
step. Each case's outcome and wall time go to ``results/stress/README.md`` and ``cases.csv``.

Usage: ``python benchmarks/bench_stress.py [--quick]`` (quick: fewer examples, 100 s runs,
meshes up to 26.4k triangles).
"""
from __future__ import annotations

import argparse
import csv
import logging
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Callable, List

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "stress"))
from common import ROOT, stamp  # noqa: E402

from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import stresslib as sl  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests" / "boundaries"))
import boundlib as bl  # noqa: E402
from test_random_scenarios import cue_amplitudes, network_params, platform_params  # noqa: E402

OUT = ROOT / "results" / "stress"
CLI = [sys.executable, "-m", "immersim.orchestrator.cli"]
ROWS: List[dict] = []


def record(group: str, case: str, fn: Callable[[], str]) -> None:
    """Run one case; ``fn`` returns a detail string or raises (UNSOUND)."""
    t0 = time.perf_counter()
    try:
        detail, status = fn(), "ok"
    except Exception as exc:  # noqa: BLE001 - every failure is recorded
        notes = " ".join(getattr(exc, "__notes__", []))
        detail = f"{type(exc).__name__}: {exc} {notes}".replace("\n", " ")[:600]
        status = "UNSOUND"
        traceback.print_exc()
    dt = time.perf_counter() - t0
    ROWS.append({"group": group, "case": case, "status": status, "wall_s": round(dt, 2), "detail": detail})
    print(f"[{group}] {case}: {status} in {dt:.1f} s -- {detail[:200]}", flush=True)


def _run(sc: dict, tmp: Path, units: List[str], tag: str) -> sl.Outcome:
    out = sl.run_checked(sl.write_scenario(sc, tmp / f"{tag}.toml"), tmp / f"{tag}.mcap")
    sl.assert_sound(out, units)
    return out


class Tally:
    def __init__(self) -> None:
        self.done = self.failed = 0
        self.reasons: List[str] = []

    def add(self, out: sl.Outcome) -> None:
        if out.completed:
            self.done += 1
        else:
            self.failed += 1
            m = re.search(r"(?:Error|error): [^;]{0,120}", out.message)
            self.reasons.append(m.group(0) if m else out.message[:120])

    def __str__(self) -> str:
        r = "; ".join(sorted(set(self.reasons)))[:400]
        return f"{self.done} completed, {self.failed} failed cleanly" + (f" ({r})" if r else "")


# -- random scenarios -------------------------------------------------------------------------------

def random_cases(tmp: Path, n: int, stop: float) -> None:
    cfg = settings(max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck))

    def platform() -> str:
        t = Tally()

        @cfg
        @given(params=platform_params, cues=cue_amplitudes, step=st.sampled_from([0.033, 0.0165, 0.05]))
        def prop(params, cues, step):
            t.add(_run(sl.platform_scenario(params, cues, stop=stop, step=step), tmp, ["p"], "rp"))
        prop()
        return str(t)

    def network() -> str:
        t = Tally()

        @cfg
        @given(params=network_params, drive=st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1)), min_size=4,
                                                     max_size=4), burst=st.floats(0.0, 20.0))
        def prop(params, drive, burst):
            k = params["players"]
            t.add(_run(sl.network_scenario(params, [a for a, _ in drive][:k], [b for _, b in drive][:k], stop=stop,
                                           latency_burst=burst), tmp, ["net"], "rn"))
        prop()
        return str(t)

    def collision() -> str:
        t = Tally()

        @cfg
        @given(n_tanks=st.integers(1, 64), tris=st.sampled_from(["400", "5.4k"]),
               backend=st.sampled_from(["fcl", "basis_point", "honeycomb"]),
               vx=st.floats(-60.0, 60.0), vy=st.floats(-60.0, 60.0), wz=st.floats(-6.0, 6.0),
               x0=st.floats(-40.0, 40.0), spacing=st.floats(6.0, 30.0), ccd=st.booleans())
        def prop(n_tanks, tris, backend, vx, vy, wz, x0, spacing, ccd):
            scene = f"tanks:n={n_tanks},tris={tris},spacing={spacing:.3f};missile:name=m,dynamic=1,z=1"
            motion = {"body[1].x": {"slope": vx, "initial": x0}, "body[1].y": {"slope": vy, "initial": -x0},
                      "body[1].yaw": {"slope": wz}}
            t.add(_run(sl.collision_scenario(scene, "m vs any tank", motion, stop=min(stop, 2.0),
                                             params={"backend": backend, "ccd": ccd}), tmp, ["coll"], "rc"))
        prop()
        return str(t)

    def campus() -> str:
        t = Tally()

        @cfg
        @given(latency=st.floats(0.0, 2000.0), loss=st.floats(0.0, 0.5), players=st.integers(1, 4),
               payload=st.floats(0.0, 150.0), k_t=st.floats(0.0, 2.0), backend=st.sampled_from(["fcl", "basis_point"]),
               algorithm=st.sampled_from(["jacobi", "gauss-seidel"]), extrap=st.sampled_from(["zoh", "linear"]),
               throttle=st.floats(-1.0, 1.0))
        def prop(latency, loss, players, payload, k_t, backend, algorithm, extrap, throttle):
            from immersim.orchestrator.scenario import tomllib

            sc = tomllib.loads((Path(__file__).parent / "scenarios" / "campus_drive.toml").read_text())
            sc["simulation"].update({"stop": stop, "algorithm": algorithm, "extrapolation": extrap})
            net, coll, plat = sc["units"]
            net["parameters"].update({"latency_ms": latency, "loss": loss, "players": max(players, 2)})
            coll["parameters"]["backend"] = backend
            plat["parameters"].update({"payload_mass": payload, "washout.k_t": k_t})
            sc["inputs"][0] = {"target": "net.avatar[1].throttle", "kind": "constant", "value": throttle}
            sc.pop("log", None)
            sc.pop("description", None)
            t.add(_run(sc, tmp, ["net", "coll", "platform"], "rcd"))
        prop()
        return str(t)

    for name, fn in (("platform", platform), ("network", network), ("collision", collision),
                     ("campus_drive closed loop", campus)):
        record("random", f"{name}: {n} examples x {stop:g} s", fn)


# -- 1000 s runs -------------------------------------------------------------------------------------

def long_cases(tmp: Path, stop: float) -> None:
    def platform() -> str:
        cues = {"cue.f_x": 3.0, "cue.f_y": 2.0, "cue.w_z": 0.5, "jolt": 20.0}
        out = _run(sl.platform_scenario({}, cues, stop=stop), tmp, ["p"], "lp")
        from immersim.orchestrator.mcapio import read_series
        s = read_series(tmp / "lp.mcap", ["p.stroke*", "p.pose.*"])
        smax = max(float(abs(v).max()) for k, (t, v, u) in s.items() if "stroke" in k)
        return (f"{'completed' if out.completed else 'failed cleanly: ' + out.message[-200:]}; "
                f"{out.steps_done} steps; max |stroke| {smax:.4f} m (limit 0.12 m)")

    def network() -> str:
        params = {"players": 4, "render_nodes": 4, "entities": 16, "latency_ms": 2000.0, "jitter_ms": 200.0,
                  "loss": 0.5, "seed": 7}
        out = _run(sl.network_scenario(params, [0.8, -0.5, 1.0, 0.3], [0.5, -0.7, 0.2, 1.0], stop=stop,
                                       latency_burst=0.5), tmp, ["net"], "ln")
        from immersim.orchestrator.mcapio import read_series
        s = read_series(tmp / "ln.mcap", ["net.inconsistency_max", "net.avatar*.x", "net.avatar*.y"])
        inc = float(s["net.inconsistency_max"][1].max())
        pos = max(float(abs(v).max()) for k, (t, v, u) in s.items() if "avatar" in k)
        return (f"{'completed' if out.completed else 'failed cleanly: ' + out.message[-200:]}; "
                f"{out.steps_done} steps; max inconsistency {inc:.3g} m; max |avatar x,y| {pos:.1f} m (scene 100 m)")

    record("long", f"platform washout, {stop:g} s", platform)
    record("long", f"network 4 players, latency 2 s, loss 50 %, {stop:g} s", network)


# -- meshes of 10 .. 200k triangles ------------------------------------------------------------------------

def mesh_cases(tmp: Path, quick: bool) -> None:
    obj = tmp / "bipyramid.obj"
    obj.write_text(sl.BIPYRAMID_OBJ)
    probes = [("10 (bipyramid OBJ)", f"mesh:file={obj}"), ("12 (box)", "box:sx=1,sy=1,sz=1"),
              ("1280 (sphere subdiv 3)", "sphere:r=0.8,subdiv=3"), ("20480 (sphere subdiv 5)", "sphere:r=0.8,subdiv=5")]
    targets = ["400", "5.4k", "26.4k"] + ([] if quick else ["100000", "200000"])
    for label, probe in probes:
        for tris in targets:
            def case(label=label, probe=probe, tris=tris) -> str:
                scene = f"tank:name=tank_1,tris={tris};{probe},name=probe,dynamic=1,z=1"
                motion = {"body[1].x": {"slope": 20.0, "initial": -10.0}, "body[1].yaw": {"slope": 1.0}}
                t0 = time.perf_counter()
                out = _run(sl.collision_scenario(scene, "probe vs tank_1", motion, stop=1.0), tmp, ["coll"], "m")
                wall = time.perf_counter() - t0
                from immersim.orchestrator.mcapio import read_series
                s = read_series(tmp / "m.mcap", ["coll.pair[1].in_contact"])
                hits = int(s["coll.pair[1].in_contact"][1].sum())
                return (f"{'completed' if out.completed else 'failed cleanly: ' + out.message[-200:]}; "
                        f"{out.steps_done} steps, {hits} in contact, {wall:.1f} s incl. scene set-up")
            record("meshes", f"probe {label} vs tank of {tris} triangles", case)


# -- SIGINT at random instants ----------------------------------------------------------------------------

def sigint_cases(tmp: Path, n: int) -> None:
    """SIGINT during start-up (0.25 .. 0.7 s after the build check, which is logged just before
    the FMU is loaded and initialised) and at ``n`` random instants of the run."""
    # 10 h simulated (about 1.1 million steps, tens of seconds of loop): every instant lands in the run
    sc = sl.write_scenario({"simulation": {"stop": 36000.0}, "units": [{"name": "p", "fmu": "platform"}],
                            "inputs": [{"target": "p.cue.f_x", "kind": "sine", "amplitude": 2.0, "frequency": 0.5}]},
                           tmp / "sig.toml")
    rng = random.Random(7)
    delays = [0.25, 0.45, 0.7] + [rng.uniform(1.0, 12.0) for _ in range(n)]
    for i, delay in enumerate(delays):
        def case(delay=delay, i=i) -> str:
            mcap = tmp / f"sig{i}.mcap"
            p = subprocess.Popen(CLI + ["-v", "run", str(sc), "-o", str(mcap), "-q"], stderr=subprocess.PIPE,
                                 text=True)
            head = []
            for line in p.stderr:
                head.append(line)
                if "up to date" in line or "built" in line:
                    break
            time.sleep(delay)
            sent = p.poll() is None
            p.send_signal(signal.SIGINT)
            _, err = p.communicate(timeout=900)
            err = "".join(head) + err
            last = err.strip().splitlines()[-1] if err.strip() else ""
            problems = []
            # the signal came after the last step (reported as such, ignored while the command
            # ended, or the process had exited): sound when the log is complete (checked below)
            late = not sent or "after the run completed" in last or p.returncode == 0
            if p.returncode != 130 and not (late and p.returncode == 0):
                problems.append(f"exit {p.returncode} (expected 130)" + (" -- the run ended before the signal" if p.returncode == 0 else ""))
            if "Traceback" in err:
                problems.append("traceback on stderr")
            if mcap.exists():
                log = sl.check_log(mcap)
                steps = int(log.run.get("steps_done", -1))
                if log.nonfinite or log.messages.get("p", 0) != steps + 1:
                    problems.append(f"log: {log.messages} vs steps_done {steps}")
                if late and log.run.get("status") != "completed":
                    problems.append(f"exit {p.returncode} after a late signal, but the run is {log.run.get('status')}")
                where = f"log holds {steps} steps, status {log.run.get('status')}"
            else:
                where = "no log written"
                if "holds steps" in err:
                    problems.append("message claims a log that does not exist")
            if problems:
                raise AssertionError(f"{'; '.join(problems)}; {where}; stderr: {last[:300]}")
            return f"exit {p.returncode}; {where}" + ("; the signal came after the last step" if late else "")
        record("sigint", f"SIGINT {delay:.2f} s after the FMU build check", case)


def _test_unit(name: str, tmp: Path) -> Path:
    from immersim.orchestrator.build import build_unit

    return build_unit(ROOT / "tests" / "units" / name, tmp / "units")


#: the configurations the signal and crash tries rotate through
CONFIGS = {"log in the master": [], "log-writer process": ["--set", "log.process=true"],
           "unit in a worker": ["--set", "m2:process=1"]}


def signal_cases(tmp: Path, tries: int) -> None:
    """SIGINT, SIGTERM and SIGHUP at ``tries`` random instants each (0.02 .. 3 s after the
    command starts: start-up, set-up and the run) of two coupled oscillators (100 s at 1 ms)."""
    fmu = _test_unit("oscillator", tmp)
    rng = random.Random(13)
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        tally = {"before the log": 0, "mid-run": 0, "interpreter start-up": 0, "after the end": 0}
        problems: List[str] = []
        t0 = time.perf_counter()
        for i in range(tries):
            label, extra = list(CONFIGS.items())[i % len(CONFIGS)]
            run_dir = tmp / f"{sig.name}{i}"
            run_dir.mkdir()
            sc = bl.scenario(run_dir, bl.oscillator_units(fmu), stop=100.0, step=0.001)
            out = run_dir / "run.mcap"
            since = time.time()
            delay = rng.uniform(0.02, 3.0)
            p = bl.start(["run", str(sc), "-o", str(out), "-q", *extra], run_dir)
            time.sleep(delay)
            p.send_signal(sig)
            stdout, stderr = p.communicate(timeout=600)
            res = bl.Outcome(p.returncode, stdout, stderr)
            try:
                if res.code in (-sig, 1) and "orchestrator" not in res.stderr and not stdout:
                    # the interpreter's own start-up, before immersim's first line: the default
                    # action (SIGINT: KeyboardInterrupt in the import system); nothing was written
                    assert not out.exists() and not bl.leftovers(run_dir, since), "files after a start-up signal"
                    tally["interpreter start-up"] += 1
                    continue
                if res.code == 0:   # the run had ended when the signal came: a complete log
                    assert not res.stderr.strip(), res.stderr
                    bl.assert_log_holds(out, "m1", 100000, "completed")
                    assert not bl.leftovers(run_dir, since)
                    tally["after the end"] += 1
                    continue
                line = bl.one_line(res, 128 + sig, rf"interrupted by {sig.name}")
                if "no log was written" in line or "before the run started" in line or "while starting" in line:
                    assert not out.exists(), "a log exists though the line says none was written"
                    tally["before the log"] += 1
                else:
                    bl.assert_log_holds(out, "m1", bl.completed_steps(line), "interrupted")
                    tally["mid-run"] += 1
                left = bl.leftovers(run_dir, since)
                assert not left, f"left behind: {left}"
            except Exception as exc:  # noqa: BLE001 - every failure is recorded
                problems.append(f"try {i} ({label}, {delay:.2f} s): {type(exc).__name__}: {exc}; stderr "
                                f"{res.stderr.strip()[-200:]!r}"[:500])

        def case(tally=tally, problems=problems) -> str:
            if problems:
                raise AssertionError("; ".join(problems))
            hit = tries - tally["interpreter start-up"] - tally["after the end"]
            return (f"{tries} of {tries} sound: 0 steps lost, 0 leftovers; {hit} with "
                    f"exit 128+{sig.value}, one line and a CRC-valid log of exactly the completed steps "
                    f"({tally['mid-run']} mid-run, {tally['before the log']} before the log was opened); "
                    f"{tally['after the end']} after the run had ended (exit 0, complete log); "
                    f"{tally['interpreter start-up']} in the interpreter's own start-up, before immersim's first line "
                    f"(default action: exit {-sig.value if sig != signal.SIGINT else '1 or -2'}, nothing written)")
        t1 = time.perf_counter()
        record("signals", f"{sig.name} at {tries} random instants (0.02 .. 3 s), rotating {', '.join(CONFIGS)}", case)
        ROWS[-1]["wall_s"] = round(t1 - t0, 1)


def segfault_cases(tmp: Path, tries: int) -> None:
    """A unit that segfaults or aborts at a random time of a 6 s run (33 ms steps)."""
    fmu = _test_unit("crasher", tmp)
    rng = random.Random(17)
    problems: List[str] = []
    t0 = time.perf_counter()
    for i in range(tries):
        how = "segv" if i % 3 else "abort"
        crash_at = round(rng.uniform(0.05, 5.5), 3)
        extra = ["--set", "log.process=true"] if i % 2 else []
        run_dir = tmp / f"crash{i}"
        run_dir.mkdir()
        sc = bl.scenario(run_dir, bl.crash_units(fmu, crash_at, how), stop=6.0, step=0.033)
        out = run_dir / "run.mcap"
        since = time.time()
        res = bl.run(["run", str(sc), "-o", str(out), "-q", *extra], run_dir)
        k = bl.steps_of_crash(crash_at, 0.033)
        name = "SIGSEGV" if how == "segv" else "SIGABRT"
        try:
            bl.one_line(res, 1, rf"failed after {k} of 182 steps: unit boom crashed the process \({name}\) in a step "
                                rf"at t = {k * 0.033:.9g} s; the log .* holds steps 0\.\.{k}$")
            bl.assert_log_holds(out, "boom", k, "failed")
            assert not bl.leftovers(run_dir, since)
        except Exception as exc:  # noqa: BLE001 - every failure is recorded
            problems.append(f"try {i} ({how} at {crash_at} s{' log.process' if extra else ''}): {exc}"[:300])

    def case() -> str:
        if problems:
            raise AssertionError("; ".join(problems))
        return (f"{tries} of {tries} clean: exit 1, one line naming the unit and the time, CRC-valid log of exactly "
                f"the completed steps (in-process log and log-writer process), 0 leftovers")
    record("segfault", f"crasher unit, {tries} random crash times (segv and abort)", case)
    ROWS[-1]["wall_s"] = round(time.perf_counter() - t0, 1)


def supervision_cases(tmp: Path, pairs: int) -> None:
    """campus_drive with the supervising parent (A) and without (B, ``IMMERSIM_SUPERVISE=0``),
    interleaved; also with ``log.process = true`` (the supervised log-writer process gets each
    step at once instead of batches of 8)."""
    import os
    import statistics

    sc = ROOT / "scenarios" / "campus_drive.toml"
    for label, extra in (("campus_drive", []), ("campus_drive, log.process = true", ["--set", "log.process=true"])):
        loops: dict = {"A": [], "B": []}
        walls: dict = {"A": [], "B": []}
        for i in range(pairs):
            for arm in ("A", "B") if i % 2 == 0 else ("B", "A"):
                env = dict(os.environ, IMMERSIM_SUPERVISE="1" if arm == "A" else "0")
                w0 = time.perf_counter()
                r = subprocess.run(CLI + ["run", str(sc), "-o", str(tmp / f"ab{arm}.mcap"), "-q", *extra],
                                   capture_output=True, text=True, env=env)
                walls[arm].append(time.perf_counter() - w0)
                assert r.returncode == 0, r.stderr
                loops[arm].append(float(re.search(r"loop ([0-9.e+-]+) s", r.stdout).group(1)))

        def case(loops=loops, walls=walls) -> str:
            la, lb = statistics.median(loops["A"]), statistics.median(loops["B"])
            wa, wb = statistics.median(walls["A"]), statistics.median(walls["B"])
            return (f"{pairs} pairs interleaved; loop median supervised {la:.3f} s vs unsupervised {lb:.3f} s "
                    f"(ratio {la / lb:.3f}); wall median {wa:.2f} s vs {wb:.2f} s (ratio {wa / wb:.3f}); loops A "
                    f"{', '.join(f'{x:.2f}' for x in loops['A'])}; B {', '.join(f'{x:.2f}' for x in loops['B'])}")
        record("supervision", f"{label}: supervised (A) vs IMMERSIM_SUPERVISE=0 (B)", case)


def journal_cost(tmp: Path, steps: int = 3000, reps: int = 7) -> None:
    """The supervised log's extra work per step, in isolation: ``McapObserver.write_step`` of a
    campus_drive-sized step (5 channels, ~3 kB) with the journal (A) and without (B),
    interleaved; and the two int64 crumb stores before each doStep."""
    import statistics
    import timeit

    from immersim.orchestrator import supervisor
    from immersim.orchestrator.observers import McapObserver

    items = [(0, bytes(range(256)) * 2 + b"%d" % i) for i in range(5)]
    times: dict = {"A": [], "B": []}
    for r in range(reps):
        for arm in ("A", "B") if r % 2 == 0 else ("B", "A"):
            obs = McapObserver(tmp / f"journal{arm}.mcap")
            cid, _ = obs.add_channel("u", [])
            if arm == "A":
                obs.writer.journal = supervisor.Journal(obs._fh)
            step_items = [(cid, d) for _, d in items]
            t0 = time.perf_counter()
            for k in range(steps):
                obs.write_step(k * 33_000_000, k, step_items)
            times[arm].append((time.perf_counter() - t0) / steps)
            obs.close()
    crumb = supervisor.CRUMB
    store = min(timeit.repeat("c[2] = 1; c[3] = t", globals={"c": crumb, "t": 123456789}, number=200000, repeat=5))
    empty = min(timeit.repeat("pass", number=200000, repeat=5))

    def case() -> str:
        a, b = statistics.median(times["A"]), statistics.median(times["B"])
        return (f"write_step of 5 messages (2.6 kB): {a * 1e6:.1f} us with the journal vs {b * 1e6:.1f} us without "
                f"(+{(a - b) * 1e6:.1f} us per step, medians of {reps} x {steps} steps); crumb stores before a "
                f"doStep {(store - empty) / 200000 * 1e9:.0f} ns")
    record("supervision", "the journal copy and the crumb stores in isolation", case)


def write_report(quick: bool, cmd: str, groups: List[str]) -> None:
    """Write cases.csv and README.md; rows of groups not run this time are kept from cases.csv."""
    OUT.mkdir(parents=True, exist_ok=True)
    global ROWS
    old = []
    if (OUT / "cases.csv").exists():
        with open(OUT / "cases.csv", newline="") as fh:
            old = [r for r in csv.DictReader(fh) if r["group"] not in groups]
    order = ["random", "long", "meshes", "sigint", "signals", "segfault", "supervision"]
    ROWS = sorted(old + ROWS, key=lambda r: order.index(r["group"]) if r["group"] in order else 99)
    with open(OUT / "cases.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["group", "case", "status", "wall_s", "detail"])
        w.writeheader()
        w.writerows(ROWS)
    bad = [r for r in ROWS if r["status"] != "ok"]
    lines = ["# Stress suite (long cases)", "", stamp(cmd), "",
             "(A run with `--only GROUP` replaces that group's rows and keeps the others from `cases.csv`.)", "",
             "Generated by `benchmarks/bench_stress.py`; the fast cases are `tests/stress/` (`make test`).",
             "Property checked in every case: the run completes, or fails with a clear message naming the unit",
             "and the time; the MCAP log is read back and holds only finite numbers and one message per",
             "completed step (plus the initial one). `ok` = the property held (the detail says whether the runs",
             "completed or failed cleanly); `UNSOUND` = it did not (see the detail).", "",
             f"**{len(ROWS) - len(bad)} of {len(ROWS)} cases ok**" + (f", {len(bad)} UNSOUND." if bad else "."), "",
             "| group | case | status | wall [s] | detail |", "|---|---|---|---|---|"]
    lines += [f"| {r['group']} | {r['case']} | {r['status']} | {r['wall_s']} | {r['detail'].replace('|', '/')} |"
              for r in ROWS]
    lines += ["", "**Signals and crashes.** `signals`: SIGINT, SIGTERM and SIGHUP sent at random instants of",
              "`immersim run` (start-up, set-up and the run; two coupled oscillators, 100 s at 1 ms), rotating the log",
              "in the master's process, in a log-writer process, and a unit in a worker process: each try must end",
              "with exit 128 + signal, one stderr line, a log that reads back with CRC checks and holds exactly the",
              "completed steps it names (status `interrupted`), and no temporary folder or `/dev/shm` file left.",
              "`segfault`: a unit (tests/units/crasher) that segfaults or aborts in the master's process at a",
              "random time: exit 1, one line naming the unit and the simulated time, the log rebuilt by the",
              "supervising parent with exactly the completed steps. `supervision`: what that parent costs,",
              "campus_drive run by the CLI with it (A) and with `IMMERSIM_SUPERVISE=0` (B), interleaved; the loop",
              "time is the run's own figure (the journal copy of each step's records and the crumb stores are in",
              "it: A only has the journal, both have the two int64 stores before each doStep), the wall time adds",
              "the fork and the parent's wait. The machine is shared with other work (its load varies during a",
              "run): the ratios of interleaved medians are the figures to read, and the journal's cost is also",
              "measured in isolation.", ""]
    lines += ["", "Fault injection (NaN/inf forced into an input mid-run, SIGINT, truncated FMU files, a full disk",
              "through /dev/full, a 64 KiB tmpfs or RLIMIT_FSIZE) is covered by `tests/stress/test_faults.py`; the",
              "boundaries (a corpus of broken FMU archives, output targets that fail, a few signals at random",
              "instants, a crashing unit) by `tests/boundaries/`, both in `make test`."]
    (OUT / "README.md").write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer examples, 100 s long runs, meshes up to 26.4k")
    ap.add_argument("--only", nargs="*", default=None,
                    help="groups: random long meshes sigint signals segfault supervision")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.CRITICAL)
    groups = args.only or ["random", "long", "meshes", "sigint", "signals", "segfault", "supervision"]
    with tempfile.TemporaryDirectory(prefix="bench_stress_") as d:
        tmp = Path(d)
        if "random" in groups:
            random_cases(tmp, n=6 if args.quick else 25, stop=2.0 if args.quick else 5.0)
        if "long" in groups:
            long_cases(tmp, stop=100.0 if args.quick else 1000.0)
        if "meshes" in groups:
            mesh_cases(tmp, args.quick)
        if "sigint" in groups:
            sigint_cases(tmp, n=2 if args.quick else 5)
        if "signals" in groups:
            signal_cases(tmp, tries=5 if args.quick else 50)
        if "segfault" in groups:
            segfault_cases(tmp, tries=10)
        if "supervision" in groups:
            journal_cost(tmp)
            supervision_cases(tmp, pairs=3 if args.quick else 7)
    cmd = "python benchmarks/bench_stress.py" + (" --quick" if args.quick else "") + \
          (f" --only {' '.join(args.only)}" if args.only else "")
    write_report(args.quick, cmd, groups)
    print(f"wrote {OUT / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main() or 0)
