"""Native platform FMU (``platform-native``) against the Python build, side by side.

* FMPy: per-step time of one instance over campus_drive's recorded platform inputs
  (``tests/platform/data/campus_drive_platform_inputs.csv``, 607 steps), both builds in one run,
  alternating rounds; the median over steps of (a) the whole master step (setReal of the 19
  inputs, fmi2DoStep, getReal/getBoolean of the outputs, FMPy's ctypes wrappers) and (b)
  fmi2DoStep alone; outputs compared for equality on the way.
* Our orchestrator: the demo scenario with each build (``fmu = "platform"`` / ``"platform-native"``),
  the platform unit's time per step from the run's timing.
* campus_drive with each build: wall time of the loop and the platform unit's time.

``--record`` rewrites the recorded inputs from the campus_drive run with the Python build.
Writes ``results/platform/native.md``.

Usage: ``python benchmarks/bench_native.py [--quick] [--record]``
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, stamp  # noqa: E402

from immersim.fmus.platform.platform_fmu import FLAG_OUTPUTS, PACKED_INPUTS, PACKED_REAL_OUTPUTS  # noqa: E402

INPUTS = ROOT / "tests" / "platform" / "data" / "campus_drive_platform_inputs.csv"
OUT = ROOT / "results" / "platform" / "native.md"
CAMPUS_PARAMS = {"washout.k_t": 0.2, "washout.k_r": 0.2}
H = 0.033


def fmpy_steps(path: Path, U: np.ndarray):
    """(per-step seconds of the whole master step, of fmi2DoStep alone, outputs (n, 29)) with FMPy."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="bench")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    for k, v in CAMPUS_PARAMS.items():
        fmu.setReal([vr[k]], [v])
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    ivr, ovr = [vr[n] for n in PACKED_INPUTS], [vr[n] for n in PACKED_REAL_OUTPUTS]
    bvr = [vr[n] for n, _ in FLAG_OUTPUTS]
    whole, step, out = [], [], []
    t, clock = 0.0, time.perf_counter
    for u in U.tolist():
        t0 = clock()
        fmu.setReal(ivr, u)
        t1 = clock()
        fmu.doStep(t, H)
        t2 = clock()
        y = fmu.getReal(ovr) + fmu.getBoolean(bvr)
        t3 = clock()
        whole.append(t3 - t0)
        step.append(t2 - t1)
        out.append(y)
        t += H
    fmu.terminate()
    fmu.freeInstance()
    return whole, step, np.array(out, float)


TIMER_C = r"""
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "fmi2Functions.h"
static void logger(fmi2ComponentEnvironment e, fmi2String n, fmi2Status s, fmi2String c, fmi2String m, ...) {}
static int cmp(const void* a, const void* b) { double x = *(const double*) a, y = *(const double*) b; return (x > y) - (x < y); }
int main(int argc, char** argv) {  /* library, GUID, inputs file, 19 input vrs, k_t vr, k_r vr; prints the median */
  fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
  void* lib = dlopen(argv[1], RTLD_NOW);
  fmi2InstantiateTYPE* inst = (fmi2InstantiateTYPE*) dlsym(lib, "fmi2Instantiate");
  fmi2SetupExperimentTYPE* setup = (fmi2SetupExperimentTYPE*) dlsym(lib, "fmi2SetupExperiment");
  fmi2EnterInitializationModeTYPE* enter = (fmi2EnterInitializationModeTYPE*) dlsym(lib, "fmi2EnterInitializationMode");
  fmi2ExitInitializationModeTYPE* leave = (fmi2ExitInitializationModeTYPE*) dlsym(lib, "fmi2ExitInitializationMode");
  fmi2SetRealTYPE* set = (fmi2SetRealTYPE*) dlsym(lib, "fmi2SetReal");
  fmi2DoStepTYPE* step = (fmi2DoStepTYPE*) dlsym(lib, "fmi2DoStep");
  fmi2ValueReference in[19], par[2];
  double u[19], gains[2] = {0.2, 0.2}, t = 0.0, *dt = malloc(sizeof(double) * 100000);
  int k, n = 0;
  struct timespec a, b;
  FILE* f = fopen(argv[3], "r");
  fmi2Component c = inst("timer", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
  for (k = 0; k < 19; ++k) in[k] = (fmi2ValueReference) atoi(argv[4 + k]);
  par[0] = (fmi2ValueReference) atoi(argv[23]); par[1] = (fmi2ValueReference) atoi(argv[24]);
  setup(c, fmi2False, 0, 0.0, fmi2False, 0); set(c, par, 2, gains); enter(c); leave(c);
  while (fscanf(f, "%lf", &u[0]) == 1) {
    for (k = 1; k < 19; ++k) if (fscanf(f, "%lf", &u[k]) != 1) return 4;
    set(c, in, 19, u);
    clock_gettime(CLOCK_MONOTONIC, &a);
    if (step(c, t, 0.033, fmi2True)) return 5;
    clock_gettime(CLOCK_MONOTONIC, &b);
    dt[n++] = (b.tv_sec - a.tv_sec) * 1e6 + (b.tv_nsec - a.tv_nsec) * 1e-3;
    t += 0.033;
  }
  qsort(dt, n, sizeof(double), cmp);
  printf("%.3f\n", dt[n / 2]);
  return 0;
}
"""


