"""Start-up of a short run: ``immersim run scenarios/campus_drive.toml`` as a whole command, and
each phase up to the first step, side by side with another commit.

Each side is a copy of a source tree (this checkout's tracked files as they are on disk; each
``--base REV``, default :data:`BASE`: REV's files from ``git archive``) imported through its own
``immersim`` package folder on ``PYTHONPATH`` (so each side runs its own orchestrator; its units
are built from its own sources into its own ``build/fmus``) and runs its own copy of the
scenario. Each copy gets its Python bytecode compiled once, as an installed package has it
(``--source``: none, every run compiles the sources, as a checkout run under
``PYTHONDONTWRITEBYTECODE=1``); no run writes bytecode. Two measurements, interleaved side by side:

* the whole command (the program ``immersim run SCENARIO -q -o LOG``, as a user runs it): wall
  seconds from spawn to exit;
* its phases, by a harness process that times the same functions on every side
  (interpreter start, imports, scenario parse and check, per unit extraction, instantiation
  and initialisation, the set-up to step 0, the first step, the other steps, the log's close,
  the exit).

Sides of this checkout: ``cache`` (the extraction, mesh and checked-scenario caches warm, as
every run after the first), ``no scenario cache`` (``IMMERSIM_SCENARIO_CACHE=0``: each run checks
the scenario with the schema, as the first run of a new or edited scenario does), ``no mesh
cache`` (``IMMERSIM_MESH_CACHE=0``: each run builds the scene's meshes with trimesh), ``no
cache`` (all three off: each run extracts and compiles anew as well).

    python benchmarks/bench_startup.py [--base REV ...] [--repeats N] [--quick] [--source] [--no-ablation] [--no-checkout]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Dict, List

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, median, stamp  # noqa: E402

SCENARIO = "scenarios/campus_drive.toml"
OUT = ROOT / "results" / "startup"
#: the commit the start-up figures are compared with by default (before the start-up work)
BASE = "1998c63"
#: the folders of a tree that make up the ``immersim`` package
PACKAGE = ("api", "orchestrator", "models", "fmus", "scenarios")

#: the entry point of the ``immersim`` program (what pip writes into the venv's bin/)
PROGRAM = "import sys\nfrom immersim.orchestrator.cli import main\nsys.exit(main())\n"

#: times the phases of one run of a tree's CLI; prints {phase: seconds} as JSON (last line)
HARNESS = r'''
import json, os, sys, time
spawned = float(os.environ["BENCH_SPAWNED"])
marks = [("interpreter", time.perf_counter())]
def mark(name):
    marks.append((name, time.perf_counter()))
from immersim.orchestrator import cli, api, execution, fmu
mark("imports")
E, F = execution.Execution, fmu.FmuInstance
def after(owner, attr, label):
    fn = getattr(owner, attr)
    def wrapped(*a, **k):
        out = fn(*a, **k)
        mark(label(a) if callable(label) else label)
        return out
    setattr(owner, attr, wrapped)
after(execution, "load_scenario", "scenario parse")
after(execution, "check_system", "scenario check")
after(F, "_extract", lambda a: "extract " + a[0].name)
after(F, "_instantiate", lambda a: "instantiate " + a[0].name)
after(F, "initialize", lambda a: "initialise " + a[0].name)
if hasattr(E, "_add_unit_view"):
    after(E, "_add_unit_view", "3D view of the units")
observe = E._observe
def observed(self, master, k, t_ns):
    observe(self, master, k, t_ns)
    if k == 0:
        mark("set-up to step 0")
    elif k == 1:
        mark("first step")
E._observe = observed
close_log, closed = E._close_log, []
def close_first(self, result):
    if not closed:
        closed.append(1)
        mark("stepping")
    return close_log(self, result)
E._close_log = close_first
code = cli.main(sys.argv[1:])
mark("log close")
out, last = {}, spawned
for name, t in marks:
    out[name] = out.get(name, 0.0) + t - last
    last = t
print("\n" + json.dumps({"phases": out, "end": last, "code": code}))
if hasattr(cli, "_exit_now"):   # the program's own exit, where it has one
    cli._exit_now(code)
'''


class Side:
    """A source tree run through its own ``immersim`` package folder."""

    def __init__(self, name: str, tree: Path, work: Path, env: Dict[str, str]) -> None:
        self.name, self.tree = name, tree
        pkg = work / f"pkg_{len(list(work.glob('pkg_*')))}"
        (pkg / "immersim").mkdir(parents=True)
        (pkg / "immersim" / "__init__.py").symlink_to(tree / "api" / "__init__.py")
        for top in ("orchestrator", "models", "fmus", "scenarios"):
            (pkg / "immersim" / top).symlink_to(tree / top)
        self.env = {**os.environ, "PYTHONPATH": str(pkg), "PYTHONDONTWRITEBYTECODE": "1", **env}
        self.env.pop("IMMERSIM_BUILD_DIR", None)
        self.program = work / "immersim"
        self.program.write_text(PROGRAM)
        self.harness = work / "harness.py"
        self.harness.write_text(HARNESS)
        self.args = ["run", str(tree / SCENARIO), "-q", "-o", str(work / f"{name.replace(' ', '_')}.mcap")]
        self.work = work

    def check(self) -> None:
        """Build the units (not timed) and make sure the side imports its own tree."""
        where = subprocess.run([sys.executable, "-c", "import immersim.orchestrator.fmu as m; print(m.__file__)"],
                               env=self.env, cwd=self.work, capture_output=True, text=True, check=True).stdout
        if not Path(where.strip()).resolve().is_relative_to(self.tree.resolve()):
            raise SystemExit(f"side {self.name} imports {where.strip()}, not its tree {self.tree}")
        self.whole()

    def whole(self) -> tuple:
        """Wall seconds and CPU seconds (user + system, the process and its children)."""
        cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run([sys.executable, str(self.program)] + self.args, env=self.env, cwd=self.work, check=True,
                       stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        return wall, after.ru_utime - cpu.ru_utime + after.ru_stime - cpu.ru_stime

    def imports(self) -> List[tuple]:
        """``(module, cumulative seconds)`` of the imports made at top level in one run of the
        program (``python -X importtime``), largest first; a unit's packed package as
        ``immersim_<build>``."""
        env = {**self.env, "IMMERSIM_SUPERVISE": "0"}
        err = subprocess.run([sys.executable, "-X", "importtime", str(self.program)] + self.args, env=env,
                             cwd=self.work, check=True, capture_output=True, text=True).stderr
        out = []
        for line in err.splitlines():
            parts = line.split("|")
            if len(parts) == 3 and parts[0].startswith("import time:") and parts[2].startswith(" ") \
                    and not parts[2].startswith("  ") and parts[1].strip().isdigit():
                out.append((re.sub(r"_[0-9a-f]{12}\b", "_<build>", parts[2].strip()),
                            int(parts[1]) / 1e6))
        return sorted(out, key=lambda r: -r[1])

    def phases(self) -> Dict[str, float]:
        env = {**self.env, "IMMERSIM_SUPERVISE": "0"}
        t = time.perf_counter()
        env["BENCH_SPAWNED"] = repr(t)
        out = subprocess.run([sys.executable, str(self.harness)] + self.args, env=env, cwd=self.work, check=True,
                             capture_output=True, text=True).stdout
        end = time.perf_counter()
        rec = json.loads(out.strip().splitlines()[-1])
        phases = rec["phases"]
        phases["exit"] = end - rec["end"]
        return phases


def copy_tree(rev: str | None, dest: Path, bytecode: bool) -> Path:
    """The package folders of ``rev`` (``git archive``; None: this checkout's tracked files as they
    are on disk) copied to ``dest``, their bytecode compiled when ``bytecode``."""
    dest.mkdir(parents=True)
    if rev is None:
        files = subprocess.run(["git", "ls-files", "-z", "--", *PACKAGE], cwd=ROOT, check=True,
                               capture_output=True).stdout.decode().split("\0")
        for f in filter(None, files):
            if (ROOT / f).is_file():
                (dest / f).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(ROOT / f, dest / f)
        shutil.copy2(ROOT / "pyproject.toml", dest / "pyproject.toml")
    else:
        archive = subprocess.run(["git", "archive", rev, "pyproject.toml", *PACKAGE], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    if bytecode:
        subprocess.run([sys.executable, "-m", "compileall", "-q", *(str(dest / p) for p in PACKAGE)], check=True,
                       stdout=subprocess.DEVNULL, env={k: v for k, v in os.environ.items()
                                                       if k != "PYTHONDONTWRITEBYTECODE"})
    return dest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", action="append", default=[],
                    help=f"git revision to compare with (default {BASE}); may be given more than once")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="3 repeats")
    ap.add_argument("--source", action="store_true", help="no bytecode: every run compiles the sources")
    ap.add_argument("--no-ablation", action="store_true", help="only the bases and this checkout's cache side")
    ap.add_argument("--no-checkout", action="store_true", help="only the bases (not this checkout's files)")
    args = ap.parse_args()
    args.base = args.base or [BASE]
    repeats = 3 if args.quick else args.repeats
    work = Path(tempfile.mkdtemp(prefix="immersim_bench_startup_"))
    try:
        sides: List[Side] = []
        cache, meshes, checked = work / "fmu_cache", work / "mesh_cache", work / "scenario_cache"
        for k, rev in enumerate(args.base):
            name = subprocess.run(["git", "rev-parse", "--short", rev], cwd=ROOT, check=True, capture_output=True,
                                  text=True).stdout.strip()
            sides.append(Side(name, copy_tree(rev, work / f"base_{k}", not args.source), work, {}))
        tree = None if args.no_checkout else copy_tree(None, work / "checkout", not args.source)
        if tree is not None:
            sides.append(Side("cache", tree, work, {"IMMERSIM_FMU_CACHE": str(cache),
                                                    "IMMERSIM_MESH_CACHE": str(meshes),
                                                    "IMMERSIM_SCENARIO_CACHE": str(checked)}))
        if tree is not None and not args.no_ablation:
            sides.append(Side("no scenario cache", tree, work, {"IMMERSIM_FMU_CACHE": str(cache),
                                                                "IMMERSIM_MESH_CACHE": str(meshes),
                                                                "IMMERSIM_SCENARIO_CACHE": "0"}))
            sides.append(Side("no mesh cache", tree, work, {"IMMERSIM_FMU_CACHE": str(cache),
                                                            "IMMERSIM_MESH_CACHE": "0",
                                                            "IMMERSIM_SCENARIO_CACHE": str(checked)}))
            sides.append(Side("no cache", tree, work, {"IMMERSIM_FMU_CACHE": "0", "IMMERSIM_MESH_CACHE": "0",
                                                       "IMMERSIM_SCENARIO_CACHE": "0"}))
        for s in sides:
            s.check()
        whole: Dict[str, List[tuple]] = {s.name: [] for s in sides}
        phases: Dict[str, List[Dict[str, float]]] = {s.name: [] for s in sides}
        for _ in range(repeats):
            for s in sides:
                whole[s.name].append(s.whole())
            for s in sides:
                phases[s.name].append(s.phases())
        write(sides, whole, phases, args, repeats, sides[-1 if args.no_checkout else len(args.base)].imports())
    finally:
        shutil.rmtree(work, ignore_errors=True)


def write(sides: List[Side], whole, phases, args, repeats: int, imports: List[tuple]) -> None:
    names = [s.name for s in sides]
    ref = names[0]
    lines = ["# Start-up of a short run", "",
             stamp(f"python benchmarks/bench_startup.py{''.join(' --base ' + b for b in args.base)}"
                   f"{' --quick' if args.quick else ''}{' --source' if args.source else ''}"
                   f"{' --no-ablation' if args.no_ablation else ''}{' --no-checkout' if args.no_checkout else ''}"),
             "Bytecode: " + ("none (every run compiles the sources, as a checkout run under "
                             "`PYTHONDONTWRITEBYTECODE=1`)." if args.source else
                             "compiled once per side (as an installed package has it); no run writes any."), "",
             f"Whole command `immersim run {SCENARIO} -q -o LOG` (20 s simulated, 607 steps), wall seconds, "
             f"median of {repeats} interleaved runs per side, and the CPU seconds they used (user + system, less "
             f"sensitive to other load on the machine); ratios to `{ref}`:", "",
             "| side | median (s) | min | max | ratio | CPU median (s) | CPU ratio |", "|---|---|---|---|---|---|---|"]
    for n in names:
        w, c = [r[0] for r in whole[n]], [r[1] for r in whole[n]]
        w0, c0 = median([r[0] for r in whole[ref]]), median([r[1] for r in whole[ref]])
        lines.append(f"| {n} | {median(w):.3f} | {min(w):.3f} | {max(w):.3f} | {median(w) / w0:.2f} "
                     f"| {median(c):.3f} | {median(c) / c0:.2f} |")
    keys: List[str] = []   # every side's phases, each after the phase it follows on its side
    for n in names:
        for rec in phases[n]:
            prev = None
            for k in rec:
                if k not in keys:
                    keys.insert(keys.index(prev) + 1 if prev is not None else 0, k)
                prev = k
    lines += ["", f"Phases of one run (harness timing the same functions on each side, no supervising "
                  f"parent), wall seconds, median of {repeats}:", "",
              "| phase | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    med = {n: {k: median([r.get(k, 0.0) for r in phases[n]]) for k in keys} for n in names}
    for k in keys:
        lines.append(f"| {k} | " + " | ".join(f"{med[n][k]:.3f}" for n in names) + " |")
    first = keys.index("first step") + 1 if "first step" in keys else len(keys)
    lines.append("| **to the end of the first step** | " + " | ".join(
        f"**{median([sum(r.get(k, 0.0) for k in keys[:first]) for r in phases[n]]):.3f}**" for n in names) + " |")
    lines.append("| **whole run** | " + " | ".join(
        f"**{median([sum(r.values()) for r in phases[n]]):.3f}**" for n in names) + " |")
    lines += ["", "The largest imports made directly by the program or a unit's code (`python -X importtime`, one run "
                  f"of `{names[-1] if args.no_checkout else 'cache'}`, cumulative seconds; without bytecode, "
                  "compiling is part of it):", "", "| module | s |", "|---|---|"]
    lines += [f"| `{m}` | {t:.3f} |" for m, t in imports[:15]]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / ("bench_source.md" if args.source else "bench.md")).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
