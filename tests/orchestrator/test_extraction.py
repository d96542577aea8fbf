"""The FMU extraction cache (orchestrator/extraction.py): one complete entry per FMU content,
linked by every run and process, checked before use, pruned only when nobody holds it; a run
logs the same bytes with it and without; ``immersim -v run`` reports each phase."""
from __future__ import annotations

import logging
import multiprocessing
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from .helpers import oscillator_scenario
from immersim.orchestrator import extraction
from immersim.orchestrator.fmu import FmuInstance, clear_caches, forget_python_code


@pytest.fixture
def cache(tmp_path, monkeypatch):
    root = tmp_path / "cache"
    monkeypatch.setenv("IMMERSIM_FMU_CACHE", str(root))
    clear_caches()
    yield root
    clear_caches()


def _variant(fmu: Path, dest: Path, tag: str) -> Path:
    """The same FMU with another archive comment: other bytes (another entry), same files."""
    dest.write_bytes(fmu.read_bytes())
    with zipfile.ZipFile(dest, "a") as z:
        z.comment = tag.encode()
    return dest


def _files_as_archived(entry: Path, fmu: Path) -> None:
    with zipfile.ZipFile(fmu) as z:
        for info in z.infolist():
            if not info.is_dir():
                assert (entry / info.filename).stat().st_size == info.file_size, info.filename


def test_runs_link_one_complete_entry_with_its_bytecode(test_fmus, cache, tmp_path):
    fmu = test_fmus["oscillator"]
    a = FmuInstance("a", fmu, tmp_path / "run1" / "a")
    b = FmuInstance("b", fmu, tmp_path / "run2" / "b")
    try:
        entry = cache / extraction.digest(fmu)
        assert os.path.islink(a.unzip_dir) and os.path.islink(b.unzip_dir)
        assert os.path.realpath(a.unzip_dir) == os.path.realpath(b.unzip_dir) == os.path.realpath(entry)
        _files_as_archived(entry, fmu)
        module = (entry / "resources" / "slavemodule.txt").read_text().strip()
        assert list((entry / "resources" / "__pycache__").glob(f"{module}.*.pyc"))
        assert not [p for p in cache.iterdir() if p.name.startswith(".")]   # no part left
        a.initialize(0, None, {"x0": 1.0})
        b.initialize(0, None, {"x0": -0.5})
        for k in range(30):
            a.do_step(k * 33_000_000, 33_000_000)
            b.do_step(k * 33_000_000, 33_000_000)
        w, t = np.sqrt(2.0), 30 * 0.033   # m = k = kc = 1, x_other = 0
        np.testing.assert_allclose(a.get_values(["x"])[0], np.cos(w * t), atol=1e-12)
        np.testing.assert_allclose(b.get_values(["x"])[0], -0.5 * np.cos(w * t), atol=1e-12)
    finally:
        a.terminate()
        b.terminate()
        forget_python_code(tmp_path / "run1")
        forget_python_code(tmp_path / "run2")


def test_a_damaged_entry_is_extracted_again(test_fmus, cache, tmp_path):
    fmu = test_fmus["oscillator"]
    FmuInstance("a", fmu, tmp_path / "run1" / "a").terminate()
    forget_python_code(tmp_path / "run1")
    clear_caches()   # as another process: the entry is checked at its next use
    entry = cache / extraction.digest(fmu)
    (entry / "modelDescription.xml").write_text("<cut")
    b = FmuInstance("b", fmu, tmp_path / "run2" / "b")
    try:
        assert os.path.realpath(b.unzip_dir) == os.path.realpath(entry)
        _files_as_archived(entry, fmu)
        b.initialize(0, None, {"x0": 1.0})
        b.do_step(0, 33_000_000)
    finally:
        b.terminate()
        forget_python_code(tmp_path / "run2")


def test_a_stored_model_description_is_used_and_a_damaged_one_read_again(test_fmus, cache, tmp_path,
                                                                         monkeypatch):
    from immersim.orchestrator import modeldesc

    fmu = test_fmus["oscillator"]
    first = modeldesc.read_model(fmu, "u")[1]   # no entry yet: nothing stored
    FmuInstance("a", fmu, tmp_path / "run1" / "a").terminate()
    forget_python_code(tmp_path / "run1")
    clear_caches()
    assert modeldesc.read_model(fmu, "u")[1] == first   # the entry exists now: stored
    stored = list((cache / extraction.digest(fmu)).glob(".immersim-model-*.pickle"))
    assert len(stored) == 1
    clear_caches()
    with monkeypatch.context() as m:
        m.setattr(modeldesc, "_read_model", lambda *a: pytest.fail("parsed again"))
        assert modeldesc.read_model(fmu, "u")[1] == first
    stored[0].write_bytes(stored[0].read_bytes()[:100])   # cut: parsed again, stored again
    clear_caches()
    assert modeldesc.read_model(fmu, "u")[1] == first
    clear_caches()
    with monkeypatch.context() as m:
        m.setattr(modeldesc, "_read_model", lambda *a: pytest.fail("parsed again"))
        assert modeldesc.read_model(fmu, "u")[1] == first


def _extract_at_once(fmu: str, root: str, barrier, results) -> None:
    barrier.wait()
    results.put(extraction.cached(Path(fmu), Path(root), "u"))


