"""Injected faults: a unit erroring mid-run (a NaN forced into an input), SIGINT, corrupted
FMU files and a full disk. Each must end with a clear message, a non-zero exit and -- where
the disk allows -- a readable log of every completed step.
"""
from __future__ import annotations

import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

from immersim.orchestrator.errors import FmuLoadError, ImmersimError
from immersim.orchestrator.execution import RunFailed, run_scenario

from stresslib import assert_sound, check_log, run_checked, write_scenario

CLI = [sys.executable, "-m", "immersim.orchestrator.cli"]


def _platform_run(stop: float = 1.0, faults=()):
    return {"simulation": {"stop": stop},
            "units": [{"name": "p", "fmu": "platform"}],
            "inputs": [{"target": "p.cue.f_x", "kind": "sine", "amplitude": 2.0, "frequency": 0.5}],
            "faults": list(faults)}


# -- a unit returning an error mid-run -------------------------------------------------------------

FAULTS = {
    "platform": ({"units": [{"name": "u", "fmu": "platform"}]}, "u.cue.f_y"),
    "network": ({"units": [{"name": "u", "fmu": "network", "parameters": {"players": 2}}]}, "u.avatar[2].steer"),
    "collision": ({"units": [{"name": "u", "fmu": "collision",
                              "parameters": {"scene": "tanks:n=2,tris=400,spacing=8;box:name=b,dynamic=1"}}]},
                  "u.body[1].x"),
}


@pytest.mark.parametrize("unit, value", [("platform", float("nan")), ("platform", float("inf")),
                                         ("network", float("nan")), ("collision", float("-inf"))])
def test_forced_nonfinite_input_stops_the_run_with_a_clear_message(unit, value, tmp_path):
    base, target = FAULTS[unit]
    sc = dict(base, simulation={"stop": 1.0}, faults=[{"target": target, "at": 0.5, "value": value}])
    out = run_checked(write_scenario(sc, tmp_path / "f.toml"), tmp_path / "f.mcap")
    assert not out.completed
    # the fault is active from the first step starting at or after 0.5 s: k = 16 (0.528 s)
    assert out.steps_done == 16
    var = target.split(".", 1)[1]
    assert re.search(rf"unit u: .*{re.escape(var)}.*t = 0\.528 s", out.message), out.message
    assert_sound(out, ["u"])


def test_fault_through_the_cli_exits_1_with_one_line(tmp_path, built_fmus):
    sc = write_scenario(_platform_run(faults=[{"target": "p.cue.f_y", "at": 0.3, "value": float("nan")}]),
                        tmp_path / "f.toml")
    r = subprocess.run(CLI + ["run", str(sc), "-o", str(tmp_path / "f.mcap"), "-q"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("immersim: error:")]
    assert len(err) == 1 and "cue.f_y" in err[0] and "t = 0.33 s" in err[0], r.stderr
    log = check_log(tmp_path / "f.mcap")
    assert log.messages["p"] == 11 and log.run["status"] == "failed" and not log.nonfinite


# -- SIGINT ------------------------------------------------------------------------------------------

def test_sigint_exits_130_and_keeps_every_completed_step(tmp_path, built_fmus):
    sc = write_scenario(_platform_run(stop=600.0), tmp_path / "long.toml")
    mcap = tmp_path / "long.mcap"
    proc = subprocess.Popen(CLI + ["run", str(sc), "-o", str(mcap), "-q"], stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not mcap.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # the log is open: the step loop runs
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    m = re.search(r"interrupted at t = ([0-9.]+) s after (\d+) of 18182 steps", err)
    assert m, err
    steps = int(m.group(2))
    log = check_log(mcap)
    assert log.run["status"] == "interrupted" and int(log.run["steps_done"]) == steps
    assert log.messages["p"] == steps + 1 and not log.nonfinite


# -- corrupted FMU files -------------------------------------------------------------------------------

def _truncated(src: Path, dst: Path, keep: int) -> Path:
    dst.write_bytes(src.read_bytes()[:keep])
    return dst


def _with_member_truncated(src: Path, dst: Path, member_suffix: str, keep: int) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            data = zin.read(info)
            if info.filename.endswith(member_suffix):
                data = data[:keep]
            zout.writestr(info, data)
    return dst


@pytest.mark.parametrize("how", ["half", "empty", "zip_header_only"])
def test_truncated_fmu_gives_fmu_load_error_naming_the_file(how, tmp_path, built_fmus):
    src = built_fmus["platform"]
    size = src.stat().st_size
    keep = {"half": size // 2, "empty": 0, "zip_header_only": 30}[how]
    bad = _truncated(src, tmp_path / "platform_broken.fmu", keep)
    sc = write_scenario(_platform_run(stop=0.1), tmp_path / "s.toml")
    with pytest.raises(FmuLoadError, match=re.escape(str(bad))):
        run_scenario(sc, tmp_path / "s.mcap", overrides={"p:fmu": str(bad)})
    r = subprocess.run(CLI + ["run", str(sc), "-o", str(tmp_path / "c.mcap"), "-q", "--set", f"p:fmu={bad}"],
                       capture_output=True, text=True, timeout=300) if how == "half" else None
    if r is not None:
        assert r.returncode == 2 and "Traceback" not in r.stderr
        assert r.stderr.startswith("immersim: error:") and str(bad) in r.stderr, r.stderr


@pytest.mark.parametrize("member", [
    "modelDescription.xml",
    ".so",
])
def test_fmu_with_a_truncated_member_gives_a_clear_error(member, tmp_path, built_fmus):
    bad = _with_member_truncated(built_fmus["platform"], tmp_path / "platform_member.fmu", member, 200)
    sc = write_scenario(_platform_run(stop=0.1), tmp_path / "s.toml")
    cwd = os.getcwd()
    try:
        with pytest.raises(ImmersimError, match=re.escape(str(bad))):
            run_scenario(sc, tmp_path / "s.mcap", overrides={"p:fmu": str(bad)})
        assert os.getcwd() == cwd, "loading the FMU changed the working directory"
    finally:
        os.chdir(cwd)  # do not leave later tests in a deleted folder


# -- a full disk ------------------------------------------------------------------------------------


def _assert_clean_disk_failure(r: subprocess.CompletedProcess, log: str) -> None:
    assert r.returncode != 0
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("immersim: error:")]
    assert len(err) == 1 and log in err[0], r.stderr[-2000:]


def test_log_to_dev_full_fails_cleanly(tmp_path, built_fmus):
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    sc = write_scenario(_platform_run(stop=1.0), tmp_path / "s.toml")
    r = subprocess.run(CLI + ["run", str(sc), "-o", "/dev/full", "-q"], capture_output=True, text=True, timeout=300)
    _assert_clean_disk_failure(r, "/dev/full")


def test_log_to_dev_full_raises_run_failed_in_the_api(tmp_path, built_fmus):
    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    sc = write_scenario(_platform_run(stop=0.3), tmp_path / "s.toml")
    try:
        run_scenario(sc, "/dev/full")
    except RunFailed as exc:
        assert "/dev/full" in str(exc)
    except OSError as exc:
        pytest.fail(f"raw {type(exc).__name__}: {exc}")
    else:
        pytest.fail("a run logging to /dev/full completed")


def _small_fs(tmp_path: Path):
    """A 64 KiB tmpfs when mounting is allowed (root), else None (RLIMIT_FSIZE is used)."""
    d = tmp_path / "small"
    d.mkdir()
    if shutil.which("mount") and os.geteuid() == 0:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(d)], capture_output=True)
        if r.returncode == 0:
            return d
    return None


