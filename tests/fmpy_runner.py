"""A minimal co-simulation loop written directly on FMPy's ``FMU2Slave`` (independent of our
orchestrator's wrapper), with a logger that captures the FMU's messages. Shared by the unit
FMU tests so each unit is also simulated by plain FMPy."""
from __future__ import annotations

import tempfile
import zipfile

import numpy as np
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

from immersim.orchestrator.pythonfmu_exit import install

install()   # this process loads pythonfmu binaries through plain FMPy: let it exit normally

H = 0.033


class Runner:
    """Instantiate ``path``, set ``params`` in initialization mode, then :meth:`step` at ``k * h``.

    ``init=False`` stays in initialization mode (to test what exit-initialization reports).
    """

    def __init__(self, path, name="u", params=None, init=True, h=H):
        self.md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.types = {v.name: v.type for v in self.md.modelVariables}
        self.tmp = tempfile.mkdtemp(prefix=f"{name}_fmu_")
        zipfile.ZipFile(path).extractall(self.tmp)
        self.messages = []
        self.h = h

        def logger(env, inst, status, category, message):
            self.messages.append(message.decode(errors="replace"))

        self.cb = fmi2CallbackFunctions()
        self._logger = fmi2CallbackLoggerTYPE(logger)
        self.cb.logger = self._logger
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.tmp,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=self.cb, loggingOn=True)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.set(params or {})
        if init:
            self.fmu.exitInitializationMode()
        self.k = 0

    def set(self, values):
        for name, value in values.items():
            t, vr = self.types[name], [self.vr[name]]
            if t == "Real":
                self.fmu.setReal(vr, [float(value)])
            elif t == "Integer":
                self.fmu.setInteger(vr, [int(value)])
            elif t == "Boolean":
                self.fmu.setBoolean(vr, [bool(value)])
            else:
                self.fmu.setString(vr, [str(value)])

    def get(self, names):
        """Values as floats (Booleans and Integers converted), shape (len(names),)."""
        out = []
        for n in names:
            t, vr = self.types[n], [self.vr[n]]
            out.append(float(self.fmu.getBoolean(vr)[0]) if t == "Boolean" else
                       float(self.fmu.getInteger(vr)[0]) if t == "Integer" else self.fmu.getReal(vr)[0])
        return np.array(out)

    def step(self, inputs=None):
        if inputs:
            self.set(inputs)
        self.fmu.doStep(currentCommunicationPoint=self.k * self.h, communicationStepSize=self.h)
        self.k += 1

    def close(self):
        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()


def simulate(path, params, inputs, outputs, n_steps, runner=Runner):
    """Run ``n_steps`` with ``inputs(k)`` applied before step k; rows of (t, *outputs) after each step."""
    r = runner(path, params=params)
    rows = []
    try:
        for k in range(n_steps):
            r.step(inputs(k))
            rows.append(np.concatenate([[(k + 1) * r.h if hasattr(r, "h") else (k + 1) * H], r.get(outputs)]))
    finally:
        r.close()
    return np.array(rows)


def wrapper_class(unit_dir):
    """The FMU wrapper class of ``fmus/<unit>/`` (imported from its script, as pythonfmu does)."""
    import importlib.util
    from pathlib import Path

    unit_dir = Path(unit_dir)
    spec = importlib.util.spec_from_file_location(f"{unit_dir.name}_fmu_test", unit_dir / f"{unit_dir.name}_fmu.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return getattr(module, unit_dir.name)


def readme_has_generated_table(unit_dir) -> bool:
    """Whether the unit README contains the variable table generated from the wrapper's VARIABLES."""
    from pathlib import Path

    from immersim.fmus.common import markdown_table

    return markdown_table(wrapper_class(unit_dir).VARIABLES) in (Path(unit_dir) / "README.md").read_text()
