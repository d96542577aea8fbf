"""``make bench``: run every ``benchmarks/bench_*.py`` script and rewrite ``results/``.

Each script runs as a subprocess with its own command line (``--quick`` when it offers it and
this runner is in quick mode), one after the other (the machine has 2 cores; the timings in
the scripts must not compete). A script that is missing or fails does not stop the others;
``results/bench_runs.md`` records, for this invocation, the machine, the commit, and per
script its command, exit status and wall time. Exit status: 0 when every script succeeded.

Usage: ``python benchmarks/run_all.py [--quick] [--only NAME ...] [--skip NAME ...] [--dry-run]``
(NAME is the script name without ``bench_`` and ``.py``, e.g. ``platform``).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path
from typing import Dict, List

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, commit, machine  # noqa: E402

HERE = Path(__file__).resolve().parent
#: benchmarks the issues ask for; a missing one is reported, not silently skipped
EXPECTED = ("orchestrator", "platform", "collision", "network", "campus_drive", "cosim_accuracy", "stress", "native",
            "mutation", "sweep", "analysis", "contact")
#: quick-mode arguments of scripts without a ``--quick`` flag
QUICK_ARGS: Dict[str, List[str]] = {"orchestrator": ["--steps", "2000", "--repeats", "3"]}


def discover() -> Dict[str, Path]:
    return {p.stem[len("bench_"):]: p for p in sorted(HERE.glob("bench_*.py"))}


def command(name: str, path: Path, quick: bool) -> List[str]:
    cmd = [sys.executable, str(path)]
    if not quick:
        return cmd
    if name in QUICK_ARGS:
        return cmd + QUICK_ARGS[name]
    try:
        helptext = subprocess.run(cmd + ["--help"], capture_output=True, text=True, timeout=120, cwd=ROOT).stdout
    except subprocess.TimeoutExpired:
        helptext = ""
    return cmd + (["--quick"] if "--quick" in helptext else [])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="each script in its quick mode")
    ap.add_argument("--only", nargs="*", default=None, help="run only these benchmarks")
    ap.add_argument("--skip", nargs="*", default=[], help="do not run these benchmarks")
    ap.add_argument("--dry-run", action="store_true", help="print the commands, run and write nothing")
    args = ap.parse_args(argv)
    found = discover()
    rows = []
    for name in EXPECTED:
        if name not in found and (args.only is None or name in args.only):
            print(f"run_all: benchmarks/bench_{name}.py is missing: its results/ folder is not rewritten",
                  file=sys.stderr)
            rows.append((name, "-", "missing", 0.0))
    names = [n for n in found if (args.only is None or n in args.only) and n not in args.skip]
    for n in args.only or []:
        if n not in found and n not in EXPECTED:
            print(f"run_all: no benchmarks/bench_{n}.py (have: {', '.join(found)})", file=sys.stderr)
            rows.append((n, "-", "missing", 0.0))
    failed = 0
    for name in names:
        cmd = command(name, found[name], args.quick)
        shown = "python " + " ".join(str(Path(c).relative_to(ROOT)) if c.startswith(str(ROOT)) else c
                                     for c in cmd[1:])
        print(f"run_all: {shown}", flush=True)
        if args.dry_run:
            continue
        t0 = time.perf_counter()
        rc = subprocess.run(cmd, cwd=ROOT).returncode
        dt = time.perf_counter() - t0
        status = "ok" if rc == 0 else f"FAILED (exit {rc})"
        failed += rc != 0
        print(f"run_all: {name}: {status} in {dt:.0f} s", flush=True)
        rows.append((name, f"`{shown}`", status, dt))
    if args.dry_run:
        return 0
    lines = ["# Benchmark runs", "",
             f"Runner: `python benchmarks/run_all.py{' --quick' if args.quick else ''}` (`make bench`)  ",
             f"Commit: `{commit()}`  ", f"Machine: {machine()}  ",
             f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", "",
             "| benchmark | command | status | wall [s] |", "|---|---|---|---|"]
    lines += [f"| {n} | {c} | {s} | {d:.0f} |" for n, c, s, d in rows]
    out = ROOT / "results" / "bench_runs.md"
    out.parent.mkdir(exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    print(f"run_all: wrote {out}")
    missing = sum(1 for r in rows if r[2] == "missing")
    return 1 if failed or missing else 0


if __name__ == "__main__":
    sys.exit(main())
