"""Benchmark the run analysis: the HTML report of the campus_drive backend sweep (size, render
time in headless Chromium) and ``immersim.read_log`` of a campus_drive log.

Runs ``scenarios/sweeps/campus_backends.toml`` (3 runs of the 20 s campus_drive; ``--quick``:
cut to 5 s), writes its report, loads it in Debian's headless Chromium over the DevTools
protocol (navigation until every plot is drawn; A/B against the same page without figures and
an empty page, interleaved), and times ``read_log`` of a run's log warm (in this process) and
cold (a fresh interpreter: imports included) against the per-message reader ``read_series``.
Writes ``results/analysis/README.md`` and the report's screenshot.

Usage: ``python benchmarks/bench_analysis.py [--quick] [--repeats N]``
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from common import ROOT, interleaved, median, stamp  # noqa: E402

OUT = ROOT / "results" / "analysis"
READY = "document.body && document.body.dataset.rendered"


def run_sweep(dest: Path, stop: float | None) -> Path:
    from immersim.orchestrator.sweep import run_sweep as sweep

    text = (ROOT / "scenarios" / "sweeps" / "campus_backends.toml").read_text()
    text = text.replace('scenario = "../campus_drive.toml"',
                        f'scenario = "{(ROOT / "scenarios" / "campus_drive.toml").as_posix()}"')
    if stop is not None:
        text = text.replace("[grid]\n", f'[grid]\n"simulation.stop" = [{stop}]\n', 1)
    path = dest / "campus_backends.toml"
    path.write_text(text)
    sweep(path, dest / "campus_backends", workers=2, progress=False)
    return dest / "campus_backends"


def page_times(report: Path, tmp: Path, repeats: int) -> dict:
    """Seconds from navigation until the page's ready condition, for the report, the report's
    page with no figure (plotly.js unpacked only) and an empty page; interleaved."""
    from tests.browser import open_page

    bare = tmp / "no_figures.html"
    text = report.read_text()
    start = text.index('<script type="application/json" id="figures">')
    end = text.index("</script>", start)
    bare.write_text(text[:start] + '<script type="application/json" id="figures">{}' + text[end:])
    empty = tmp / "empty.html"
    empty.write_text("<html><body><script>document.body.dataset.rendered = 1</script></body></html>")

    cpu = {}

    def timed(name, path):
        def f():
            run = open_page(path, READY)
            if run.errors:
                raise RuntimeError(f"{path}: {run.errors}")
            cpu.setdefault(name, []).append(run.cpu_s)
            return run.load_s
        return f

    pages = {"report": report, "plotly.js only": bare, "empty page": empty}
    wall = interleaved({k: timed(k, p) for k, p in pages.items()}, repeats)
    return {"wall": wall, "cpu": cpu}


def read_times(log: Path, repeats: int) -> dict:
    import numpy as np

    import immersim
    from immersim.orchestrator.mcapio import read_series

    df = immersim.read_log(log)
    series = read_series(log, ["*"])
    identical = all(np.array_equal(df[k].to_numpy(dtype=float), y, equal_nan=True) for k, (_, y, _) in series.items())

    def warm_read_log():
        t0 = time.perf_counter()
        immersim.read_log(log)
        return time.perf_counter() - t0

    def warm_read_series():
        t0 = time.perf_counter()
        read_series(log, ["*"])
        return time.perf_counter() - t0

    code = ("import time; t0 = time.perf_counter(); import immersim; immersim.read_log({!r}); "
            "print(time.perf_counter() - t0)").format(str(log))

    def cold():
        return float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                    check=True).stdout)

    times = interleaved({"read_log (warm)": warm_read_log, "read_series (warm)": warm_read_series,
                         "read_log in a fresh interpreter (imports included)": cold}, repeats)
    return {"times": times, "identical": identical, "shape": df.shape}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="runs cut to 5 s, 2 repeats")
    ap.add_argument("--repeats", type=int, default=None, help="repeats of each timing (default 5, quick 2)")
    args = ap.parse_args(argv)
    repeats = args.repeats or (2 if args.quick else 5)
    from immersim.orchestrator.analysis.report import write_report
    from tests.browser import open_page

    import os

    OUT.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench_analysis_") as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        sweep = run_sweep(tmp, 5.0 if args.quick else None)
        sweep_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        os.chdir(tmp)  # the page names its sources as given: a relative folder, not this machine's path
        report = write_report(Path(sweep.name), tmp / "report.html")
        os.chdir(ROOT)
        write_s = time.perf_counter() - t0
        size = report.stat().st_size
        shot = OUT / "report_campus_backends.png"
        check = open_page(report, READY, {"plots": "document.querySelectorAll('.js-plotly-plot .main-svg').length"},
                          screenshot=shot)
        pages = page_times(report, tmp, repeats)
        reads = read_times(sweep / "000_fcl.mcap", repeats)
    load_after = os.getloadavg()[0]
    render = median(pages["wall"]["report"])
    render_cpu = median(pages["cpu"]["report"])
    cold = median(reads["times"]["read_log in a fresh interpreter (imports included)"])
    warm = median(reads["times"]["read_log (warm)"])
    stop = "5 s (--quick)" if args.quick else "20 s"
    lines = ["# Run analysis: report size and render time, read_log", "",
             stamp("python benchmarks/bench_analysis.py" + (" --quick" if args.quick else "")
                   + (f" --repeats {args.repeats}" if args.repeats else "")), "",
             f"Sweep: `scenarios/sweeps/campus_backends.toml` (fcl, basis_point, honeycomb), campus_drive to {stop}, "
             f"`-j 2`, {sweep_s:.0f} s wall. Timings are medians of {repeats} interleaved repeats on a machine "
             f"shared with other jobs (1-minute load average {load_before:.1f} at the start, {load_after:.1f} at "
             "the end, on 2 cores): compare within the tables.", "",
             "| target | measured | met |", "|---|---|---|",
             f"| report of a 3-run sweep < 5 MB | {size / 1e6:.2f} MB ({size} bytes) | {'met' if size < 5e6 else 'NOT met'} |",
             f"| renders in headless Chromium < 5 s | {render:.2f} s wall, navigation until both plots are drawn (min "
             f"{min(pages['wall']['report']):.2f} s); the browser's processes used {render_cpu:.2f} s CPU in that span "
             f"| {'met' if render < 5 else 'NOT met'} |",
             f"| read_log of a campus_drive log < 0.5 s | {warm:.3f} s warm; {cold:.2f} s in a fresh interpreter with its imports "
             f"| {'met' if warm < 0.5 else 'NOT met'} (warm){'' if cold < 0.5 else '; NOT met cold'} |",
             f"| read_log values bit-identical to the log | {'yes' if reads['identical'] else 'NO'}: every one of the "
             f"{reads['shape'][1]} columns equals the per-message struct decoder (`read_series`) | "
             f"{'met' if reads['identical'] else 'NOT met'} |", "",
             f"Report written in {write_s:.2f} s. Script errors in the page: {check.errors or 'none'}.", "",
             "## Page load in headless Chromium (s, from navigation until the ready flag)", "",
             "| page | wall median | wall min | wall max | CPU median (browser processes) |", "|---|---|---|---|---|"]
    lines += [f"| {k} | {median(v):.3f} | {min(v):.3f} | {max(v):.3f} | {median(pages['cpu'][k]):.3f} |"
              for k, v in pages["wall"].items()]
    lines += ["", f"The report's own cost over unpacking and running plotly.js: "
              f"{render - median(pages['wall']['plotly.js only']):.2f} s wall, "
              f"{render_cpu - median(pages['cpu']['plotly.js only']):.2f} s CPU (median differences).", "",
              f"## Reading a campus_drive log ({reads['shape'][0]} samples x {reads['shape'][1]} signals, ros1)", "",
              "| reader | median [s] | min [s] |", "|---|---|---|"]
    lines += [f"| {k} | {median(v):.4f} | {min(v):.4f} |" for k, v in reads["times"].items()]
    ratio = median(reads["times"]["read_series (warm)"]) / warm
    lines += ["", f"read_log (a DataFrame of every signal) takes 1/{ratio:.1f} of read_series' time "
              "(per-message decode into Python lists).", "",
              f"Screenshot of the report: `{shot.relative_to(ROOT)}`."]
    (OUT / "README.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