def c_host_timer(path: Path, U: np.ndarray, tmp: Path):
    """A callable giving the median fmi2DoStep time (us) of the native FMU stepped over ``U`` by a C
    program (no Python in the process), compiled once into ``tmp``."""
    import subprocess

    from fmpy import extract, read_model_description

    from immersim.orchestrator.native_build import fmi_headers

    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    folder = Path(extract(str(path), unzipdir=str(tmp / "fmu")))
    (tmp / "timer.c").write_text(TIMER_C)
    subprocess.run(["gcc", "-O2", f"-I{fmi_headers()}", str(tmp / "timer.c"), "-o", str(tmp / "timer"), "-ldl"],
                   check=True)
    np.savetxt(tmp / "inputs.txt", U, fmt="%.17g")
    args = [str(tmp / "timer"), str(folder / "binaries" / "linux64" / "platform_native.so"), md.guid,
            str(tmp / "inputs.txt")] + [str(vr[n]) for n in PACKED_INPUTS] + [str(vr[n]) for n in CAMPUS_PARAMS]
    return lambda: float(subprocess.run(args, capture_output=True, text=True, check=True).stdout)


def run(scenario_text: str, folder: Path, name: str):
    """Run a scenario text in this process; returns (loop s, platform unit s, steps) from the run's timing."""
    from immersim.orchestrator.execution import run_scenario

    src = folder / f"{name}.toml"
    src.write_text(scenario_text)
    res = run_scenario(src, folder / f"{name}.mcap")
    unit = sum(v for k, v in res.timing.items() if k.startswith("unit:") and "plat" in k)
    return res.timing.get("loop", float("nan")), unit, res.steps_done


