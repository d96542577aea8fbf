"""``immersim`` command line: build, run, export, info, plot, diff, report, convert, sweep, examples.

User errors print one line ``immersim: error: ...`` and exit with status 2 (bad input) or 1
(a run that failed); SIGINT, SIGTERM and SIGHUP exit with 128 + the signal. No traceback for
user errors (``--debug`` shows it).
"""
from __future__ import annotations

import os
import signal
import sys

#: signals that came while the program was starting, before ``main`` could act on them: as the
#: program (not imported by a test), the module's first act is to hold them (the interpreter's
#: own start-up, before this line, keeps the default actions; nothing is written then)
_EARLY: list = []
_HOLDING = __name__ == "__main__" or os.path.basename(sys.argv[0] if sys.argv else "") == "immersim"
#: the signals ignored by whoever started the program (nohup, a background job): they stay ignored
_IGNORED = [s for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP) if signal.getsignal(s) is signal.SIG_IGN]
if _HOLDING:
    for _sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        if _sig not in _IGNORED:
            signal.signal(_sig, lambda signum, frame: _EARLY.append(signum))

from . import phases  # noqa: E402,F401  (the phases' clock: the interpreter's start-up ends here)

import argparse  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import List, Optional  # noqa: E402

from .errors import ImmersimError  # noqa: E402

log = logging.getLogger("immersim")

EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 1, 2, 130


def _cmd_build(args: argparse.Namespace) -> int:
    from .build import build_all, parse_options

    units = [f"{u}-native" for u in args.units or ["platform"]] if args.native else args.units or None
    for path in build_all(units, args.dest, force=args.force, options=parse_options(args.option)):
        log.info("%s", path)
        sys.stdout.write(f"{path}\n")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .api import execute
    from .execution import RunFailed, RunInterrupted

    overrides = _parse_sets(args.set)
    if args.realtime is not None and not (math.isfinite(args.realtime) and args.realtime > 0):
        from .errors import ScenarioError

        raise ScenarioError(f"--realtime {args.realtime:g}: the factor must be a finite number > 0")
    live = _live_server(args.live, args.live_rate)
    try:
        res = execute(args.scenario, overrides, args.output, progress=not args.quiet,
                      realtime=args.realtime, live=live, replay=args.replay)
    except RunInterrupted as exc:
        sys.stderr.write(f"immersim: {exc}\n")
        return 128 + exc.signum
    except RunFailed as exc:
        sys.stderr.write(f"immersim: error: {exc}\n")
        return EXIT_FAILED
    finally:
        if live is not None:
            live.stop()
    late = args.late_sigint
    if late.requested:  # the signal came after the last step, while the run closed
        sys.stderr.write(f"immersim: interrupted by {late.name} after the run completed; the log {res.output} holds "
                         f"all {res.steps_done} steps\n")
        return 128 + (late.signum or 2)
    sys.stdout.write(f"{res.scenario}: {res.steps_done} steps to t = {res.t_ns / 1e9:.6g} s -> {res.output}\n")
    if res.status == "ended":   # a unit asked to end the simulation (its step is logged)
        sys.stdout.write(f"{res.reason}\n")
    summary = res.timing_summary()
    if summary:
        sys.stdout.write(summary + "\n")
    if res.pacing:
        sys.stdout.write(res.pacing + "\n")
    log.info("%s", phases.summary())
    if res.skipped_units:
        sys.stdout.write(f"not loaded (nothing uses their outputs): {', '.join(res.skipped_units)}\n")
    return 0


def _live_server(address: Optional[str], rate: float = 60.0):
    """The live view's server for ``--live [HOST:PORT]`` (None without the flag), streaming at
    most ``rate`` messages per channel and wall second (0: all); its address goes to stderr
    before the run starts."""
    if address is None:
        return None
    from .errors import ScenarioError
    from .live import LiveServer, parse_address

    try:
        if not (math.isfinite(rate) and rate >= 0):
            raise ValueError(f"--live-rate {rate:g}: must be a finite number >= 0")
        server = LiveServer(*parse_address(address or None), max_rate=rate or None)
    except (ValueError, OSError) as exc:
        raise ScenarioError(str(exc)) from None
    sys.stderr.write(f"immersim: live view at {server.url} (Foxglove: Open connection, Foxglove WebSocket)\n")
    sys.stderr.flush()
    return server


def _parse_sets(items: Optional[List[str]]):
    """``unit.param=VALUE`` pairs, VALUE read as a TOML value (a bare word is a string)."""
    from .errors import ScenarioError
    from .scenario import tomllib

    out = {}
    for item in items or []:
        if "=" not in item:
            raise ScenarioError(f"--set {item!r}: expected UNIT.PARAM=VALUE")
        key, raw = item.split("=", 1)
        try:
            out[key.strip()] = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = raw
    return out


