"""Benchmark of the reference scene campus_drive: real-time factor with full logging, time per
unit and for the orchestrator, and the speed-up of lazy stepping on a mostly idle scene.

Usage::

    /tmp/venv/bin/python benchmarks/bench_campus_drive.py [--quick]

Writes ``results/scenarios/bench.md``. Target (issue 6): campus_drive at >= 100x real time with
full logging on this machine.
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, List

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, interleaved, median, stamp  # noqa: E402

from immersim.orchestrator.execution import Execution, RunResult  # noqa: E402

CAMPUS = ROOT / "scenarios" / "campus_drive.toml"
IDLE = ROOT / "scenarios" / "campus_idle.toml"
OUT = ROOT / "results" / "scenarios" / "bench.md"
TARGET_RTF = 100.0


def run(path: Path, overrides: Dict, log_to: Path | None) -> tuple:
    """One run; returns (RunResult, process CPU seconds of the loop + set-up, Execution)."""
    ex = Execution(path, log_to, overrides=overrides)
    c0 = time.process_time()
    res = ex.run()
    return res, time.process_time() - c0, ex


def unit_table(results: List[RunResult], cpu: List[float]) -> List[str]:
    """Median wall seconds per part of the loop and per step."""
    units = [k for k in results[0].timing if k.startswith("unit:")]
    steps = results[0].steps_done
    sim = (results[0].t_ns - results[0].start_ns) / 1e9
    rows = ["| part | wall s (median) | ms per step | share of loop |", "|---|---|---|---|"]
    loop = median([r.timing["loop"] for r in results])
    parts = {k[5:]: median([r.timing[k] for r in results]) for k in units}
    parts["logging (MCAP)"] = median([r.timing["logging"] for r in results])
    parts["master (orchestrator)"] = median([r.timing["loop"] - r.timing["logging"]
                                             - sum(r.timing[k] for k in units) for r in results])
    for name, s in parts.items():
        rows.append(f"| {name} | {s:.3f} | {1e3 * s / steps:.2f} | {100 * s / loop:.0f} % |")
    rows.append(f"| **loop** | **{loop:.3f}** | **{1e3 * loop / steps:.2f}** | 100 % |")
    rows.append("")
    rows.append(f"Simulated {sim:g} s in {steps} steps; loop wall time median {loop:.3f} s "
                f"(runs: {', '.join('%.2f' % r.timing['loop'] for r in results)} s); "
                f"process CPU time of the whole run (set-up + loop + close) median {median(cpu):.2f} s.")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat instead of three")
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    reps = 1 if args.quick else 3
    lines: List[str] = ["# Benchmark: campus_drive (issue 6)", "",
                        stamp("/tmp/venv/bin/python benchmarks/bench_campus_drive.py" + (" --quick" if args.quick else "")),
                        ""]
    with tempfile.TemporaryDirectory(prefix="bench_campus_") as d:
        tmp = Path(d)
        # 1. campus_drive, 20 s, full logging
        results, cpus = [], []
        for i in range(reps):
            res, cpu, _ = run(CAMPUS, {}, tmp / f"campus_{i}.mcap")
            results.append(res)
            cpus.append(cpu)
            print(res.timing_summary())
        loop = median([r.timing["loop"] for r in results])
        sim = (results[0].t_ns - results[0].start_ns) / 1e9
        rtf = sim / loop
        rtf_cpu = sim / median(cpus)
        size = (tmp / "campus_0.mcap").stat().st_size
        units = {k[5:]: median([r.timing[k] for r in results]) for k in results[0].timing if k.startswith("unit:")}
        slowest = max(units, key=units.get)
        steps = results[0].steps_done
        budget_ms = 1e3 * sim / steps / TARGET_RTF
        lines += ["## 1. campus_drive with full logging", "",
                  f"`scenarios/campus_drive.toml` as shipped ({sim:g} s, 3 players x 3 render nodes, 8 entities, "
                  f"collision fcl with 5 monitored pairs over 8 dynamic bodies and 7 tanks of 5.4k triangles, "
                  f"platform washout + computed torque + RK4), `[log] include = [\"*\"]` "
                  f"(every input and output of the three units, {size / 1e6:.1f} MB MCAP), {reps} run(s).", ""]
        lines += unit_table(results, cpus)
        verdict = "met" if rtf >= TARGET_RTF else "NOT met"
        lines += ["",
                  f"**Real-time factor: {rtf:.2f}x** (wall, median; {rtf_cpu:.2f}x on process CPU time). "
                  f"Target >= {TARGET_RTF:g}x: **{verdict}**. "
                  f"The target allows {budget_ms:.2f} ms of wall time per 33 ms step for everything; "
                  f"the slowest unit, `{slowest}`, alone takes {1e3 * units[slowest] / steps:.2f} ms per step "
                  f"({1e3 * units[slowest] / steps / budget_ms:.0f}x the whole budget). "
                  f"Orchestrator (master) and logging together take "
                  f"{1e3 * (loop - sum(units.values())) / steps:.3f} ms per step.", ""]

        # 2. where the collision unit's time goes: ccd off, and the idle-unit floor
        var = {"ccd off (no time of impact)": {"coll.ccd": False},
               "max_distance = 5 m (no exact distance for far pairs)": {"coll.max_distance": 5.0},
               "basis_point backend": {"coll.backend": "basis_point"}}
        lines += ["## 2. Collision unit variants (same scene, 20 s, full logging, 1 run each)", "",
                  "| variant | coll s | net s | plat s | loop s | real-time factor |", "|---|---|---|---|---|---|",
                  f"| as shipped (fcl, ccd on) | {units.get('coll', 0):.2f} | {units.get('net', 0):.2f} | "
                  f"{units.get('plat', 0):.2f} | {loop:.2f} | {rtf:.2f}x |"]
        for name, ov in var.items():
            res, _, _ = run(CAMPUS, ov, tmp / "var.mcap")
            t = res.timing
            lines.append(f"| {name} | {t['unit:coll']:.2f} | {t['unit:net']:.2f} | {t['unit:plat']:.2f} | "
                         f"{t['loop']:.2f} | {sim / t['loop']:.2f}x |")
            print(name, res.timing_summary())
        lines.append("")

        # 3. lazy vs eager on the mostly idle scene
        lines += ["## 3. Lazy vs eager stepping on a mostly idle scene (campus_idle)", "",
                  "`scenarios/campus_idle.toml`: the campus scene with no free entities, nobody driving for "
                  "7 s, then player 1 drives until 10 s. `simulation.lazy` true vs false (override), no log, "
                  f"interleaved runs, {reps + 2} repeats each, median loop wall time.", "",
                  "| scene | eager loop s | lazy loop s | speed-up | steps skipped (lazy) per unit |",
                  "|---|---|---|---|---|"]
        for label, stop in (("idle only (0 .. 6.9 s)", 6.9), ("idle 7 s + 3 s drive (0 .. 10 s)", 10.0)):
            skipped: Dict[str, int] = {}
            eager_units: Dict[str, List[float]] = {}

            def lazy_run(stop=stop, skipped=skipped) -> float:
                res, _, ex = run(IDLE, {"simulation.stop": stop, "simulation.lazy": True}, None)
                skipped.update({n: s.skipped_steps for n, s in ex.master.slots.items()})
                return res.timing["loop"]

            def eager_run(stop=stop, eager_units=eager_units) -> float:
                res, _, _ = run(IDLE, {"simulation.stop": stop, "simulation.lazy": False}, None)
                for k, v in res.timing.items():
                    if k.startswith("unit:"):
                        eager_units.setdefault(k[5:], []).append(v / res.steps_done)
                return res.timing["loop"]

            times = interleaved({"eager": eager_run, "lazy": lazy_run}, reps + 2)
            e, z = median(times["eager"]), median(times["lazy"])
            n_steps = round(stop / 0.033 + 0.4999)
            lines.append(f"| {label} | {e:.3f} | {z:.3f} | {e / z:.2f}x | "
                         f"{', '.join(f'{k} {v}/{n_steps}' for k, v in skipped.items())} |")
            print(label, "eager", times["eager"], "lazy", times["lazy"])
            if stop < 7.0:
                floor = ", ".join(f"{k} {1e3 * median(v):.2f} ms" for k, v in eager_units.items())
        lines += ["", f"Eager stepping of the idle scene (every unit at rest, so each step is only the FMI "
                  f"call and the unit's own at-rest shortcut) costs per step: {floor}. For coll and plat this is "
                  f"the per-call floor of a pythonfmu unit, already above the 0.33 ms budget of the whole step "
                  f"at 100x real time; the network keeps simulating its periodic traffic every frame at rest.",
                  "", "Results are identical to eager stepping except the network's per-step traffic counters "
                  "(`net.messages`, `net.bytes`), see `tests/scenarios/test_scenarios.py`.", ""]
    lines += ["## Reading", "", ANALYSIS]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


ANALYSIS = """\
* Wall times are from a 2-core machine shared with other engineers' jobs: the three repeats of
  section 1 differ by up to 2x, and the process CPU time is well below the wall time. Single runs
  (section 2) are indicative only.
* The target of 100x real time needs 0.33 ms of wall time per 33 ms macro step for the three
  units, the master and the MCAP log together. Each unit is a pythonfmu FMU, and every `doStep`
  goes through the FMI C layer and back into Python. The table shows how long each unit takes,
  and which one is the bottleneck.
* The collision unit with fcl tests every monitored pair in every step in which a body moved:
  the three avatar-vs-tank pairs, avatar 1 against four entity spheres, and conservative-advancement
  time of impact for every moved body (section 2 shows how much time CCD costs). The network's
  cost per frame does not depend on how much moves: it runs its discrete-event loop for every
  frame (frame sync, state records, heartbeats).
* Lazy stepping skips the FMI calls of units that report `at_rest`. Two things limit the speed-up
  on an idle scene. First, the units already skip their own work when at rest (collision: cached
  result; platform: skipped step), so eager stepping of an idle unit only pays the FMI call.
  Second, the network's catch-up step simulates every skipped frame (its periodic traffic goes on
  at rest), so skipping it saves calls, not work. `RunResult.timing` counts the final catch-up in
  `Master.finish()` as master time, not unit time, so for the idle-only scene the lazy run's
  "master" share is really the network's catch-up.
"""

if __name__ == "__main__":
    main()
