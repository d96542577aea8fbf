"""A process that loaded pythonfmu FMUs exits without touching freed memory.

pythonfmu 0.7.0's binary releases its Python state a second time in ``_dl_fini`` after the
state's static destructor freed it (see ``orchestrator/pythonfmu_exit.py``); with the heap
reused, glibc aborts the finished process ("corrupted double-linked list"). The valgrind test
shows the use-after-free without our exit handler and its absence with it.
"""
from __future__ import annotations

import math
import shutil
import subprocess
import sys
import tempfile
import textwrap
import zipfile
from pathlib import Path

import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from immersim.orchestrator.pythonfmu_exit import release_pythonfmu_states

#: loads two extracted copies of an FMU (argv[1]) through plain FMPy, steps and frees each,
#: then leaves through the interpreter's normal exit; argv[2] == "fix" installs our handler
SCRIPT = textwrap.dedent("""
    import sys, tempfile, zipfile
    from fmpy import read_model_description
    from fmpy.fmi2 import FMU2Slave
    if sys.argv[2] == "fix":
        from immersim.orchestrator.pythonfmu_exit import install
        install()
    md = read_model_description(sys.argv[1])
    for k in range(2):
        d = tempfile.mkdtemp()
        zipfile.ZipFile(sys.argv[1]).extractall(d)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                        instanceName=f"i{k}")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        fmu.doStep(0.0, 0.033)
        fmu.terminate()
        fmu.freeInstance()
""")


def _vr(fmu: Path, name: str) -> int:
    return next(v.valueReference for v in read_model_description(str(fmu)).modelVariables if v.name == name)


def _load(fmu: Path, name: str):
    """An initialised instance of the oscillator test unit released from x0 = 1 m."""
    md = read_model_description(str(fmu))
    folder = tempfile.mkdtemp(prefix="exit_")
    zipfile.ZipFile(fmu).extractall(folder)
    inst = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                     instanceName=name)
    inst.instantiate()
    inst.setupExperiment(startTime=0.0)
    inst.setReal([_vr(fmu, "x0")], [1.0])
    inst.enterInitializationMode()
    inst.exitInitializationMode()
    return inst, folder


def test_release_resets_every_loaded_copy_and_instances_keep_working(test_fmus):
    """Each extracted copy is found by the dynamic linker's list (also after FMPy deleted its
    folder); an instance alive across the reset still steps, and a new one instantiates."""
    fmu = test_fmus["oscillator"]
    (a, folder_a), (b, folder_b) = _load(fmu, "a"), _load(fmu, "b")
    try:
        shutil.rmtree(folder_b)        # a loaded copy whose file is gone
        reset = release_pythonfmu_states()
        assert any(p.startswith(folder_a) for p in reset), reset
        assert any(p.startswith(folder_b) for p in reset), reset
        assert release_pythonfmu_states() == reset   # idempotent
        x_exact = math.cos(math.sqrt(2.0) * 0.033)   # k = kc = m = 1, x_other = 0: w = sqrt(2)
        a.doStep(0.0, 0.033)           # the instance holds its own reference to the state
        assert a.getReal([_vr(fmu, "x")])[0] == pytest.approx(x_exact, rel=1e-12)
        c, folder_c = _load(fmu, "c")  # after a reset, a new instance makes a new state
        c.doStep(0.0, 0.033)
        assert c.getReal([_vr(fmu, "x")])[0] == pytest.approx(x_exact, rel=1e-12)
        c.terminate()
        c.freeInstance()
        shutil.rmtree(folder_c, ignore_errors=True)
    finally:
        for inst in (a, b):
            inst.terminate()
            inst.freeInstance()
        shutil.rmtree(folder_a, ignore_errors=True)


def _valgrind(fmu: Path, mode: str, tmp: Path) -> subprocess.Popen:
    script = tmp / "exit_script.py"
    script.write_text(SCRIPT)
    return subprocess.Popen(["valgrind", "--error-limit=no", "-q", sys.executable, str(script), str(fmu), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.skipif(shutil.which("valgrind") is None, reason="needs valgrind")
def test_exit_reads_no_freed_memory_under_valgrind(test_fmus, tmp_path):
    """With the handler the FMU binary makes no invalid access at exit; without it (the
    control), valgrind sees ``finalizePythonInterpreter`` read the freed state, in the pythonfmu
    releases known to have the defect (up to 0.7.0, the newest when this was written)."""
    from importlib.metadata import version

    fmu = test_fmus["oscillator"]
    runs = {mode: _valgrind(fmu, mode, tmp_path) for mode in ("plain", "fix")}
    out = {mode: p.communicate(timeout=300) for mode, p in runs.items()}
    for mode, p in runs.items():
        assert p.returncode == 0, (mode, out[mode][1][-3000:])
    plain, fixed = out["plain"][1], out["fix"][1]
    assert "finalizePythonInterpreter" not in fixed and "oscillator.so" not in fixed, fixed[-3000:]
    if tuple(int(x) for x in version("pythonfmu").split(".")[:3] if x.isdigit()) <= (0, 7, 0):
        assert "Invalid read" in plain and "finalizePythonInterpreter" in plain, plain[-3000:]
