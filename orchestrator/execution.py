"""The execution: set up units, master and observers; run the step loop; always close the log.

The loop itself is a few lines (:meth:`Execution.run`): manipulate, step, observe. Failures
(an FMU error or discard, a NaN output, SIGINT) stop the loop; the MCAP file is closed
properly and holds every completed step, and a :class:`RunFailed` says where and why.
"""
from __future__ import annotations

import functools
import gc
import logging
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional

from .fmu import ENDED, forget_python_code
from . import phases, supervisor
from .supervisor import DeferredSigint
from .errors import FmuCallError, FmuLoadError, ImmersimError, LogWriteError, ScenarioError
from .master import Master
from .live import attach_live_inputs
from .logwriter import LogPlan, LogProcess, LogWriter
from .pacing import Pacer
from .scenario import Scenario, load_scenario
from .stepping import Slot
from .system import System, check_system, fmu_hashes

log = logging.getLogger(__name__)


class RunFailed(ImmersimError, RuntimeError):
    """A run stopped before its end; ``result`` tells how far it got."""

    def __init__(self, message: str, result: "RunResult") -> None:
        super().__init__(message)
        self.result = result


class RunInterrupted(RunFailed):
    """The run was interrupted by SIGINT, SIGTERM or SIGHUP (``signum``)."""

    def __init__(self, message: str, result: "RunResult", signum: int = 2) -> None:
        super().__init__(message, result)
        self.signum = signum


@dataclass
class RunResult:
    scenario: Path
    output: Optional[Path]
    steps_done: int
    steps_total: int
    t_ns: int
    start_ns: int = 0
    status: str = "completed"
    reason: str = ""
    skipped_units: List[str] = field(default_factory=list)
    delayed_connections: List[str] = field(default_factory=list)
    values: Dict[str, Dict[str, Any]] = field(default_factory=dict)
    #: wall seconds: "loop" (the whole step loop), "logging" (observers), "unit:<name>" per unit
    #: (for a unit in a worker process: the worker's time in its calls), "wait" (the master's
    #: time waiting for worker processes; only with some)
    timing: Dict[str, float] = field(default_factory=dict)
    #: units that ran in worker processes (``process`` >= 1)
    remote_units: List[str] = field(default_factory=list)
    #: a paced run (``realtime``): late steps, worst and p99 lateness, as one line
    pacing: str = ""

    def timing_summary(self) -> str:
        """One line: wall time of the loop, real-time factor, share of each unit and of logging."""
        loop = self.timing.get("loop", 0.0)
        if loop <= 0 or self.steps_done == 0:
            return ""
        sim = (self.t_ns - self.start_ns) / 1e9
        units = {k[5:]: v for k, v in self.timing.items() if k.startswith("unit:")}
        parts = [f"{k} {v:.3g} s" + (" (worker)" if k in self.remote_units else "") for k, v in units.items()]
        wait = self.timing.get("wait", 0.0)
        master = (loop - sum(v for k, v in units.items() if k not in self.remote_units)
                  - self.timing.get("logging", 0.0) - wait)
        return (f"loop {loop:.3g} s for {sim:.6g} s simulated ({sim / loop:.1f}x real time); "
                f"units: {', '.join(parts)}; logging {self.timing.get('logging', 0.0):.3g} s; master {master:.3g} s"
                + (f"; waiting for workers {wait:.3g} s" if "wait" in self.timing else "")
                + (f"; log writer process {self.timing['log writer cpu']:.3g} s CPU"
                   if "log writer cpu" in self.timing else ""))


