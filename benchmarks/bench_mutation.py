"""Mutation score of the test suite over the declared mutants (``benchmarks/mutation/mutants.toml``).

Writes ``results/mutation/README.md`` (score, per-module table, every surviving, timed-out,
invalid or stale mutant) and ``results/mutation/mutants.csv`` (one row per mutant). The checkout
is never modified: see :mod:`benchmarks.mutation.runner`.

Usage: ``python benchmarks/bench_mutation.py [--quick] [--named] [--only ID ...] [--tests FILE ...]
[--timeout S] [--no-write]``. ``--named`` checks that each mutant of the first block fails the
test named for it, alone. ``--quick`` runs the mutants of the first block (the changes the
suite once missed) only; ``--tests`` replaces every mutant's test files (to check that one
test file alone kills a mutant).
"""
from __future__ import annotations

import argparse
import csv
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "mutation"))
from common import ROOT, commit, machine  # noqa: E402
import runner  # noqa: E402

OUT = ROOT / "results" / "mutation"
TARGET_SCORE, TARGET_COUNT = 0.95, 150
SCORED = ("killed", "timeout", "error", "survived")


def score(outcomes):
    c = Counter(o.status for o in outcomes)
    n = sum(c[s] for s in SCORED)
    dead = c["killed"] + c["timeout"] + c["error"]
    return dead, n, (dead / n if n else float("nan")), c


def module_of(path: str) -> str:
    return path[:-3] if path.endswith(".py") else path


def write(outcomes, baselines, command: str, wall: float, quick: bool) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    with open(OUT / "mutants.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "file", "status", "seconds", "detail", "original", "replacement", "why"])
        for o in outcomes:
            m = o.mutant
            w.writerow([m.id, m.file, o.status, f"{o.seconds:.1f}", o.detail, m.original, m.replacement, m.why])
    dead, n, s, c = score(outcomes)
    per = defaultdict(Counter)
    for o in outcomes:
        per[module_of(o.mutant.file)][o.status] += 1
    modules = sorted(per)
    lines = ["# Mutation testing", "",
             f"Command: `{command}` (part of `make bench`)  ", f"Commit: `{commit()}`  ", f"Machine: {machine()}  ",
             f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; wall time {wall / 60:.0f} min", "",
             "Each declared mutant (`benchmarks/mutation/mutants.toml`: file, original line, replacement, why)",
             "is applied to a private copy of the committed tree and its declared test files run with",
             "`pytest -x` and a timeout. Killed = a test failed (or errored, or timed out); survived = every",
             "test passed. Stale (snippet no longer in the tree) and invalid (tests fail unmutated) mutants",
             "are listed, not scored.", "",
             "| target | measured | met |", "|---|---|---|",
             f"| mutation score >= {TARGET_SCORE:.0%} | {s:.1%} ({dead} of {n} killed) | "
             f"{'met' if s >= TARGET_SCORE else 'NOT met'} |",
             f"| >= {TARGET_COUNT} scored mutants | {n} | {'met' if n >= TARGET_COUNT else 'NOT met'}"
             f"{' (quick run: first block only)' if quick else ''} |",
             f"| every module of models/ and orchestrator/ mutated | {len(modules)} modules | see below |", "",
             "Outcomes: " + ", ".join(f"{k} {c[k]}" for k in ("killed", "timeout", "error", "survived", "invalid", "stale")
                                     if c[k]), "",
             "## Per module", "", "| module | mutants | killed | survived | other |", "|---|---|---|---|---|"]
    for mod in modules:
        k = per[mod]
        lines.append(f"| `{mod}` | {sum(k.values())} | {k['killed'] + k['timeout'] + k['error']} | {k['survived']} | "
                     f"{k['invalid'] + k['stale']} |")
    rest = [o for o in outcomes if o.status not in ("killed",)]
    lines += ["", "## Surviving, timed-out, erroring, invalid and stale mutants", ""]
    if not rest:
        lines.append("None.")
    else:
        lines += ["| id | file | status | change | why | detail |", "|---|---|---|---|---|---|"]
        for o in rest:
            m = o.mutant
            lines.append(f"| {m.id} | `{m.file}` | {o.status} | `{m.original}` -> `{m.replacement}` | {m.why} | "
                         f"{o.detail.replace('|', '/')} |".replace("`` ", "` ` "))
    lines += ["", "## Test sets (unmutated baseline)", "", "| tests | baseline | seconds |", "|---|---|---|"]
    for key, (res, dt, detail) in baselines.items():
        lines.append(f"| {' '.join(k.replace('tests/', '') for k in key)} | {res} {detail} | {dt:.0f} |")
    lines += ["", "Per-mutant outcomes: `mutants.csv` (id, file, status, seconds, first failing test, change, why)."]
    (OUT / "README.md").write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="only the first block (tag 'missed')")
    ap.add_argument("--only", nargs="*", default=None, help="mutant ids")
    ap.add_argument("--tests", nargs="*", default=None, help="test files replacing each mutant's own")
    ap.add_argument("--named", action="store_true",
                    help="each mutant of the first block against its named test alone (nothing written)")
    ap.add_argument("--timeout", type=float, default=240.0, help="seconds per mutant's test run")
    ap.add_argument("--list", type=Path, default=HERE / "mutation" / "mutants.toml")
    ap.add_argument("--no-write", action="store_true", help="print the outcomes, write nothing to results/")
    args = ap.parse_args(argv)
    mutants, _ = runner.load(args.list)
    if args.quick:
        mutants = [m for m in mutants if "missed" in m.tags]
    if args.only:
        mutants = [m for m in mutants if m.id in args.only]
    if args.tests:
        for m in mutants:
            m.tests = list(args.tests)
    if args.named:
        mutants = [m for m in mutants if m.named]
        for m in mutants:
            m.tests = [m.named]
    t0 = time.perf_counter()
    outcomes, baselines = runner.run(mutants, timeout=args.timeout, log=lambda s: print(s, flush=True))
    wall = time.perf_counter() - t0
    dead, n, s, c = score(outcomes)
    print(f"mutation score {s:.1%}: {dead} of {n} killed; {dict(c)}; {wall / 60:.1f} min")
    if args.named:
        for o in outcomes:
            print(f"{o.mutant.id}: {o.status} by {o.mutant.named}")
    if not args.no_write and not args.only and not args.tests and not args.named:
        cmd = "python benchmarks/bench_mutation.py" + (" --quick" if args.quick else "")
        write(outcomes, baselines, cmd, wall, args.quick)
        print(f"wrote {OUT / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
