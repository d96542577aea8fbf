"""Output failures (full disk, EIO, EFBIG, a place that cannot be written, a file where a folder
is wanted, an unknown image format) are one line and a non-zero exit; and the log's integrity:
a failed run is never recorded as completed, a run may start before t = 0, scene coordinates
FCL would crash on are refused."""
from __future__ import annotations

import re
import resource
from pathlib import Path

import pytest

import boundlib as bl
from immersim.orchestrator.cli import main
from immersim.orchestrator.execution import RunFailed, run_scenario


def _cli(capsys, *args) -> tuple:
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, [ln for ln in captured.err.splitlines() if ln.strip()], captured.out


def _osc(tmp: Path, fmu: Path, stop: float = 1.0, extra: str = "") -> Path:
    return bl.scenario(tmp, bl.oscillator_units(fmu), stop=stop, step=0.01, extra=extra)


@pytest.mark.parametrize("target, process, pattern", [
    ("/dev/full", False, r"cannot write the log /dev/full.*No space left on device"),
    ("/dev/full", True, r"cannot write the log /dev/full.*No space left on device"),
    ("/proc/version", False, r"cannot write the log /proc/version.*: Input/output error"),
    ("/proc/no_such_dir/run.mcap", False, r"cannot write the log /proc/no_such_dir/run.mcap"),
])
def test_run_output_failure(test_fmus, tmp_path, capsys, target, process, pattern):
    sc = _osc(tmp_path, test_fmus["oscillator"])
    code, lines, _ = _cli(capsys, "run", sc, "-o", target, "-q", *(["--set", "log.process=true"] if process else []))
    assert code == 1 and len(lines) == 1, lines
    assert lines[0].startswith("immersim: error: run of ") and "s.toml" in lines[0]
    assert re.search(pattern, lines[0]), lines[0]


def test_file_size_limit(test_fmus, tmp_path):
    """``ulimit -f``: EFBIG while the log grows (a worker's shared memory falls back to the
    socket); one line naming the log and the time; the log keeps its complete chunks."""
    sc = _osc(tmp_path, test_fmus["oscillator"], stop=30.0)
    out = tmp_path / "big.mcap"
    cap = 400 * 1024   # above the FMU's largest member, below a worker's 512 KiB shared memory

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (cap, cap))

    res = bl.run(["run", str(sc), "-o", str(out), "-q", "--set", "m2:process=1"], tmp_path, preexec_fn=limit)
    bl.one_line(res, 1, r"failed at t = .* after \d+ of 3000 steps: cannot write the log .*big\.mcap at t = .*: "
                        r"File too large; the log .* keeps what the disk accepted$")
    assert out.stat().st_size <= cap


def test_info_of_a_folder_or_missing_file(tmp_path, capsys):
    code, lines, _ = _cli(capsys, "info", tmp_path)
    assert code == 2 and lines == [f"immersim: error: {tmp_path} is a folder, not an MCAP log file"]
    code, lines, _ = _cli(capsys, "info", tmp_path / "none.mcap")
    assert code == 2 and lines == [f"immersim: error: log file {tmp_path / 'none.mcap'} does not exist"]
    (tmp_path / "text.mcap").write_text("not a log\n")
    code, lines, _ = _cli(capsys, "info", tmp_path / "text.mcap")
    assert code == 2 and len(lines) == 1 and "not a readable MCAP file" in lines[0]