class Execution:
    """A scenario ready to run.

    Parameters
    ----------
    scenario : Scenario or path
    output : path, optional
        MCAP file; no log when None.
    progress : bool
        Show a tqdm progress bar on stderr.
    realtime : float, optional
        Pace the run: simulated time follows wall time times this factor (:mod:`.pacing`).
    live : LiveServer, optional
        Serve every logged channel live (:mod:`.live`); the log is then written in this process.
    replay : path, optional
        An MCAP log whose recorded live inputs drive the scenario's ``[[live_inputs]]``.
    """

    def __init__(self, scenario: Scenario | Path | str, output: Optional[Path | str] = None,
                 progress: bool = False, overrides: Optional[Dict[str, Any]] = None,
                 realtime: Optional[float] = None, live: Any = None, replay: Optional[Path | str] = None) -> None:
        phases.run_started()
        self.scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario, overrides)
        phases.mark("scenario parse")
        self.pacer = None if realtime is None else Pacer(realtime, self.scenario.start_ns)
        self.live = live
        self.scenario, self.live_inputs = attach_live_inputs(self.scenario, live, replay)
        self.output = Path(output) if output else None
        self.progress = progress
        self.system: System = check_system(self.scenario)
        phases.mark("scenario check")   # (the FMUs' build check, model descriptions, connections)
        self.meshes: List[Any] = []   # what the units describe, drawn once ([foxglove] units)
        self.view_steps: List[Any] = []   # ... and redrawn every step (the platform's rods)
        if self.scenario.view_units:
            self._add_unit_view()
            phases.mark("3D view of the units")
        supervisor.remove_stale()   # what runs killed outright left behind
        supervisor.reset()
        self._tmp = tempfile.TemporaryDirectory(prefix=f"immersim_run_{os.getpid()}_")
        self.observer: Optional[LogWriter | LogProcess] = None   # the MCAP log
        self._log_step: Optional[Callable[[int, int], None]] = None   # logs step k at t_ns
        self.observers: List[Callable[[int, int], None]] = []
        self._observe_ns = 0
        #: the collector was paused for the set-up: :meth:`run` resumes it at the first step
        self.resume_collector = False

    def _add_unit_view(self) -> None:
        """Add the bodies the loaded units describe to the 3D view (:mod:`.views`)."""
        from dataclasses import replace

        from .fmu import read_model
        from .views import unit_view

        sc, system = self.scenario, self.system
        units = []
        for name in system.needed:
            params = dict(sc.unit(name).parameters)
            scene = system.variables[name].get("scene")
            if scene is not None:
                params.setdefault("scene", scene.start)
            units.append((name, read_model(system.paths[name], name)[0].modelName, params))
        bodies, self.meshes, self.view_steps = unit_view(units, sc.mesh_triangles, sc.view_rods)
        self.scenario = system.scenario = replace(sc, foxglove=list(sc.foxglove) + bodies)

    # -- set-up --------------------------------------------------------------------------
    def _setup(self) -> Master:
        sc, system = self.scenario, self.system
        supervisor.note(scenario=str(sc.file), steps_total=sc.n_steps)
        system.instantiate(Path(self._tmp.name))
        conns = system.connections()
        slots: Dict[str, Slot] = {}
        for name in system.needed:
            inst = system.instances[name]
            sources = [c.src_var for c in conns if c.src_unit == name]
            viewed = [r.split(".", 1)[1] for b in sc.foxglove for r in b.refs() if r.split(".", 1)[0] == name]
            reader = inst.reader(system.logged[name] + sources + viewed
                                 + (["at_rest"] if _lazy_capable(inst, sc) else []), check_finite=True)
            slot = Slot(name, inst, reader.names)
            slot.reader = reader
            real_in = [c.dst_var for c in conns if c.dst_unit == name and inst.var(c.dst_var).family == "float"]
            real_in += [s.var for s in sc.inputs if s.unit == name]
            real_in += [f.var for f in sc.faults if f.unit == name and inst.var(f.var).family == "float"
                        and inst.var(f.var).causality == "input"]
            names = slot.inputs.names = list(dict.fromkeys(real_in))
            if names:
                slot.inputs.setter = inst.real_setter(names)
                slot.inputs.values = [float(inst.var(n).start or 0.0) for n in names]
            slots[name] = slot
        self._initialize(slots, conns)
        master = Master(sc, slots, conns)
        master.initial(sc.start_ns)
        return master

    def _initialize(self, slots: Dict[str, Slot], conns) -> None:
        """Initialize the units in connection order: a unit's connected inputs get the outputs
        its sources report after their own initialization (with gain and offset), its scenario
        signals their value at the start time, so every unit starts from consistent inputs.
        Inputs fed across a cycle keep their start values (the delayed connections)."""
        from .graph import gauss_seidel_order
        from .manipulators import signal

        sc = self.scenario
        order, _ = gauss_seidel_order(list(slots), conns)
        done = set()
        for name in order:
            values = dict(sc.unit(name).parameters)
            for s in sc.inputs:
                if s.unit == name:
                    values[s.var] = signal(s)(sc.start_ns / 1e9)
            for c in conns:
                if c.dst_unit == name and c.src_unit in done:
                    src = slots[c.src_unit]
                    y = src.cur[src.index(c.src_var)]
                    values[c.dst_var] = c.gain * y + c.offset if c.scaled else y
            try:
                slots[name].inst.initialize(sc.start_ns, sc.stop_ns, values, sc.tolerance)
            except FmuCallError as exc:   # the unit refused its parameters: a bad scenario (exit 2)
                from .values import refused_at_initialization

                raise refused_at_initialization(sc, name, exc) from None
            slots[name].read()
            done.add(name)

    def _open_log(self, master: Master) -> None:
        sc, system = self.scenario, self.system
        plan = LogPlan(str(self.output), sc.log.encoding, time_offset_ns=max(0, -sc.start_ns),
                       steps_total=sc.n_steps)
        plan.metadata += [
            ("scenario", {"file": str(sc.file), "text": sc.text}),
            ("fmus", {u: f"{system.origin(u)} sha256={h}" for u, h in fmu_hashes(system).items()}),
            ("immersim", {
                "version": _version(), "algorithm": sc.algorithm, "extrapolation": sc.extrapolation,
                "step_ns": str(sc.step_ns), "start_ns": str(sc.start_ns), "stop_ns": str(sc.stop_ns),
                "skipped_units": ",".join(system.skipped),
                "delayed_connections": "; ".join(str(c) for c in master.delayed if sc.algorithm == "gauss-seidel"),
                **({"log_time_offset_ns": str(plan.time_offset_ns)} if plan.time_offset_ns else {})})]
        slots = list(master.slots.values())
        for s, slot in enumerate(slots):
            logged = system.logged[slot.name]
            if logged:
                idx = [slot.index(n) for n in logged]
                plan.channels.append((slot.name, [slot.inst.var(n) for n in logged], s,
                                      None if idx == list(range(len(slot.read_names))) else idx))
            if sc.log.parameters:
                pnames = [n for n, v in slot.inst.variables.items() if v.causality in ("parameter", "structuralParameter")]
                if pnames:
                    plan.parameters.append((slot.name, [slot.inst.var(n) for n in pnames],
                                            slot.inst.get_values(pnames), sc.start_ns))
        if sc.foxglove:
            rank = {slot.name: s for s, slot in enumerate(slots)}
            plan.bodies = list(sc.foxglove)
            plan.meshes, plan.view_steps = self.meshes, self.view_steps
            for ref in {r for b in sc.foxglove for r in b.refs()}:
                unit, var = ref.split(".", 1)
                plan.refs[ref] = (rank[unit], master.slots[unit].index(var))
        if sc.log.process and self.live is None:   # a live view is fed by the writer in this process
            proc = self.observer = LogProcess(plan)
            self._log_step = lambda k, t_ns: proc.step(k, t_ns, [slot.cur for slot in slots])
        else:   # reads the slots' values itself
            self.observer = LogWriter(plan, sources=slots, tee=self.live)
            self._log_step = self.observer.write

    def _observe(self, master: Master, k: int, t_ns: int) -> None:
        """Log step ``k`` (ending at ``t_ns``): one message per logged unit and the 3D view
        (:class:`~immersim.orchestrator.logwriter.LogWriter`), then the observers."""
        t_start = time.perf_counter_ns()
        if self.observer is not None:
            self._log_step(k, t_ns)
        for fn in self.observers:
            fn(k, t_ns)
        self._observe_ns += time.perf_counter_ns() - t_start
        if self.pacer is not None:   # waits for the wall clock (not counted as logging)
            self.pacer(k, t_ns)

    # -- the loop ------------------------------------------------------------------------
    def run(self) -> RunResult:
        """Run to the stop time. Raises :class:`RunFailed` after closing the log on failure."""
        sc = self.scenario
        n = sc.n_steps
        result = RunResult(sc.file, self.output, 0, n, sc.start_ns, start_ns=sc.start_ns,
                           skipped_units=list(self.system.skipped), status="failed",
                           reason="the run ended without a reason (an error of immersim itself)")
        loop_start = None
        master: Optional[Master] = None
        bar = None
        # SIGINT is deferred from the start: raised inside an FMU's Python code during set-up or
        # a step it would leave the unit fatal; it is acted on between phases and steps instead.
        sigint = DeferredSigint()
        try:
            with sigint:
                ENDED.clear()
                master = self.master = self._setup()
                result.delayed_connections = ([str(c) for c in master.delayed]
                                              if sc.algorithm == "gauss-seidel" else [])
                if sigint.requested:
                    raise KeyboardInterrupt
                crumb, STEPS = supervisor.CRUMB, supervisor.STEPS
                crumb[supervisor.PHASE] = supervisor.STEPPING
                if self.output is not None:
                    supervisor.note(log=str(self.output), start_ns=sc.start_ns, step_ns=sc.step_ns)
                    self._open_log(master)
                self._observe(master, 0, sc.start_ns)
                self._observe_ns = 0   # (step 0's log, the meshes with it, is set-up: not the loop's)
                phases.mark("master and log set-up")
                if self.resume_collector:   # (paused by run_scenario for the set-up)
                    gc.freeze()
                    gc.enable()
                if self.progress:
                    from tqdm import tqdm
                    # on a terminal only (disable=None), and only for a run still going after 2 s
                    bar = tqdm(total=n, unit="step", desc=sc.file.stem, leave=False, disable=None, delay=2.0)
                t0, h, stop = sc.start_ns, sc.step_ns, sc.stop_ns
                master.schedule = (t0, stop, h)
                pipelined = master.pipelined
                loop_start = time.perf_counter()
                for k in range(n):
                    if sigint.requested:
                        raise KeyboardInterrupt
                    if k == 1:
                        phases.mark("first step")
                    t_ns, t_next = t0 + k * h, min(t0 + (k + 1) * h, stop)
                    master.step(t_ns, t_next - t_ns)
                    try:   # units in worker processes start the next step while this one is logged
                        if pipelined and k + 1 < n:
                            master.post_remote(t_next, min(t0 + (k + 2) * h, stop) - t_next)
                    finally:
                        self._observe(master, k + 1, t_next)
                        result.steps_done, result.t_ns = k + 1, t_next
                        crumb[STEPS] = k + 1
                    if bar is not None:
                        bar.update(1)
                    if ENDED:   # a unit asked to end the simulation: this step is the last
                        break
                master.finish()
                phases.mark("stepping")
                result.status, result.reason = "completed", ""
                if ENDED:
                    result.status, result.reason = "ended", "; ".join(
                        f"unit {u} asked to end the simulation at t = {t / 1e9:.9g} s" for u, t in ENDED)
                if self.observer is not None:
                    self._close_log(result)
        except KeyboardInterrupt:
            result.status, result.reason = "interrupted", f"interrupted by {sigint.name}"
            raise RunInterrupted(self._stop_message(result), result, sigint.signum or 2) from None
        except (ScenarioError, FmuLoadError):
            if loop_start is None:   # known at load (a connection rule, an FMU that does not load):
                result.status = "refused"   # refused as bad input, nothing was run
                raise
            result.status, result.reason = "failed", str(sys.exc_info()[1])
            raise RunFailed(self._stop_message(result), result) from sys.exc_info()[1]
        except ImmersimError as exc:
            result.status, result.reason = "failed", str(exc)
            raise RunFailed(self._stop_message(result), result) from exc
        except Exception as exc:   # not an error of ours: the run failed all the same, and says so
            result.status, result.reason = "failed", f"{type(exc).__name__}: {exc}"
            log.debug("run failed", exc_info=True)
            raise RunFailed(self._stop_message(result), result) from exc
        finally:
            if bar is not None:
                bar.close()
            if master is not None:
                result.values = {name: dict(zip(s.read_names, s.cur)) for name, s in master.slots.items()}
                if loop_start is not None:
                    result.timing["loop"] = time.perf_counter() - loop_start
                    result.timing["logging"] = self._observe_ns / 1e9
                    if getattr(self.observer, "cpu_s", None) is not None:   # [log] process: the writer's own
                        result.timing["log writer cpu"] = self.observer.cpu_s
                    for name, s in master.slots.items():
                        # a unit in a worker process: the worker's time in its calls (it steps in
                        # parallel); the master's time waiting for workers is "wait"
                        result.timing[f"unit:{name}"] = (s.inst.busy_ns if s.inst.remote else s.busy_ns) / 1e9
                    if master.remote:   # both algorithms step through Master._parallel_step then
                        result.timing["wait"] = master.wait_ns / 1e9
                        result.remote_units = [n for n, s in master.slots.items() if s.inst.remote]
            self._finish(result)
            phases.mark("log close")
        return result

    def _stop_message(self, r: RunResult) -> str:
        where = f"; the log {r.output} holds steps 0..{r.steps_done}" if r.output else ""
        if r.output and self.observer is None:
            where = f"; no log was written (stopped before {r.output} was opened)"
        if r.output and r.reason.startswith("cannot "):  # LogWriteError: the disk decides what is kept
            where = f"; the log {r.output} keeps what the disk accepted"
        return (f"run of {r.scenario} {r.status} at t = {r.t_ns / 1e9:.9g} s after {r.steps_done} of "
                f"{r.steps_total} steps: {r.reason}{where}")

    def _close_log(self, result: RunResult) -> None:
        """Write the run metadata and finish the MCAP file (raises LogWriteError)."""
        obs = self.observer
        if obs is None or obs.closed:
            return
        run = {"status": result.status, "steps_done": result.steps_done, "steps_total": result.steps_total,
               "t_ns": result.t_ns, "reason": result.reason}
        if self.pacer is not None:
            run.update({f"realtime_{k}": v for k, v in self.pacer.summary().items()})
        if self.live_inputs is not None:   # what people sent, to replay the run exactly
            run["live_inputs"] = self.live_inputs.record()["values"]
        obs.close(run)

    def _finish(self, result: RunResult) -> None:
        try:
            try:
                self._close_log(result)
            except LogWriteError as exc:  # a failure is already being reported; keep it, note this one
                # (at debug level when it is the log's own failure: the one line says it already)
                log.log(logging.DEBUG if result.reason.startswith("cannot ") else logging.ERROR, "%s", exc)
        finally:
            self.close()

    def close(self) -> None:
        """Free the FMU instances and remove their extraction (with the Python modules loaded
        from it, see :func:`~immersim.orchestrator.fmu.forget_python_code`). :meth:`run` calls
        it; call it after using :meth:`_setup` directly."""
        supervisor.CRUMB[supervisor.PHASE] = supervisor.CLOSING
        if isinstance(self.observer, LogProcess):
            self.observer.reap()
        self.system.terminate()
        forget_python_code(Path(self._tmp.name))
        self._tmp.cleanup()


