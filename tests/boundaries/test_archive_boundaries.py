"""FMU archives that cannot run here are refused at load: exit 2, one line naming the unit, the
file and what is wrong, nothing run and no log written. Corrupted copies of our pythonfmu
units and of the Reference FMUs (FMI 2.0 and 3.0), made by tests/boundaries/archives.py."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

import archives
from immersim.orchestrator.cli import main

REFERENCE = Path(__file__).resolve().parents[1] / "conformance" / "reference-fmus"


def _reference_fmus():
    """The vendored Reference FMUs (FMI 2.0 and 3.0 Dahlquist)."""
    return {f"{v} Dahlquist": REFERENCE / v / "Dahlquist.fmu" for v in ("fmi2", "fmi3")
            if (REFERENCE / v / "Dahlquist.fmu").exists()}


def _run(capsys, scenario: Path, out: Path):
    code = main(["run", str(scenario), "-o", str(out), "-q"])
    err = capsys.readouterr().err
    return code, [ln for ln in err.splitlines() if ln.strip()]


def _scenario(tmp: Path, fmu: Path) -> Path:
    path = tmp / "bad.toml"
    path.write_text(f'[simulation]\nstop = 0.1\n\n[[units]]\nname = "u"\nfmu = "{fmu}"\n')
    return path


def _cases():
    yield from ((("crasher", name) + case) for name, case in {**archives.CASES, **archives.PYTHONFMU_CASES}.items())
    for label in _reference_fmus():
        yield from (((label, name) + case) for name, case in archives.CASES.items())


@pytest.mark.parametrize("source, case, edit, pattern", list(_cases()), ids=lambda v: v if isinstance(v, str) else "")
def test_archive_refused_at_load(test_fmus, tmp_path, capsys, source, case, edit, pattern):
    src = test_fmus["crasher"] if source == "crasher" else _reference_fmus()[source]
    bad = archives.corrupt(src, tmp_path / "bad.fmu", edit)
    out = tmp_path / "run.mcap"
    code, lines = _run(capsys, _scenario(tmp_path, bad), out)
    assert code == 2, lines
    assert len(lines) == 1, lines
    assert lines[0].startswith("immersim: error: unit u: "), lines[0]
    assert "bad.fmu" in lines[0]
    assert re.search(pattern, lines[0]), (pattern, lines[0])
    assert not out.exists()


@pytest.mark.parametrize("keep", [0.0, 0.3, 0.9])
def test_cut_short_archive(test_fmus, tmp_path, capsys, keep):
    bad = archives.truncated(test_fmus["crasher"], tmp_path / "bad.fmu", keep)
    code, lines = _run(capsys, _scenario(tmp_path, bad), tmp_path / "run.mcap")
    assert code == 2 and len(lines) == 1, lines
    assert "unit u" in lines[0] and "bad.fmu" in lines[0]


def test_reference_fmus_are_vendored():
    """The control of the Reference FMU cases: both FMI versions are there to corrupt."""
    assert {"fmi2 Dahlquist", "fmi3 Dahlquist"} <= set(_reference_fmus())
