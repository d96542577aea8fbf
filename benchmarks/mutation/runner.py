"""Mutation testing over a declared list of mutants (``mutants.toml``), in a private copy of the tree.

Each mutant replaces one snippet (``original``, which must occur exactly once in its file) by
``replacement``. The runner never edits the checkout: it unpacks the committed tree
(``git archive HEAD``) into a temporary folder, makes ``immersim.models`` / ``.orchestrator`` /
``.fmus`` resolve to that copy (a package ``immersim`` of symbolic links, first on
``PYTHONPATH``, ahead of the editable install), then, mutant by mutant, writes the mutated
file, runs the mutant's tests (``pytest -x`` with a timeout) in the copy and restores the file.
Each mutant's tests get a fresh FMU extraction cache (``IMMERSIM_FMU_CACHE``), never the user's.

A mutant is *killed* when a test fails, errors or times out (a timeout is listed as such),
*survived* when its tests pass. Before the mutants, every test file used runs once on the
unmutated copy: a mutant whose test set holds a test failing there is *invalid*; a mutant whose snippet
is not found exactly once in the copy is *stale* (neither is scored, both are listed).

Tests per mutant: the ``tests`` key of the mutant, else the longest prefix of its file in
``[tests]`` of ``mutants.toml``.
"""
from __future__ import annotations

import csv
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Dict, List, Optional, Tuple

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
TOPS = ("models", "orchestrator", "fmus", "scenarios")


@dataclass
class Mutant:
    """One declared mutant: ``file`` (relative to the checkout), snippet, replacement, reason."""

    id: str
    file: str
    original: str
    replacement: str
    why: str
    tests: List[str] = field(default_factory=list)
    tags: List[str] = field(default_factory=list)
    named: str = ""        # the test written to catch this change (first block)
    equivalent: str = ""   # why no output can change (a performance-only bound), when analysed so
    gap: str = ""          # a survivor analysed as a real gap no test covers yet (what would tell)


@dataclass
class Outcome:
    mutant: Mutant
    status: str            # killed | survived | timeout | error | invalid | stale
    seconds: float
    detail: str = ""       # the first failing test, or the error line


def load(path: Path = HERE / "mutants.toml") -> Tuple[List[Mutant], Dict[str, List[str]]]:
    """The declared mutants and the ``[tests]`` map (path prefix -> test files)."""
    data = tomllib.loads(path.read_text())
    tests = {k: list(v) for k, v in data.get("tests", {}).items()}
    out, seen = [], set()
    for i, m in enumerate(data.get("mutant", [])):
        mid = m.get("id") or f"m{i + 1:03d}"
        if mid in seen:
            raise ValueError(f"{path.name}: mutant id {mid!r} declared twice")
        seen.add(mid)
        mu = Mutant(mid, m["file"], m["original"], m["replacement"], m["why"], list(m.get("tests", [])),
                    list(m.get("tags", [])), m.get("named", ""), m.get("equivalent", ""), m.get("gap", ""))
        if not mu.tests:
            keys = [k for k in tests if mu.file.startswith(k)]
            if not keys:
                raise ValueError(f"{path.name}: mutant {mid} ({mu.file}): no [tests] entry covers this file")
            mu.tests = tests[max(keys, key=len)]
        out.append(mu)
    return out, tests


def check(mutants: List[Mutant], root: Path = ROOT) -> List[str]:
    """Problems of the list against the tree at ``root``: a snippet missing, not unique, or a no-op."""
    problems = []
    for m in mutants:
        src = (root / m.file).read_text() if (root / m.file).exists() else None
        if src is None:
            problems.append(f"{m.id}: no file {m.file}")
            continue
        n = src.count(m.original)
        if n != 1:
            problems.append(f"{m.id}: {m.file}: the original snippet occurs {n} times (must be once)")
        if m.original == m.replacement:
            problems.append(f"{m.id}: replacement equals the original")
    return problems


def make_copy(dest: Path, rev: str = "HEAD") -> Path:
    """Unpack ``rev`` of the checkout into ``dest/tree`` and the import shim into ``dest/shim``:
    ``immersim`` is the copy's ``api/`` (or an empty package) with ``models``, ``orchestrator``,
    ``fmus`` and ``scenarios`` linked into it, as setup.py maps them. Returns the ``PYTHONPATH``
    entry that makes ``immersim.*`` the copy."""
    tree = dest / "tree"
    tree.mkdir(parents=True)
    blob = subprocess.run(["git", "archive", "--format=tar", rev], cwd=ROOT, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(blob)) as tf:
        tf.extractall(tree)
    shim = dest / "shim"
    shim.mkdir()
    api = tree / "api"   # the package ``immersim`` itself, when the tree has one (setup.py's package_dir)
    if (api / "__init__.py").exists():
        (shim / "immersim").symlink_to(api, target_is_directory=True)
        pkg = api
    else:
        pkg = shim / "immersim"
        pkg.mkdir()
        (pkg / "__init__.py").write_text('"""The copy under mutation test (see benchmarks/mutation/runner.py)."""\n')
    for top in TOPS:
        if (tree / top).is_dir() and not (pkg / top).exists():
            (pkg / top).symlink_to(tree / top, target_is_directory=True)
    return dest / "shim"


def _drop_bytecode(path: Path) -> None:
    cache = path.parent / "__pycache__"
    if cache.is_dir():
        for pyc in cache.glob(f"{path.stem}.*.pyc"):
            pyc.unlink()