def test_disk_filling_up_mid_run_fails_cleanly(tmp_path, built_fmus):
    """60 s of platform log (~600 kB compressed) into 64 KiB of tmpfs, or into a file limited to
    400 kB by RLIMIT_FSIZE (above the largest file the FMU extracts) when tmpfs cannot be mounted."""
    sc = write_scenario(_platform_run(stop=60.0), tmp_path / "s.toml")
    d = _small_fs(tmp_path)
    try:
        mcap = (d or tmp_path) / "run.mcap"
        limit = None if d else (lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, 400_000)))
        r = subprocess.run(CLI + ["run", str(sc), "-o", str(mcap), "-q"], capture_output=True, text=True,
                           timeout=300, preexec_fn=limit)
        _assert_clean_disk_failure(r, str(mcap))
    finally:
        if d is not None:
            subprocess.run(["umount", str(d)], capture_output=True)


def test_disk_filling_up_keeps_the_completed_steps_that_fitted(tmp_path, built_fmus):
    """Same as above; the log must still be readable and hold the steps that fitted (at least one)."""
    from immersim.orchestrator.mcapio import read_info

    sc = write_scenario(_platform_run(stop=60.0), tmp_path / "s.toml")
    d = _small_fs(tmp_path)
    try:
        mcap = (d or tmp_path) / "run.mcap"
        limit = None if d else (lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, 400_000)))
        r = subprocess.run(CLI + ["run", str(sc), "-o", str(mcap), "-q"], capture_output=True, text=True,
                           timeout=300, preexec_fn=limit)
        assert r.returncode != 0
        info = read_info(mcap)
        assert info.channels["p"].count >= 1
    finally:
        if d is not None:
            subprocess.run(["umount", str(d)], capture_output=True)


def test_sigint_during_start_up_exits_130_without_claiming_a_missing_log(tmp_path, built_fmus):
    """SIGINT at a few instants after the FMU build check (logged just before the FMU is loaded,
    instantiated and initialised, which takes about a second here). The run is short (60 s
    simulated, well under a second of loop on a quiet machine), so the later instants land in the
    loop, while the log is closed, or while the FMUs are freed after the last step. None may
    die of the signal (exit -2): a signal acted on exits 130 with a message; one that came after
    the last step (or after the process ended) leaves a complete log."""
    sc = write_scenario(_platform_run(stop=60.0), tmp_path / "s.toml")
    problems = []
    for delay in (0.25, 0.45, 0.7, 1.0, 1.4):
        mcap = tmp_path / f"s{delay}.mcap"
        proc = subprocess.Popen(CLI + ["-v", "run", str(sc), "-o", str(mcap), "-q"], stderr=subprocess.PIPE,
                                text=True)
        try:
            lines = []
            for line in proc.stderr:
                lines.append(line)
                if "up to date" in line or "built" in line:
                    break
            time.sleep(delay)
            sent = proc.poll() is None  # the process may have finished before this instant
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=300)
            err = "".join(lines) + err
        finally:
            if proc.poll() is None:
                proc.kill()
        last = err.strip().splitlines()[-1] if err.strip() else ""
        late = proc.returncode == 130 and "after the run completed" in last
        if not sent or late or (proc.returncode == 0 and "Traceback" not in err):
            # the process had finished, or the signal came after the last step (reported, or
            # ignored once the command was done): the log must be complete
            log = check_log(mcap)
            if log.run.get("status") != "completed" or log.messages.get("p") != 1820:
                problems.append(f"{delay} s: exit {proc.returncode} but the log is incomplete: {log.run}")
            continue
        if proc.returncode != 130:
            problems.append(f"{delay} s: exit {proc.returncode}: {last[:200]}")
        if "Traceback" in err:
            problems.append(f"{delay} s: traceback")
        if "holds steps" in err and not mcap.exists():
            problems.append(f"{delay} s: the message names a log that was not written")
    assert not problems, problems