def _cmd_info(args: argparse.Namespace) -> int:
    from .mcapio import read_info

    info = read_info(args.file)
    lines = [f"{info.path}" + (" (ends early: the complete records are shown)" if info.truncated else "")]
    run = info.metadata.get("run", {})
    if run:
        lines.append(f"run: {run.get('status')} after {run.get('steps_done')} of {run.get('steps_total')} steps"
                     + (f" ({run.get('reason')})" if run.get("reason") else ""))
    meta = info.metadata.get("immersim", {})
    if meta:
        extrap = f" + {meta['extrapolation']}" if meta.get("extrapolation") else ""
        lines.append(f"immersim {meta.get('version')}, {meta.get('algorithm')}{extrap}, "
                     f"step {int(meta.get('step_ns', 0)) / 1e9:g} s")
    for topic, ch in info.channels.items():
        span = f"{ch.first_ns / 1e9:.6g} .. {ch.last_ns / 1e9:.6g} s"
        lines.append(f"channel {topic}: {ch.count} messages, {span}, {len(ch.signals)} signals")
        if args.signals or len(ch.signals) <= 12:
            for s in ch.signals:
                u = ch.unit_of(s)
                lines.append(f"  {topic}.{s}" + (f" [{u}]" if u else ""))
    sys.stdout.write("\n".join(lines) + "\n")
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from .analysis.runs import split_sources
    from .plotting import plot_signals

    sources, patterns = split_sources(args.inputs)
    pages = _write_checked(Path(args.output), lambda out: plot_signals(
        sources, patterns, out, color_by=args.color_by, max_signals=args.max_signals))
    sys.stdout.write("".join(f"{p}\n" for p in pages))
    return 0


def _write_checked(output: Path, render) -> List[Path]:
    """``render(path)`` (returning the files it wrote) into a temporary folder, then each file
    copied to ``output``'s folder with every write checked: an unknown image format, a full
    disk or an unwritable place is one error naming the file (matplotlib's PNG writer ignores
    a failed close)."""
    import shutil
    import tempfile

    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    if output.suffix and output.suffix[1:].lower() not in formats:   # (none: PNG)
        raise ImmersimError(f"plot -o {output}: unknown image format {output.suffix!r}; "
                            f"use one of {', '.join('.' + f for f in sorted(formats))}")
    with tempfile.TemporaryDirectory(prefix="immersim_plot_") as tmp:
        written = []
        bare = not output.suffix   # matplotlib writes PNG to "<name>.png" then
        for page in render(Path(tmp) / (output.name + (".png" if bare else ""))):
            dest = output.with_name(page.stem if bare else page.name)
            try:
                dest.parent.mkdir(parents=True, exist_ok=True)
                with open(page, "rb") as src, open(dest, "wb") as dst:
                    shutil.copyfileobj(src, dst)
            except OSError as exc:
                raise ImmersimError(f"cannot write the plot {dest}: {exc.strerror or exc}") from None
            written.append(dest)
    return written


def _cmd_diff(args: argparse.Namespace) -> int:
    from .analysis.diff import diff_logs

    result = diff_logs(args.a, args.b, args.patterns or ["*"], rtol=args.rtol, atol=args.atol)
    sys.stdout.write(f"{result}\n")
    return 0 if result.equal else EXIT_FAILED


def _cmd_report(args: argparse.Namespace) -> int:
    from .analysis.report import write_report

    out = write_report(args.sources, args.output, signals=args.signals, color_by=args.color_by)
    sys.stdout.write(f"{out}\n")
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    from .analysis.convert import convert_log

    sys.stdout.write(f"{convert_log(args.file, args.output, args.patterns or ['*'])}\n")
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from .sweep import SweepFailed, run_sweep

    try:
        table = run_sweep(args.sweepfile, args.output_dir, workers=args.workers, scheduler=args.scheduler,
                          progress=not args.quiet)
    except SweepFailed as exc:  # every run done and written; some failed: show the table, exit 1
        sys.stdout.write(f"{exc.result}\n")
        sys.stderr.write(f"immersim: error: {exc}\n")
        return EXIT_FAILED
    sys.stdout.write(f"{table}\n")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from .ssp import export_ssp

    out = export_ssp(args.scenario, args.output, overrides=_parse_sets(args.set))
    sys.stdout.write(f"{out}\n")
    return 0