@pytest.fixture(scope="module")
def small_log(test_fmus, tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("plotlog")
    out = tmp / "osc.mcap"
    run_scenario(_osc(tmp, test_fmus["oscillator"], stop=0.2), out)
    return out


@pytest.mark.parametrize("target, pattern", [
    ("p.txt", r"plot -o .*p\.txt: unknown image format '\.txt'; use one of .*\.png"),
    ("/dev/full", r"cannot write the plot /dev/full: No space left on device"),
    ("/proc/no_such_dir/p.png", r"cannot write the plot /proc/no_such_dir/p\.png"),
])
def test_plot_output_failure(small_log, tmp_path, capsys, target, pattern):
    dest = target if target.startswith("/") else tmp_path / target
    code, lines, _ = _cli(capsys, "plot", small_log, "m1.x", "-o", dest)
    assert code == 2 and len(lines) == 1, lines
    assert re.search(pattern, lines[0]), lines[0]


def test_plot_writes_png_without_suffix(small_log, tmp_path, capsys):
    code, _, out = _cli(capsys, "plot", small_log, "m1.x", "-o", tmp_path / "plain")
    assert code == 0 and (tmp_path / "plain").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sweep_into_an_existing_file(test_fmus, tmp_path, capsys):
    _osc(tmp_path, test_fmus["oscillator"], stop=0.1)
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('scenario = "s.toml"\n\n[grid]\n"m1.k" = [1.0, 2.0]\n')
    (tmp_path / "afile").write_text("")
    code, lines, _ = _cli(capsys, "sweep", sweep, "-o", tmp_path / "afile", "-q", "-j", "1")
    assert code == 2 and len(lines) == 1, lines
    assert re.search(r"sweep -o .*afile: cannot write the sweep's folder: a file is there, not a folder", lines[0])


def test_failed_run_is_never_recorded_completed(test_fmus, tmp_path, monkeypatch):
    """An error that is not one of immersim's (here a TypeError raised mid-run) still fails the
    run, names it, and the log's run record says failed."""
    from immersim.orchestrator import master

    real = master.Master.step

    def step(self, t_ns, h_ns):
        if t_ns >= 300_000_000:
            raise TypeError("boom")
        return real(self, t_ns, h_ns)
    monkeypatch.setattr(master.Master, "step", step)
    out = tmp_path / "f.mcap"
    with pytest.raises(RunFailed, match=r"failed at t = 0.3 s after 30 of 100 steps: TypeError: boom"):
        run_scenario(_osc(tmp_path, test_fmus["oscillator"]), out)
    content = bl.read_log(out)
    assert content.run["status"] == "failed" and content.run["reason"] == "TypeError: boom"
    assert content.steps["m1"] == list(range(31))


def test_negative_start(test_fmus, tmp_path):
    """A run from t = -0.5 s: the log reads back at the simulation times (MCAP times are
    unsigned: the file is shifted by 0.5 s and says so)."""
    from immersim.orchestrator.mcapio import read_info, read_series

    sc = _osc(tmp_path, test_fmus["oscillator"], stop=0.5)
    sc.write_text(sc.read_text().replace("[simulation]\n", "[simulation]\nstart = -0.5\n"))
    out = tmp_path / "neg.mcap"
    res = run_scenario(sc, out)
    assert res.steps_done == 100
    info = read_info(out)
    assert info.metadata["immersim"]["log_time_offset_ns"] == "500000000"
    assert (info.channels["m1"].first_ns, info.channels["m1"].last_ns) == (-500_000_000, 500_000_000)
    t, x, _ = read_series(out, ["m1.x"])["m1.x"]
    assert t[0] == -0.5 and t[-1] == 0.5 and x[0] == 1.0
    assert bl.read_log(out).steps["m1"] == list(range(101))


def test_scene_coordinates_beyond_the_bound_are_refused():
    from immersim.models.collision.scene import MAX_COORD, SceneError, parse_scene

    with pytest.raises(SceneError, match=r"body 'tank_1' at \(1e\+200, 0, 0\) m reaches 1e\+200 m from the "
                                         r"origin, beyond 1e\+06 m"):
        parse_scene("tanks:n=4,tris=5.4k,spacing=1e200;missile:x=-30,y=0,z=15,pitch=0.41")
    with pytest.raises(SceneError, match="box_big"):
        parse_scene(f"box:name=box_big,sx={3 * MAX_COORD}")
    assert len(parse_scene("tanks:n=4,tris=5.4k,spacing=1e4").bodies) == 4   # far apart, inside the bound

