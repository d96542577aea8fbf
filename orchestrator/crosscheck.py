"""Run one FMU (or an SSP system) for a number of fixed steps under FMPy and under OSP libcosim,
for comparison.

Both runners start ``instances`` copies of the FMU in one process, apply the same start
values (parameters and constant inputs), take ``n_steps`` steps of ``step_ns`` and record
the named Real outputs after every step. Used by the units' tests to show that our FMUs
give the same results in another FMI 2.0 master.
"""
from __future__ import annotations

import contextlib
import gc
import logging
from pathlib import Path
from typing import Dict, Iterator, List, Sequence

import numpy as np

from .fmu import FmuInstance, read_model

log = logging.getLogger(__name__)


def simulate_fmpy(fmu: Path | str, start_values: Dict[str, object], n_steps: int, outputs: Sequence[str],
                  step_ns: int = 33_000_000, instances: int = 1) -> List[Dict[str, np.ndarray]]:
    """Step ``instances`` copies with FMPy (through :class:`FmuInstance`).

    Returns
    -------
    list (one per instance) of dict output name -> array of shape (n_steps,), the values after each step
    """
    insts = [FmuInstance(f"i{k}", fmu) for k in range(instances)]
    try:
        for inst in insts:
            inst.initialize(0, n_steps * step_ns, dict(start_values))
        readers = [inst.reader(list(outputs)) for inst in insts]
        rows: List[List[List[float]]] = [[] for _ in readers]
        for k in range(n_steps):
            for inst, r, acc in zip(insts, readers, rows):
                inst.do_step(k * step_ns, step_ns)
                acc.append(r.read())
    finally:
        for inst in insts:
            inst.terminate()
    return [{name: np.array([row[j] for row in acc], dtype=float) for j, name in enumerate(outputs)}
            for acc in rows]


def simulate_libcosim(fmu: Path | str, start_values: Dict[str, object], n_steps: int, outputs: Sequence[str],
                      step_ns: int = 33_000_000, instances: int = 1) -> List[Dict[str, np.ndarray]]:
    """Step ``instances`` copies in OSP libcosim (libcosimpy) with a fixed-step algorithm.

    Start values are applied with libcosim's ``*_initial_value``; outputs are read with a
    last-value observer after each ``step(1)``.
    """
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    _, variables = read_model(Path(fmu), "libcosim")
    ex = CosimExecution.from_step_size(step_size=step_ns)
    obs = CosimObserver.create_last_value()
    ex.add_observer(observer=obs)
    idx = []
    for k in range(instances):
        slave = CosimLocalSlave(fmu_path=str(Path(fmu).resolve()), instance_name=f"i{k}")
        idx.append(ex.add_local_slave(local_slave=slave))
    for i in idx:
        for name, value in start_values.items():
            v = variables[name]
            if v.family == "float":
                ex.real_initial_value(i, v.vr, float(value))
            elif v.family == "int":
                ex.integer_initial_value(i, v.vr, int(value))
            elif v.family == "bool":
                ex.boolean_initial_value(i, v.vr, bool(value))
            else:
                ex.string_initial_value(i, v.vr, str(value))
    vrs = [variables[o].vr for o in outputs]
    fam = [variables[o].family for o in outputs]
    if any(f != "float" for f in fam):
        raise ValueError("simulate_libcosim compares Real outputs only")
    rows: List[List[List[float]]] = [[] for _ in idx]
    # libcosim initializes on the first step; record the values after each step
    for k in range(n_steps):
        ex.step(step_count=1)
        for i, acc in zip(idx, rows):
            acc.append(obs.last_real_values(i, vrs))
    ex.stop()
    return [{name: np.array([row[j] for row in acc], dtype=float) for j, name in enumerate(outputs)}
            for acc in rows]


def simulate_ssp_libcosim(ssp: Path | str, n_steps: int, outputs: Dict[str, Sequence[str]]) -> Dict[str, Dict[str, np.ndarray]]:
    """Run an SSP archive in OSP libcosim (``CosimExecution.from_ssp_file``: its fixed-step
    algorithm at the SSP's base step) and record Real variables after each of ``n_steps`` steps
    (an input as libcosim sets it for the next step, after the step's transfers).

    Parameters
    ----------
    outputs : dict of unit -> variable names (Real)

    Returns
    -------
    dict of unit -> variable -> array of shape (n_steps,)
    """
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    ex = CosimExecution.from_ssp_file(str(Path(ssp).resolve()))
    obs = CosimObserver.create_last_value()
    ex.add_observer(observer=obs)
    plan = []
    for unit, names in outputs.items():
        idx = ex.slave_index_from_instance_name(unit)
        refs = {(v.name.decode() if isinstance(v.name, bytes) else v.name): v.reference for v in ex.slave_variables(idx)}
        plan.append((unit, idx, list(names), [refs[n] for n in names]))
    rows: Dict[str, List[List[float]]] = {unit: [] for unit in outputs}
    for _ in range(n_steps):   # libcosim initializes on the first step: values after each step
        ex.step(step_count=1)
        for unit, idx, _, vrs in plan:
            rows[unit].append(obs.last_real_values(idx, vrs))
    ex.stop()
    del ex, obs
    gc.collect()   # libcosim frees its FMUs and removes its extraction now
    _forget_removed_code()
    return {unit: {n: np.array([r[j] for r in rows[unit]]) for j, n in enumerate(names)}
            for unit, _, names, _ in plan}