def _cmd_examples(args: argparse.Namespace) -> int:
    from .examples import copy_examples, list_examples

    if args.copy:
        for path in copy_examples(args.copy, args.names):
            sys.stdout.write(f"{path}\n")
        return 0
    shown = [e for e in list_examples() if not args.names or {e.name, e.name[:-5]} & set(args.names)]
    width = max((len(e.name) for e in shown), default=0)
    sys.stdout.write("".join(f"{e.name.ljust(width)}  {e.title}".rstrip() + "\n" for e in shown))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="immersim", description=__doc__.splitlines()[0])
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    p.add_argument("--debug", action="store_true", help="show tracebacks of user errors")
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build", help="build unit folders fmus/<unit>/ into FMUs (incremental)")
    b.add_argument("units", nargs="*", help="units to build (default: all)")
    b.add_argument("-d", "--dest", default=None, help="output folder (default: build/fmus)")
    b.add_argument("--force", action="store_true", help="rebuild even when up to date")
    b.add_argument("--native", action="store_true",
                   help="build the native (C, no Python at run time) FMU of the units (platform): <unit>-native.fmu")
    b.add_argument("--option", action="append", default=[], metavar="NAME=N",
                   help="a build option sizing the named units, e.g. players=8 (network), bodies=16 or pairs=16 "
                        "(collision): <unit>-players8.fmu")
    b.set_defaults(fn=_cmd_build)

    r = sub.add_parser("run", help="run a scenario file and log every signal to MCAP")
    r.add_argument("scenario", help="scenario TOML file, or an SSP archive (.ssp)")
    r.add_argument("-o", "--output", help="MCAP file (default: results/runs/<scenario>.mcap)")
    r.add_argument("--set", action="append", metavar="UNIT.PARAM=VALUE",
                   help="override a parameter (unit.param), simulation.stop/step/algorithm/extrapolation/lazy, "
                        "log.encoding/include/exclude, or run a unit in worker process N (unit:process=N); TOML value")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.add_argument("--realtime", nargs="?", const=1.0, default=None, type=float, metavar="FACTOR",
                   help="pace the run: simulated time follows wall time x FACTOR (default 1.0)")
    r.add_argument("--live", nargs="?", const="", default=None, metavar="HOST:PORT",
                   help="serve every logged channel live over the Foxglove WebSocket protocol "
                        "(default localhost, a free port, printed at start); clients may drive [[live_inputs]]")
    r.add_argument("--live-rate", type=float, default=60.0, metavar="N",
                   help="stream at most N messages per channel and wall second (default 60; 0: every step)")
    r.add_argument("--replay", default=None, metavar="LOG",
                   help="drive [[live_inputs]] with the values recorded in an earlier run's MCAP log")
    r.set_defaults(fn=_cmd_run)

    ex = sub.add_parser("export", help="write a scenario as an SSP 1.0 archive (FMUs, connections, parameters)")
    ex.add_argument("scenario", help="scenario TOML file")
    ex.add_argument("-o", "--output", required=True, help="SSP file to write")
    ex.add_argument("--set", action="append", metavar="UNIT.PARAM=VALUE", help="override, as for run")
    ex.set_defaults(fn=_cmd_export)

    i = sub.add_parser("info", help="show what an MCAP log holds")
    i.add_argument("file")
    i.add_argument("--signals", action="store_true", help="list every signal of every channel")
    i.set_defaults(fn=_cmd_info)

    pl = sub.add_parser("plot", help="plot signals of MCAP logs or a sweep's runs, overlaid, into a PNG")
    pl.add_argument("inputs", nargs="+", metavar="LOG|SWEEP_DIR ... PATTERN",
                    help="MCAP files and sweep output folders, then glob patterns over unit.variable "
                         "(e.g. 'plat.stroke*')")
    pl.add_argument("-o", "--output", required=True, help="PNG file (more pages: <name>-2.png, ...)")
    pl.add_argument("--color-by", default=None, metavar="KEY", help="grid key colouring a sweep's runs")
    pl.add_argument("--max-signals", type=int, default=120, help="error when more signals match (default 120)")
    pl.set_defaults(fn=_cmd_plot)

    d = sub.add_parser("diff", help="compare two MCAP logs signal by signal (exit 0 equal, 1 different)")
    d.add_argument("a")
    d.add_argument("b")
    d.add_argument("patterns", nargs="*", help="glob patterns over unit.variable (default: every signal)")
    d.add_argument("--rtol", type=float, default=0.0, help="relative tolerance (default 0)")
    d.add_argument("--atol", type=float, default=0.0, help="absolute tolerance (default 0: bit-identical)")
    d.set_defaults(fn=_cmd_diff)

    rp = sub.add_parser("report", help="one self-contained HTML page comparing a sweep's runs or logs")
    rp.add_argument("sources", nargs="+", metavar="SWEEP_DIR|LOG", help="sweep output folders and MCAP files")
    rp.add_argument("-o", "--output", required=True, help="HTML file")
    rp.add_argument("--signals", nargs="+", default=None, metavar="PATTERN",
                    help="signals to overlay (default: those the sweep's metrics use)")
    rp.add_argument("--color-by", default=None, metavar="KEY", help="grid key colouring a sweep's runs")
    rp.set_defaults(fn=_cmd_report)

    cv = sub.add_parser("convert", help="write an MCAP log's signals as CSV or Parquet")
    cv.add_argument("file")
    cv.add_argument("patterns", nargs="*", help="glob patterns over unit.variable (default: every signal)")
    cv.add_argument("-o", "--output", required=True, help="run.csv or run.parquet")
    cv.set_defaults(fn=_cmd_convert)

    s = sub.add_parser("sweep", help="run a grid of scenario variants (ablation) in parallel")
    s.add_argument("sweepfile", help="sweep TOML file")
    s.add_argument("-o", "--output-dir", default=None, help="folder for the MCAPs and summary.csv")
    s.add_argument("-j", "--workers", type=int, default=None, help="local worker processes (default: cores)")
    s.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:port)")
    s.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    s.set_defaults(fn=_cmd_sweep)

    e = sub.add_parser("examples", help="list the shipped example scenarios, or copy them to a folder")
    e.add_argument("names", nargs="*", help="scenarios to copy (default: all), e.g. demo sweeps/platform_ablation")
    e.add_argument("--copy", metavar="DEST", default=None, help="copy them into DEST (never overwrites)")
    e.set_defaults(fn=_cmd_examples)
    return p