@functools.lru_cache(maxsize=1)
def _version() -> str:
    """The installed immersim version (importlib.metadata takes milliseconds per call)."""
    from importlib.metadata import version

    return version("immersim")


def _lazy_capable(inst, scenario: Scenario) -> bool:
    """A unit may be stepped lazily when it reports ``at_rest`` (a Boolean output)."""
    v = inst.variables.get("at_rest")
    return bool(scenario.lazy and v is not None and v.causality == "output" and v.family == "bool")


def run_scenario(scenario: Scenario | Path | str, output: Optional[Path | str] = None,
                 progress: bool = False, overrides: Optional[Dict[str, Any]] = None,
                 **options: Any) -> RunResult:
    """Load, check and run a scenario; see :class:`Execution` (``options``: realtime, live, replay).

    The cyclic garbage collector is paused for the set-up, which allocates tens of thousands
    of objects that live as long as the run (validated scenario, model descriptions, the
    units' modules and models) and no garbage worth a collection pass; at the first step
    :meth:`Execution.run` freezes what the set-up made (the collector skips it from then on)
    and resumes collecting; the run's end unfreezes it.
    """
    collecting = gc.isenabled()
    gc.disable()
    try:
        ex = Execution(scenario, output, progress, overrides, **options)
        ex.resume_collector = collecting
        result = ex.run()
    finally:
        if collecting:
            gc.unfreeze()
            gc.enable()
    if ex.pacer is not None:
        result.pacing = ex.pacer.line()
    return result