def test_processes_extracting_one_fmu_at_once_share_one_entry(test_fmus, tmp_path):
    fmu, root = test_fmus["oscillator"], tmp_path / "cache"
    ctx = multiprocessing.get_context("fork")
    barrier, results = ctx.Barrier(4), ctx.Queue()
    procs = [ctx.Process(target=_extract_at_once, args=(str(fmu), str(root), barrier, results)) for _ in range(4)]
    for p in procs:
        p.start()
    got = [results.get(timeout=120) for _ in procs]
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    entry = root / extraction.digest(fmu)
    assert got == [str(entry)] * 4
    assert sorted(p.name for p in root.iterdir()) == [entry.name]
    _files_as_archived(entry, fmu)


def _hold_until(fmu: str, root: str, held, release) -> None:
    extraction.cached(Path(fmu), Path(root), "u")
    held.set()
    release.wait(120)


def test_pruning_keeps_the_entries_in_use(test_fmus, tmp_path, monkeypatch):
    monkeypatch.setattr(extraction, "KEEP", 1)
    clear_caches()
    root = tmp_path / "cache"
    a, b, c = (_variant(test_fmus["oscillator"], tmp_path / f"{t}.fmu", t) for t in "abc")
    ctx = multiprocessing.get_context("fork")
    held, release = ctx.Event(), ctx.Event()
    holder = ctx.Process(target=_hold_until, args=(str(a), str(root), held, release))
    holder.start()
    try:
        assert held.wait(120)
        extraction.cached(b, root, "u")   # a is older, beyond KEEP, but held by the other process
        assert (root / extraction.digest(a)).is_dir()
    finally:
        release.set()
        holder.join(60)
    extraction.cached(c, root, "u")   # now a goes; b stays (this process holds it)
    assert sorted(p.name for p in root.iterdir()) == sorted([extraction.digest(b), extraction.digest(c)])
    clear_caches()


def _messages(path: Path) -> list:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return [(ch.topic, m.log_time, m.data) for _, ch, m in make_reader(fh).iter_messages()]


def test_a_run_logs_the_same_with_and_without_the_cache(test_fmus, tmp_path, monkeypatch, caplog):
    from immersim.orchestrator.cli import main

    scenario = oscillator_scenario(tmp_path, test_fmus["oscillator"], stop=1.0)
    logs = {}
    for mode in ("0", str(tmp_path / "cache"), str(tmp_path / "cache")):   # off, cold, warm
        monkeypatch.setenv("IMMERSIM_FMU_CACHE", mode)
        clear_caches()
        logs[len(logs)] = out = tmp_path / f"run{len(logs)}.mcap"
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="immersim"):
            assert main(["-v", "run", str(scenario), "-q", "-o", str(out)]) == 0
        line = [r.getMessage() for r in caplog.records if r.getMessage().startswith("phases (s): ")]
        assert len(line) == 1
        names = [p.rsplit(" ", 1)[0] for p in line[0][len("phases (s): "):].split(";")[0].split(", ")]
        assert names[names.index("scenario parse"):] == ["scenario parse", "scenario check", "extract m1", "instantiate m1", "extract m2",
                             "instantiate m2", "initialise m1", "initialise m2", "master and log set-up",
                             "first step", "stepping", "log close"], names
    clear_caches()
    assert _messages(logs[0]) == _messages(logs[1]) == _messages(logs[2])
    assert len(_messages(logs[0])) > 100


def test_the_program_runs_exit_handlers_and_keeps_its_output(test_fmus, tmp_path):
    """``immersim -v run`` ends the process itself (no interpreter teardown) after the exit
    handlers, with its output, its log, its exit status and its phases from the interpreter's
    start."""
    scenario = oscillator_scenario(tmp_path, test_fmus["oscillator"], stop=0.5)
    marker, out = tmp_path / "atexit_ran", tmp_path / "run.mcap"
    program = ("import atexit, sys\n"
               f"atexit.register(lambda: open({str(marker)!r}, 'w').write('ran'))\n"
               "from immersim.orchestrator.cli import main\n"
               f"sys.argv = ['immersim', '-v', 'run', {str(scenario)!r}, '-q', '-o', {str(out)!r}]\n"
               "sys.exit(main())\n")
    res = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "IMMERSIM_FMU_CACHE": str(tmp_path / "cache")})
    assert res.returncode == 0, res.stderr
    assert all(line.startswith("INFO ") for line in res.stderr.splitlines()), res.stderr
    phases = [line for line in res.stderr.splitlines() if line.startswith("INFO immersim: phases (s): ")]
    assert len(phases) == 1 and phases[0].split(": ", 1)[1].startswith("phases (s): interpreter "), phases
    assert ", imports " in phases[0] and phases[0].endswith(" s to the end of the first step")
    assert "osc.toml: 50 steps to t = 0.5 s" in res.stdout
    assert marker.read_text() == "ran"
    assert len([m for m in _messages(out) if not m[0].endswith("/parameters")]) == 2 * 51   # steps 0..50


def test_the_time_to_the_first_step_sums_the_phases_up_to_and_with_it(monkeypatch):
    """``phases.summary``: each phase's time, and the sum of those up to and including the first
    step (all of them when no step was made)."""
    from immersim.orchestrator import phases

    marks = [("interpreter", 0.25), ("imports", 0.5), ("first step", 0.125), ("stepping", 4.0), ("log close", 1.0)]
    monkeypatch.setattr(phases, "_marks", marks)
    assert phases.summary() == ("phases (s): interpreter 0.250, imports 0.500, first step 0.125, stepping 4.000, "
                                "log close 1.000; 0.875 s to the end of the first step")
    monkeypatch.setattr(phases, "_marks", marks[:2])
    assert phases.summary().endswith("; 0.750 s to the end of the first step")