def campus_cli(src: Path, out: Path):
    """(wall s, loop s, platform unit s, steps) of ``immersim run`` in a fresh process, from its summary line."""
    import re
    import subprocess

    t0 = time.perf_counter()
    proc = subprocess.run([str(Path(sys.executable).with_name("immersim")), "run", str(src), "-o", str(out), "-q"],
                          capture_output=True, text=True, check=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    steps = int(re.search(r": (\d+) steps to", proc.stdout).group(1))
    loop = float(re.search(r"loop ([\d.e+-]+) s", proc.stdout).group(1))
    plat = float(re.search(r"plat ([\d.e+-]+) s", proc.stdout).group(1))
    return wall, loop, plat, steps


def record_inputs(mcap: Path) -> None:
    """Write the platform inputs of a campus_drive log (unit ``plat``), one row per step."""
    from immersim.orchestrator.mcapio import read_series

    s = read_series(mcap, ["plat.*"])
    U = np.stack([s[f"plat.{n}"][1] for n in PACKED_INPUTS], axis=1)[1:]
    np.savetxt(INPUTS, U, fmt="%.17g", delimiter=",", header=",".join(PACKED_INPUTS), comments="")
    print(f"recorded {len(U)} steps of platform inputs -> {INPUTS}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 rounds instead of 5, no campus_drive runs")
    ap.add_argument("--record", action="store_true", help="rewrite the recorded campus_drive platform inputs")
    args = ap.parse_args()
    from immersim.orchestrator.build import build_all

    fmus = dict(zip(("python", "native"), build_all(["platform", "platform-native"])))
    U = np.loadtxt(INPUTS, delimiter=",", skiprows=1)
    rounds = 2 if args.quick else 5
    whole = {b: [] for b in fmus}
    step = {b: [] for b in fmus}
    outs, host = {}, []
    with tempfile.TemporaryDirectory(prefix="bench_native_host_") as tmp:
        timer = c_host_timer(fmus["native"], U, Path(tmp))
        for _ in range(rounds):  # alternate the builds: both see the same machine load
            for b, path in fmus.items():
                w, s, outs[b] = fmpy_steps(path, U)
                whole[b] += w
                step[b] += s
            host.append(timer())
    equal = bool(np.array_equal(outs["native"], outs["python"]))
    host_us = statistics.median(host)
    med = {b: (statistics.median(whole[b]) * 1e6, statistics.median(step[b]) * 1e6) for b in fmus}

    rows_orch, rows_campus = [], []
    with tempfile.TemporaryDirectory(prefix="bench_native_") as tmp:
        tmp = Path(tmp)
        demo = (ROOT / "scenarios" / "demo.toml").read_text()
        for r in range(rounds):
            for b, fmu in (("python", "platform"), ("native", "platform-native")):
                loop, unit, n = run(demo.replace('fmu = "platform"', f'fmu = "{fmu}"'), tmp, f"demo_{b}_{r}")
                rows_orch.append((b, loop / n * 1e6, unit / n * 1e6))
        if not args.quick or args.record:
            # (one [[connections]] table per signal and the units whole: the shipped system, tests/scenarios)
            campus = (ROOT / "tests" / "scenarios" / "flat" / "campus_drive.toml").read_text()
            for b, fmu in (("python", "platform"), ("native", "platform-native")):
                src = tmp / f"campus_{b}.toml"
                src.write_text(campus.replace('fmu = "platform"', f'fmu = "{fmu}"'))
                rows_campus.append((b, *campus_cli(src, tmp / f"campus_{b}.mcap")))
                if b == "python" and args.record:
                    record_inputs(tmp / f"campus_{b}.mcap")

    def orch(b, i):
        return statistics.median(r[i] for r in rows_orch if r[0] == b)

    ratio_whole, ratio_step = med["python"][0] / med["native"][0], med["python"][1] / med["native"][1]
    cmd = "python benchmarks/bench_native.py" + (" --quick" if args.quick else "")
    L = ["# Native platform FMU vs the Python build", "", stamp(cmd), "",
         "## Under FMPy (one instance, campus_drive's recorded platform inputs, 607 steps)", "",
         f"{rounds} alternating rounds per build; medians over all steps. Outputs of the two builds "
         f"bit-identical: **{equal}**.", "",
         "| build | whole step (setReal + fmi2DoStep + getReal/getBoolean), us | fmi2DoStep alone, us |",
         "|---|---|---|"]
    L += [f"| {b} | {med[b][0]:.1f} | {med[b][1]:.1f} |" for b in fmus]
    L += [f"| ratio python / native | {ratio_whole:.2f}x | {ratio_step:.2f}x |", "",
          f"The native fmi2DoStep called from a C program (no Python in the process, same inputs, run in each "
          f"round): "
          f"**{host_us:.1f} us** median; the Python build's fmi2DoStep under FMPy is {med['python'][1] / host_us:.1f}x "
          "that.", "",
          "## Under the immersim orchestrator (demo scenario, 243 steps, platform only)", "",
          "| build | loop per step, us | platform unit per step, us |", "|---|---|---|"]
    L += [f"| {b} | {orch(b, 1):.1f} | {orch(b, 2):.1f} |" for b in fmus]
    L += [f"| ratio python / native | {orch('python', 1) / orch('native', 1):.2f}x | "
          f"{orch('python', 2) / orch('native', 2):.2f}x |", ""]
    if rows_campus:
        L += ["## campus_drive (20 s, 607 steps; network in a worker process, collision, platform)", "",
              "`immersim run` in a fresh process per build.", "",
              "| build | run wall time, s | loop, s | platform unit, s | platform per step, us |", "|---|---|---|---|---|"]
        L += [f"| {b} | {wall:.2f} | {loop:.2f} | {unit:.3f} | {unit / n * 1e6:.1f} |" for b, wall, loop, unit, n in rows_campus]
        L.append("")
    target = "met" if ratio_whole >= 10 else "NOT met"
    L += ["## Targets", "",
          f"- Native per-step time >= 10x lower than the Python build under FMPy: **{target}** — "
          f"{ratio_whole:.2f}x on the whole master step, {ratio_step:.2f}x on fmi2DoStep alone. Both builds run "
          "the same compiled C macro step (the Python build calls it through pythonfmu, the wrapper and ctypes): "
          f"the Python layer adds {med['python'][1] - med['native'][1]:.1f} us to a fmi2DoStep whose C arithmetic "
          f"(2 RK4 substeps of the computed-torque loop, washout, IK) takes {med['native'][1]:.1f} us natively, and "
          "FMPy's own Python wrappers of setReal/getReal cost both builds alike; 10x would need the Python layer "
          "to cost 9x the arithmetic.",
          f"- Bit-for-bit equal (<= 1e-12 relative) on the three input traces: {'met' if equal else 'NOT met'} here "
          "for campus_drive's recorded inputs; demo and platform_tracking in `tests/platform/test_native_fmu.py` "
          "(scenario swap: identical logs).", ""]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text("\n".join(L))
    print("\n".join(L))


if __name__ == "__main__":
    main()
