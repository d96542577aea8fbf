"""Run one FMU for a number of fixed steps under FMPy and under OSP libcosim, for comparison.

Both runners start ``instances`` copies of the FMU in one process, apply the same start
values (parameters and constant inputs), take ``n_steps`` steps of ``step_ns`` and record
the named Real outputs after every step. Used by the units' tests to show that our FMUs
give the same results in another FMI 2.0 master.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Dict, List, Sequence

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