def _forget_removed_code() -> None:
    """Drop the Python modules (and ``sys.path`` entries) whose files are gone: the code of
    pythonfmu FMUs libcosim loaded from an extraction it has removed. A later load of the same
    FMU (its packed package has the same name) would otherwise reuse them and fail."""
    import importlib
    import os
    import sys

    gone = [n for n, m in list(sys.modules.items())
            if isinstance(getattr(m, "__file__", None), str) and not os.path.exists(m.__file__)]
    for n in gone:
        del sys.modules[n]
    sys.path[:] = [p for p in sys.path if not isinstance(p, str) or not p or os.path.exists(p)]
    importlib.invalidate_caches()


@contextlib.contextmanager
def libcosim_step_sizes() -> Iterator[None]:
    """Within the block, FMI 2.0 units of this process are stepped with the step size OSP
    libcosim hands its FMUs: the difference of the two time points in seconds,
    ``(t + h) / 1e9 - t / 1e9`` (libcosim's ``to_double_duration``), instead of immersim's
    ``h / 1e9``. The two differ in the last bit at some steps (from 0.264 s: 0.297 - 0.264 =
    0.03300000000000003, not 0.033), and a model integrating with the step size carries that
    rounding on. With it, immersim under Jacobi + zero-order hold reproduces libcosim's fixed-step
    results bit for bit (``tests/orchestrator/test_ssp_libcosim.py``). Units in worker processes
    are not affected (run them in this one: ``unit:process=0``)."""
    from .fmu import FmuInstance

    original = FmuInstance.do_step

    def do_step(self, t_ns: int, h_ns: int) -> None:
        if self._fmi2:   # the fast path reuses its c_double while the step size (ns) is unchanged
            self._c_h.value, self._h_ns = (t_ns + h_ns) / 1e9 - t_ns / 1e9, h_ns
        return original(self, t_ns, h_ns)

    FmuInstance.do_step = do_step
    try:
        yield
    finally:
        FmuInstance.do_step = original


def libcosim_master(scenario) -> None:
    """Set a loaded scenario (in place) to the master OSP libcosim's fixed-step algorithm is:
    Jacobi (every unit reads the others' outputs of the step's start), zero-order hold on every
    connection, every unit stepped at every step (no lazy skip)."""
    import dataclasses

    scenario.algorithm, scenario.extrapolation, scenario.lazy = "jacobi", "zoh", False
    scenario.connections[:] = [dataclasses.replace(c, extrapolation="zoh", delayed=False)
                               for c in scenario.connections]


def ssp_cross_run(toml: Path | str, folder: Path | str, steps: int, exact_steps: bool) -> List[tuple]:
    """Export a scenario to SSP, run the SSP in OSP libcosim and the scenario in immersim with
    the matching master (:func:`libcosim_master`), and pair every Real output.

    Parameters
    ----------
    toml : path
        The scenario file (every signal logged, ``steps`` macro steps of 33 ms; a unit in a
        worker process is run in this one, where :func:`libcosim_step_sizes` acts).
    folder : path
        Where the SSP and the log go.
    exact_steps : bool
        Hand the FMUs libcosim's step sizes (:func:`libcosim_step_sizes`): then bit for bit.

    Returns
    -------
    list of (signal, ours, libcosim's)
        ``"unit.var"`` and the two series of the ``steps`` step ends, arrays of shape (steps,).
    """
    from .execution import run_scenario
    from .mcapio import read_series
    from .scenario import load_scenario
    from .ssp import export_ssp
    from .system import check_system

    toml, folder = Path(toml), Path(folder)
    overrides = {"simulation.stop": round(steps * 0.033, 9), "log.include": ["*"]}
    sc = load_scenario(toml, overrides)
    overrides.update({f"{u.name}:process": 0 for u in sc.units if u.process})
    ssp = export_ssp(toml, folder / f"{toml.stem}.ssp", overrides=overrides)
    sc = load_scenario(toml, overrides)
    libcosim_master(sc)
    out = folder / f"{toml.stem}.mcap"
    with libcosim_step_sizes() if exact_steps else contextlib.nullcontext():
        run_scenario(sc, out)
    system = check_system(load_scenario(toml, overrides))
    outputs = {u.name: [n for n, v in system.variables[u.name].items() if v.causality == "output" and v.family == "float"]
               for u in sc.units}
    ours = read_series(out, [f"{u}.{n}" for u, names in outputs.items() for n in names])
    theirs = simulate_ssp_libcosim(ssp, steps, outputs)
    return [(f"{u}.{n}", ours[f"{u}.{n}"][1][1:], theirs[u][n]) for u, names in outputs.items() for n in names]
