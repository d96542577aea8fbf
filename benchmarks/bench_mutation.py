"""Mutation score of the test suite over the declared mutants (``benchmarks/mutation/mutants.toml``).

Writes ``results/mutation/README.md`` (score, per-module table, every surviving, timed-out,
invalid or stale mutant) and ``results/mutation/mutants.csv`` (one row per mutant). The checkout
is never modified: see :mod:`benchmarks.mutation.runner`.

Usage: ``python benchmarks/bench_mutation.py [--quick] [--named] [--only ID ...] [--tests FILE ...]
[--prefix PATH] [--timeout S] [--no-write]``. A run of some mutants (``--only``, ``--prefix``,
``--quick``) replaces their rows in the last results and keeps the others, each row naming the
commit it was measured on. ``--named`` checks that each mutant of the first block fails the
test named for it, alone (``results/mutation/named.md``). ``--quick`` runs the mutants of the first block (the changes the
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
from common import ROOT, machine  # noqa: E402
import runner  # noqa: E402

OUT = ROOT / "results" / "mutation"
TARGET_SCORE, TARGET_COUNT = 0.95, 150
SCORED = ("killed", "timeout", "error", "survived")


FIELDS = ["id", "file", "status", "seconds", "detail", "commit", "original", "replacement", "why"]


def score(rows):
    c = Counter(r["status"] for r in rows)
    n = sum(c[s] for s in SCORED)
    dead = c["killed"] + c["timeout"] + c["error"]
    return dead, n, (dead / n if n else float("nan")), c


def module_of(path: str) -> str:
    return path[:-3] if path.endswith(".py") else path


def rows_of(outcomes, rev: str):
    return [dict(id=o.mutant.id, file=o.mutant.file, status=o.status, seconds=f"{o.seconds:.1f}", detail=o.detail,
                 commit=rev, original=o.mutant.original, replacement=o.mutant.replacement, why=o.mutant.why)
            for o in outcomes]


def merged(new_rows, mutants):
    """The rows of the last results (``mutants.csv``) with ``new_rows`` replacing theirs, in list
    order; mutants no longer declared are dropped, declared ones never run are left out."""
    old = {}
    if (OUT / "mutants.csv").exists():
        with open(OUT / "mutants.csv", newline="") as fh:
            old = {r["id"]: r for r in csv.DictReader(fh)}
    new = {r["id"]: r for r in new_rows}
    out = []
    for m in mutants:
        r = new.get(m.id) or old.get(m.id)
        if r is not None and (r["original"], r["replacement"], r["file"]) == (m.original, m.replacement, m.file):
            out.append(dict(r, why=m.why))   # the reason as declared now (its line number follows the file)
    return out


def older_than_their_file(rows):
    """Ids of the rows whose file changed between the commit they ran on and ``HEAD``."""
    import subprocess
    return [r["id"] for r in rows if subprocess.run(["git", "diff", "--quiet", r["commit"], "HEAD", "--", r["file"]],
                                                   cwd=ROOT, capture_output=True).returncode]


def write(rows, command: str, wall: float, equivalent=None, gaps=None) -> None:
    """``results/mutation/README.md`` and ``mutants.csv`` from ``rows``; ``equivalent`` maps the
    ids of mutants analysed as changing no output to the reason (scored both ways)."""
    equivalent = equivalent or {}
    OUT.mkdir(parents=True, exist_ok=True)
    with open(OUT / "mutants.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, FIELDS)
        w.writeheader()
        w.writerows(rows)
    dead, n, s, c = score(rows)
    eq = [r for r in rows if r["status"] == "survived" and r["id"] in equivalent]
    per = defaultdict(Counter)
    for r in rows:
        per[module_of(r["file"])][r["status"]] += 1
    modules = sorted(per)
    commits = Counter(r["commit"] for r in rows)
    lines = ["# Mutation testing", "",
             f"Command: `{command}` (part of `make bench`)  ",
             f"Commit of the tree under test: {', '.join(f'`{k}` ({v} mutants)' for k, v in commits.items())}  ",
             f"Machine: {machine()}  ",
             f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; "
             + (f"wall time of the last invocation {wall / 60:.0f} min, " if wall else "")
             + f"test time of all mutants {sum(float(r['seconds']) for r in rows) / 60:.0f} min",
             "",
             "Each declared mutant (`benchmarks/mutation/mutants.toml`: file, original line, replacement, why)",
             "is applied to a private copy of the committed tree and its declared test files run with",
             "`pytest -x` and a timeout. Killed = a test failed (or errored, or timed out); survived = every",
             "test passed. Stale (snippet no longer in the tree) and invalid (tests fail unmutated) mutants",
             "are listed, not scored.", "",
             "| target | measured | met |", "|---|---|---|",
             f"| mutation score >= {TARGET_SCORE:.0%} | {s:.1%} ({dead} of {n} killed) | "
             f"{'met' if s >= TARGET_SCORE else 'NOT met'} |",
             f"| >= {TARGET_COUNT} scored mutants | {n} | {'met' if n >= TARGET_COUNT else 'NOT met'} |",
             *([f"| (the same without the {len(eq)} survivors analysed as equivalent, below) | "
                f"{dead / (n - len(eq)):.1%} ({dead} of {n - len(eq)}) | "
                f"{'met' if dead / (n - len(eq)) >= TARGET_SCORE else 'NOT met'} |"] if eq else []),
             f"| every module of models/ and orchestrator/ mutated | {len(modules)} modules | see below |", "",
             "Outcomes: " + ", ".join(f"{k} {c[k]}" for k in ("killed", "timeout", "error", "survived", "invalid", "stale")
                                     if c[k]), "",
             "## Per module", "", "| module | mutants | killed | survived | not scored |", "|---|---|---|---|---|"]
    for mod in modules:
        k = per[mod]
        lines.append(f"| `{mod}` | {sum(k.values())} | {k['killed'] + k['timeout'] + k['error']} | {k['survived']} | "
                     f"{k['invalid'] + k['stale']} |")
    old = older_than_their_file(rows)
    lines += ["", "## Outcomes measured on an older version of their file", "",
              f"{len(old)} of {len(rows)} rows ran on a commit after which their file changed (the mutated line",
              "is still there; the outcome may differ now): " + (", ".join(old) if old else "none") + "."]
    rest = [r for r in rows if r["status"] != "killed"]
    lines += ["", "## Surviving, timed-out, erroring, invalid and stale mutants", ""]
    if not rest:
        lines.append("None.")
    else:
        lines += ["| id | file | status | change | why | detail |", "|---|---|---|---|---|---|"]
        for r in rest:
            detail = r["detail"] or (f"equivalent: {equivalent[r['id']]}" if r["id"] in equivalent else
                                     f"not covered: {(gaps or {})[r['id']]}" if r["id"] in (gaps or {}) else "")
            lines.append(f"| {r['id']} | `{r['file']}` | {r['status']} | `{r['original']}` -> `{r['replacement']}` | "
                         f"{r['why']} | {detail.replace('|', '/')} |")
    lines += ["", "Per-mutant outcomes: `mutants.csv` (id, file, status, seconds, first failing test, commit, change, why).",
              "The changes the suite once missed, each against the one test named for it: `named.md`.",
              "A partial run (`--only`, `--prefix`) replaces its mutants' rows; each row names the commit",
              "of the tree it ran on."]
    (OUT / "README.md").write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="only the first block (tag 'missed')")
    ap.add_argument("--only", nargs="*", default=None, help="mutant ids (results merged into the last ones)")
    ap.add_argument("--prefix", default=None, help="only mutants of files under this path (results merged)")
    ap.add_argument("--tests", nargs="*", default=None, help="test files replacing each mutant's own")
    ap.add_argument("--named", action="store_true",
                    help="each mutant of the first block against its named test alone (results/mutation/named.md)")
    ap.add_argument("--timeout", type=float, default=240.0, help="seconds per mutant's test run")
    ap.add_argument("--list", type=Path, default=HERE / "mutation" / "mutants.toml")
    ap.add_argument("--no-write", action="store_true", help="print the outcomes, write nothing to results/")
    ap.add_argument("--rewrite", action="store_true", help="run nothing: rewrite README.md from mutants.csv")
    args = ap.parse_args(argv)
    mutants, _ = runner.load(args.list)
    if args.rewrite:
        write(merged([], mutants), "python benchmarks/bench_mutation.py", 0.0,
              {m.id: m.equivalent for m in mutants if m.equivalent},
              {m.id: m.gap for m in mutants if m.gap})
        return 0
    if args.quick:
        mutants = [m for m in mutants if "missed" in m.tags]
    declared = list(mutants)
    if args.only:
        mutants = [m for m in mutants if m.id in args.only]
    if args.prefix:
        mutants = [m for m in mutants if m.file.startswith(args.prefix)]
    if args.tests:
        for m in mutants:
            m.tests = list(args.tests)
    if args.named:
        mutants = [m for m in mutants if m.named]
        for m in mutants:
            m.tests = [m.named]
    import subprocess
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    print(f"mutants: {len(mutants)}, tree: {rev}", flush=True)
    t0 = time.perf_counter()
    outcomes, baselines = runner.run(mutants, timeout=args.timeout, log=lambda s: print(s, flush=True), rev=rev)
    wall = time.perf_counter() - t0
    rows = rows_of(outcomes, rev)
    dead, n, s, c = score(rows)
    print(f"mutation score {s:.1%}: {dead} of {n} killed; {dict(c)}; {wall / 60:.1f} min")
    if args.named:
        lines = ["# Each once-missed change against the test named for it", "",
                 f"Command: `python benchmarks/bench_mutation.py --named`  ", f"Commit: `{rev}`  ",
                 f"Machine: {machine()}  ", f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}", "",
                 "Each mutant of the first block of `benchmarks/mutation/mutants.toml` applied alone, with only",
                 "its named test run (`pytest -x`): killed means that test alone fails on the change.", "",
                 "| mutant | change | named test | outcome | first failing case |", "|---|---|---|---|---|"]
        for o in outcomes:
            m = o.mutant
            print(f"{m.id}: {o.status} by {m.named}")
            lines.append(f"| {m.id} | {m.why} | `{m.named.replace('tests/', '')}` | {o.status} | "
                         f"`{o.detail.split('::')[-1]}` |")
        if not args.no_write:
            OUT.mkdir(parents=True, exist_ok=True)
            (OUT / "named.md").write_text("\n".join(lines) + "\n")
    if not args.no_write and not args.tests and not args.named:
        cmd = "python benchmarks/bench_mutation.py" + (" --quick" if args.quick else "")
        write(merged(rows, declared), cmd, wall, {m.id: m.equivalent for m in declared if m.equivalent},
              {m.id: m.gap for m in declared if m.gap})
        print(f"wrote {OUT / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