def main(argv: Optional[List[str]] = None) -> int:
    """The ``immersim`` command (``argv`` None: the program's arguments); returns the exit code.

    As the program (``argv`` None), ``run`` ends the process itself once its work is done: the
    exit handlers run (:mod:`.pythonfmu_exit`'s among them), then ``os._exit``, which skips the
    interpreter's teardown of every module the units loaded (results/startup/README.md).
    """
    code = _main(argv)
    if argv is None and _COMMAND.get("name") == "run":
        _exit_now(code)
    return code


#: the command being run (``main``'s choice of exit)
_COMMAND: dict = {}


def _exit_now(code: int) -> None:
    """Flush the standard streams, run the exit handlers and end the process with ``code``
    (returns, for the interpreter's own exit, when a stream cannot be flushed or a profiler or
    tracer watches the process: it writes its results after ``main``)."""
    import atexit

    if sys.getprofile() is not None or sys.gettrace() is not None:
        return
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        return
    atexit._run_exitfuncs()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    os._exit(code)


def _main(argv: Optional[List[str]] = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _COMMAND["name"] = args.command
    level = logging.WARNING if args.verbose == 0 else logging.INFO if args.verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    # `run` defers SIGINT for the whole command (the run itself acts on it between steps): a
    # signal while FMUs are being freed would otherwise kill the interpreter (exit -2). As the
    # program's entry point (argv None) SIGINT is ignored once the command has finished.
    # SIGTERM and SIGHUP likewise. The handlers are in place before anything heavy is imported.
    from . import supervisor

    args.late_sigint = supervisor.DeferredSigint(restore=argv is not None)
    if args.fn is not _cmd_run and _HOLDING:   # other commands: the default actions again
        for sig, action in ((signal.SIGINT, signal.default_int_handler), (signal.SIGTERM, signal.SIG_DFL),
                            (signal.SIGHUP, signal.SIG_DFL)):
            if sig not in _IGNORED:
                signal.signal(sig, action)
    if _EARLY:   # came while the program started: nothing was done yet
        name = signal.Signals(_EARLY[0]).name
        sys.stderr.write(f"immersim: interrupted by {name} while starting; nothing was done\n")
        return 128 + _EARLY[0]
    try:
        if args.fn is _cmd_run:
            with args.late_sigint:
                if _EARLY:   # came between the check above and the handlers: acted on as any other
                    args.late_sigint.requested, args.late_sigint.signum = True, _EARLY[0]
                # the run in a child process: a unit that crashes it is reported (supervisor.py)
                if (argv is None and not args.debug and supervisor.available()
                        and os.environ.get("IMMERSIM_SUPERVISE", "1") != "0"):
                    code = supervisor.supervise(args.late_sigint)
                    if code is not None:
                        return code
                return args.fn(args)
        return args.fn(args)
    except ImmersimError as exc:
        if args.debug:
            raise
        sys.stderr.write(f"immersim: error: {exc}\n")
        return EXIT_USAGE
    except KeyboardInterrupt:
        sys.stderr.write("immersim: interrupted\n")
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