_FAILED = re.compile(r"^(FAILED|ERROR) (\S+)", re.M)


def run_tests(tree: Path, env: dict, tests: List[str], timeout: float, stop: bool = True):
    """``pytest -x`` over ``tests`` in the copy: (passed | failed | timeout | error, seconds, detail);
    with ``stop=False`` no ``-x`` and the detail is the list of every failing test."""
    cmd = [sys.executable, "-m", "pytest", *(["-x"] if stop else []), "-q", "-p", "no:cacheprovider", "-W", "ignore",
           f"--timeout={int(min(timeout, 600))}", *tests]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, timeout=timeout + 30)
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - t0, f"no result within {timeout:.0f} s"
    dt = time.perf_counter() - t0
    out = p.stdout + p.stderr
    if p.returncode == 0:
        return "passed", dt, ""
    if "Timeout" in out and "+++++ Timeout" in out:
        return "timeout", dt, f"a test exceeded {timeout:.0f} s"
    m = _FAILED.search(out)
    if not stop:
        return ("failed" if p.returncode == 1 else "error"), dt, [x.group(2) for x in _FAILED.finditer(out)]
    if p.returncode == 1 and m:
        return "failed", dt, m.group(2)
    last = [line for line in out.strip().splitlines() if line.strip()][-1:] or ["(no output)"]
    return "error", dt, (m.group(2) if m else last[0])[:200]


def run(mutants: List[Mutant], timeout: float = 300.0, keep: Optional[Path] = None, log=print,
        rev: str = "HEAD") -> Tuple[List[Outcome], Dict[tuple, Tuple[str, float, str]]]:
    """Baseline every test set, then every mutant; returns the outcomes and the baselines."""
    work = Path(tempfile.mkdtemp(prefix="immersim_mutation_")) if keep is None else keep
    try:
        shim = make_copy(work, rev)
        tree = work / "tree"
        stale = {p.split(":", 1)[0]: p for p in check(mutants, tree)}
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(shim), str(tree)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
        env["IMMERSIM_BUILD_DIR"] = str(work / "build")
        # a private FMU extraction cache (it also stores each FMU's read model description): the
        # user's would hide a mutant of the model-description reader and could keep its output
        env["IMMERSIM_FMU_CACHE"] = str(work / "fmu_cache" / "baseline")
        env.pop("PYTEST_ADDOPTS", None)
        probe = subprocess.run([sys.executable, "-c", "import immersim.models as m; print(m.__file__)"],
                               cwd=tree, env=env, capture_output=True, text=True)
        if str(shim) not in probe.stdout:
            raise RuntimeError(f"the copy does not shadow the installed immersim: {probe.stdout}{probe.stderr}")
        # one unmutated run of every test file any mutant uses; a set with a failing test is invalid
        files, deselect = set(), set()
        for m in mutants:
            if m.id in stale:
                continue
            for i, t in enumerate(m.tests):
                if i and m.tests[i - 1] == "--deselect":
                    deselect.add(t)
                elif t.startswith("tests/"):
                    files.add(t)
        files = sorted(files) + [x for d in sorted(deselect) for x in ("--deselect", d)]
        res, dt, failing = run_tests(tree, env, files, timeout * 4, stop=False)
        log(f"baseline of {len(files) - 2 * len(deselect)} test files: {res} in {dt:.0f} s {' '.join(failing)}")
        if res == "failed" and failing:   # a test failing once under load: run it again, alone
            again = run_tests(tree, env, list(failing), timeout * 2, stop=False)
            flaky = [f for f in failing if f not in again[2]] if again[0] in ("passed", "failed") else []
            failing = [f for f in failing if f not in flaky]
            res = "failed" if failing else "passed"
            log(f"baseline: passed when run again (flaky): {' '.join(flaky) or 'none'}")
        baselines = {}
        for key in sorted({tuple(m.tests) for m in mutants if m.id not in stale}):
            bad = [f for f in failing if f.split("::")[0] in key]
            baselines[key] = ("failed", dt, " ".join(bad)) if bad or res in ("timeout", "error") else ("passed", dt, "")
        outcomes = []
        for k, m in enumerate(mutants, 1):
            if m.id in stale:
                outcomes.append(Outcome(m, "stale", 0.0, stale[m.id]))
                log(f"[{k}/{len(mutants)}] {m.id} stale: {stale[m.id]}")
                continue
            base = baselines[tuple(m.tests)]
            if base[0] != "passed":
                outcomes.append(Outcome(m, "invalid", 0.0, f"tests fail unmutated: {base[2]}"))
                log(f"[{k}/{len(mutants)}] {m.id} invalid")
                continue
            path = tree / m.file
            src = path.read_text()
            path.write_text(src.replace(m.original, m.replacement, 1))
            _drop_bytecode(path)
            cache = work / "fmu_cache" / m.id   # fresh per mutant: nothing a mutant stored outlives it
            try:
                res, dt, detail = run_tests(tree, dict(env, IMMERSIM_FMU_CACHE=str(cache)), m.tests, timeout)
            finally:
                path.write_text(src)
                _drop_bytecode(path)
                shutil.rmtree(cache, ignore_errors=True)
            status = {"passed": "survived", "failed": "killed"}.get(res, res)
            outcomes.append(Outcome(m, status, dt, detail))
            log(f"[{k}/{len(mutants)}] {m.id} {m.file}: {status} in {dt:.0f} s {detail}")
        return outcomes, baselines
    finally:
        if keep is None:
            shutil.rmtree(work, ignore_errors=True)
