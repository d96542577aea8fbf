"""The native platform FMU (``platform-native``): no Python at run time, the Python build's numbers.

Equality is bit for bit (hence within any relative tolerance) against the Python build on
recorded and scenario input traces; the FMI layer's checks log the Python build's messages; the
binary runs in FMPy, OSP libcosim and a C host process that has no libpython.
"""
from __future__ import annotations

import functools
import re
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException, calloc, free
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy.validation import validate_fmu

from immersim.fmus.platform.platform_fmu import FLAG_OUTPUTS, PACKED_INPUTS, PACKED_REAL_OUTPUTS
from immersim.orchestrator.build import build_unit, default_build_dir
from immersim.orchestrator.crosscheck import simulate_fmpy, simulate_libcosim
from immersim.orchestrator.native_build import build_native, fmi_headers

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parent / "data"
H = 0.033
OUTPUTS = list(PACKED_REAL_OUTPUTS) + [name for name, _ in FLAG_OUTPUTS]


@pytest.fixture(scope="module")
def fmus():
    dest = default_build_dir()
    return {"python": build_unit(ROOT / "fmus" / "platform", dest), "native": build_native(dest)}


@functools.lru_cache(maxsize=None)
def _extracted(path: Path) -> str:
    """One extraction per FMU file for the whole module (instances share it, as in one master)."""
    return extract(str(path))


class Runner:
    """One FMU instance stepped with FMPy, its logged messages kept."""

    def __init__(self, path: Path, params: dict | None, name: str = "p1") -> None:
        """Instantiate; with ``params`` (not None) also set them and initialize."""
        md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.messages = []
        # the logger is called directly, not through FMPy's proxy: the proxy keeps the last registered
        # callback in a global, which later FMUs of the session would call after this runner is gone
        self.cb = cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(lambda env, inst, status, cat, msg: self.messages.append(msg.decode()))
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.fmu = FMU2Slave(guid=md.guid, unzipDirectory=_extracted(path),
                             modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        self.fmu.setupExperiment(startTime=0.0)
        self.t = 0.0
        if params is not None:
            self.initialize(params)

    def set(self, params: dict) -> None:
        for k, v in params.items():
            setter = {str: self.fmu.setString, int: self.fmu.setInteger}.get(type(v), self.fmu.setReal)
            setter([self.vr[k]], [v])

    def initialize(self, params: dict) -> None:
        self.set(params)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.ivr = [self.vr[n] for n in PACKED_INPUTS]
        self.ovr = [self.vr[n] for n in PACKED_REAL_OUTPUTS]
        self.bvr = [self.vr[n] for n, _ in FLAG_OUTPUTS]

    def outputs(self) -> list:
        return self.fmu.getReal(self.ovr) + [float(b) for b in self.fmu.getBoolean(self.bvr)]

    def step(self, u, h: float = H) -> list:
        self.fmu.setReal(self.ivr, [float(x) for x in u])
        self.fmu.doStep(self.t, h)
        self.t += h
        return self.outputs()

    def run(self, U, hs=None) -> np.ndarray:
        hs = [H] * len(U) if hs is None else hs
        return np.array([self.outputs()] + [self.step(u, h) for u, h in zip(U, hs)])

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


def _both(fmus, params, U, hs=None):
    out = []
    for build in ("python", "native"):
        r = Runner(fmus[build], params)
        out.append(r.run(U, hs))
        r.close()
    return out


def _demo_inputs(n: int = 200) -> np.ndarray:
    t = np.arange(n) * H
    U = np.zeros((n, len(PACKED_INPUTS)))
    U[:, 0] = np.where((t > 0.5) & (t < 2), 2.0, np.where((t > 2.5) & (t < 5), -3.0, 0.0))
    U[:, 1] = 1.5 * np.sin(2 * np.pi * 0.4 * t)
    U[:, 5] = 0.3 * np.cos(2 * np.pi * 0.4 * t)
    U[(t >= 4) & (t < 4.07), 6] = 8.0
    U[-30:] = 0.0
    return U


def _elements(node) -> list:
    return [(e.tag, e.attrib) for e in node.iter()]


# -- interface ---------------------------------------------------------------------------
def test_model_description_is_valid_and_declares_the_python_builds_variables(fmus):
    assert validate_fmu(str(fmus["native"])) == []
    roots = {b: ET.fromstring(zipfile.ZipFile(fmus[b]).read("modelDescription.xml")) for b in fmus}
    for part in ("ModelVariables", "ModelStructure", "UnitDefinitions"):
        # names, value references, causality, variability, types, starts, units, descriptions
        native, python = (_elements(roots[b].find(part)) for b in ("native", "python"))
        assert native == python and len(native) > 3, part
    cosim = roots["native"].find("CoSimulation")
    assert cosim.get("modelIdentifier") == "platform_native" and cosim.get("needsExecutionTool") == "false"
    assert cosim.get("canGetAndSetFMUstate") == cosim.get("canSerializeFMUstate") == "true"
    names = zipfile.ZipFile(fmus["native"]).namelist()
    listed = [f.get("name") for f in cosim.find("SourceFiles")]
    assert listed and all(f"sources/{n}" in names for n in listed)
    assert "binaries/linux64/platform_native.so" in names and not any(n.endswith(".py") for n in names)


# -- same numbers as the Python build ------------------------------------------------------
@pytest.mark.parametrize("params", [{}, {"control": "pd", "washout.k_t": 1.5}, {"substeps": 3, "payload_mass": 80.0}])
def test_washout_trace_is_bit_identical_to_the_python_build(fmus, params):
    """Demo-like cues with a jolt (and a reference clamped into the workspace at k_t = 1.5)."""
    py, nat = _both(fmus, params, _demo_inputs())
    np.testing.assert_array_equal(nat, py)
    assert py[:, len(PACKED_REAL_OUTPUTS) + 2].any()  # flag.outside_workspace: the clamp ran


def test_campus_drive_platform_inputs_give_bit_identical_outputs(fmus):
    """The platform inputs recorded from a campus_drive run (607 steps, washout gains of the scenario)."""
    U = np.loadtxt(DATA / "campus_drive_platform_inputs.csv", delimiter=",", skiprows=1)
    py, nat = _both(fmus, {"washout.k_t": 0.2, "washout.k_r": 0.2}, U)
    np.testing.assert_array_equal(nat, py)
    assert np.abs(py[:, :6]).max() > 0.01  # the platform moved


def test_variable_step_sizes_and_pose_cueing_are_bit_identical(fmus):
    """Step sizes 0.01..0.1 s (new washout matrices, 0..2 squarings) and pose cueing."""
    U = _demo_inputs(40)
    hs = [0.033, 0.1, 0.01, 0.066, 0.02] * 8
    py, nat = _both(fmus, {"washout.omega_t": 3.7, "washout.jolt_heave": 0.6, "substeps": 4}, U, hs)
    np.testing.assert_array_equal(nat, py)
    t = np.arange(60) * H
    P = np.zeros((60, len(PACKED_INPUTS)))
    P[:, 8], P[:, 10], P[:, 12] = 0.03 * np.sin(np.pi * t), 0.05 * np.sin(np.pi * t), 0.6 * np.sin(np.pi * t)
    py, nat = _both(fmus, {"cueing": "pose"}, P)
    np.testing.assert_array_equal(nat, py)


def test_direct_control_and_its_failure_match_the_python_build(fmus):
    """Direct forces: the same motion, then the same failed step when the platform leaves the rods' reach."""
    runs = {}
    for build in ("python", "native"):
        r = Runner(fmus[build], {"control": "direct"})
        rows, err = [], None
        for k in range(200):
            try:
                rows.append(r.step([0.0] * 13 + [300.0, -200.0, 150.0, 800.0, 700.0, 900.0]))
            except FMICallException as exc:
                err = (k, exc.status, r.messages[-1])
                break
        runs[build] = (np.array(rows), err)
        r.close()
    np.testing.assert_array_equal(runs["native"][0], runs["python"][0])
    assert runs["native"][1] is not None and runs["native"][1] == runs["python"][1]


# -- the FMI layer's checks ------------------------------------------------------------------
@pytest.mark.parametrize("case", ["nan", "time", "step"])
def test_master_errors_are_refused_with_the_python_builds_message(fmus, case):
    got = {}
    for build in ("python", "native"):
        r = Runner(fmus[build], {})
        r.step([0.0] * len(PACKED_INPUTS))
        with pytest.raises(FMICallException) as exc:
            if case == "nan":
                r.step([float("nan")] + [0.0] * (len(PACKED_INPUTS) - 1))
            elif case == "time":
                r.fmu.doStep(1.0, H)
            else:
                r.fmu.doStep(r.t, 0.0)
        got[build] = (exc.value.status, r.messages[-1])
        r.step([0.0] * len(PACKED_INPUTS))  # the instance is still usable (discard, not error)
        r.close()
    assert got["native"] == got["python"]
    expected = {"nan": "FmuInputError: p1: input cue.f_x = nan at t = 0.033 s is not finite",
                "time": "FmuInputError: p1: doStep current time t = 1.0 s but the FMU is at t = 0.033 s",
                "step": "FmuInputError: p1: communication step size 0.0 s at t = 0.033 s must be > 0"}[case]
    assert got["native"] == (2, expected)  # fmi2Discard


@pytest.mark.parametrize("name, value, match", [
    ("integrator", "cvode_bdf", "parameter integrator = 'cvode_bdf' is not supported by the native build"),
    ("integrator", "implicit", "parameter integrator = 'implicit' is not supported by the native build"),
    ("integrator", "dop853", "parameter integrator = 'dop853' is not supported by the native build"),
    ("model", "planar", "parameter model = 'planar' is not supported by the native build .it supports full."),
    ("control", "lqr", "bad parameter: control = 'lqr' is not one of computed_torque, pd, direct"),
])
def test_unsupported_choices_are_refused_when_set(fmus, name, value, match):
    r = Runner(fmus["native"], None)
    with pytest.raises(FMICallException, match="fmi2SetString failed"):
        r.set({name: value})
    r.fmu.freeInstance()
    assert len(r.messages) == 1 and r.messages[0].startswith("ValueError: p1: ")
    assert re.search(match, r.messages[0])


def test_bad_parameter_fails_initialization_with_the_python_builds_message(fmus):
    got = {}
    for build in ("python", "native"):
        r = Runner(fmus[build], None)
        r.set({"washout.omega_b": -0.5})
        r.fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            r.fmu.exitInitializationMode()
        got[build] = [m for m in r.messages if "omega_b" in m]
        r.fmu.freeInstance()
    assert got["native"] == ["ValueError: p1: bad parameter: WashoutParams.omega_b = -0.5 must be > 0"]
    text = got["native"][0].split("ValueError: ", 1)[1]
    assert any(text in m for m in got["python"]), got["python"]


def test_fmu_state_get_set_and_serialization_replay_the_same_steps(fmus):
    U = _demo_inputs(120)
    r = Runner(fmus["native"], {})
    for u in U[:60]:
        r.step(u)
    state, t = r.fmu.getFMUstate(), r.t
    first = np.array([r.step(u) for u in U[60:]])
    blob = r.fmu.serializeFMUstate(state)
    r.fmu.setFMUstate(state)
    r.t = t
    np.testing.assert_array_equal(np.array([r.step(u) for u in U[60:]]), first)
    restored = r.fmu.deSerializeFMUstate(blob)
    r.fmu.setFMUstate(restored)
    r.t = t
    np.testing.assert_array_equal(np.array([r.step(u) for u in U[60:]]), first)
    r.fmu.freeFMUstate(state)
    r.fmu.freeFMUstate(restored)
    r.close()


# -- other masters and processes ---------------------------------------------------------------
def test_libcosim_runs_several_instances_with_the_python_builds_outputs(fmus):
    start = {"cueing": "pose", "ref.y": 0.03, "ref.gamma": 0.05, "ref.z": -0.01}
    outputs = list(PACKED_REAL_OUTPUTS)
    ref = simulate_libcosim(fmus["python"], start, 45, outputs)[0]
    native = simulate_libcosim(fmus["native"], start, 45, outputs, instances=3)
    fmpy_native = simulate_fmpy(fmus["native"], start, 45, outputs, instances=2)
    fmpy_python = simulate_fmpy(fmus["python"], start, 45, outputs)[0]
    for inst in fmpy_native:
        for name in outputs:
            np.testing.assert_array_equal(inst[name], fmpy_python[name], err_msg=name)
    assert len(native) == 3
    for inst in native:
        for name in outputs:
            np.testing.assert_array_equal(inst[name], ref[name], err_msg=name)
    assert abs(ref["pose.y"][-1] - 0.03) < 1e-3  # the pose tracks the reference


HOST_C = r"""
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String cat,
                   fmi2String msg, ...) { fprintf(stderr, "%s: %s\n", name, msg); }

#define LOAD(f) f##TYPE* f = (f##TYPE*) dlsym(lib, #f); if (!f) { fprintf(stderr, "no %s\n", #f); return 2; }

int main(int argc, char** argv) {
  /* argv: library, GUID, file of inputs (n x 19 numbers), then the 19 input and 25 output value references */
  fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
  fmi2ValueReference in[19], out[25];
  double u[19], y[25], t = 0.0;
  char line[256];
  int k, inst;
  FILE* f;
  void* lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
  fmi2Component c[2];
  if (!lib) { fprintf(stderr, "%s\n", dlerror()); return 2; }
  LOAD(fmi2Instantiate) LOAD(fmi2SetupExperiment) LOAD(fmi2EnterInitializationMode)
  LOAD(fmi2ExitInitializationMode) LOAD(fmi2SetReal) LOAD(fmi2GetReal) LOAD(fmi2DoStep) LOAD(fmi2Terminate)
  LOAD(fmi2FreeInstance)
  for (k = 0; k < 19; ++k) in[k] = (fmi2ValueReference) atoi(argv[4 + k]);
  for (k = 0; k < 25; ++k) out[k] = (fmi2ValueReference) atoi(argv[23 + k]);
  for (inst = 0; inst < 2; ++inst) {
    c[inst] = fmi2Instantiate(inst ? "b" : "a", fmi2CoSimulation, argv[2], "", &cb, fmi2False, fmi2False);
    if (!c[inst] || fmi2SetupExperiment(c[inst], fmi2False, 0, 0.0, fmi2False, 0) || fmi2EnterInitializationMode(c[inst])
        || fmi2ExitInitializationMode(c[inst])) return 3;
  }
  f = fopen(argv[3], "r");
  while (fscanf(f, "%lf", &u[0]) == 1) {
    for (k = 1; k < 19; ++k) if (fscanf(f, "%lf", &u[k]) != 1) return 4;
    for (inst = 0; inst < 2; ++inst) {  /* instance b gets half the cues: two different states */
      double v[19];
      for (k = 0; k < 19; ++k) v[k] = inst ? 0.5 * u[k] : u[k];
      if (fmi2SetReal(c[inst], in, 19, v) || fmi2DoStep(c[inst], t, 0.033, fmi2True) || fmi2GetReal(c[inst], out, 25, y))
        return 5;
      for (k = 0; k < 25; ++k) printf("%.17g%c", y[k], k == 24 ? '\n' : ' ');
    }
    t += 0.033;
  }
  fclose(f);
  for (inst = 0; inst < 2; ++inst) { fmi2Terminate(c[inst]); fmi2FreeInstance(c[inst]); }
  f = fopen("/proc/self/maps", "r");
  while (fgets(line, sizeof line, f)) if (strstr(line, "libpython")) { printf("LIBPYTHON %s", line); return 6; }
  fclose(f);
  printf("no libpython\n");
  return 0;
}
"""


def test_c_host_without_python_steps_two_instances(fmus, tmp_path):
    """A C program (no Python anywhere in the process) loads the .so and reproduces the Python build's
    numbers; so does a library compiled from the FMU's sources/ alone (plain gcc, no immersim flags)."""
    folder = Path(extract(str(fmus["native"]), unzipdir=str(tmp_path / "fmu")))
    so = folder / "binaries" / "linux64" / "platform_native.so"
    ldd = subprocess.run(["ldd", str(so)], capture_output=True, text=True).stdout
    assert "python" not in ldd.lower()
    md_root = ET.parse(folder / "modelDescription.xml").getroot()
    listed = [str(folder / "sources" / f.get("name")) for f in md_root.find("CoSimulation/SourceFiles")]
    rebuilt = tmp_path / "from_sources.so"
    subprocess.run(["gcc", "-O0", "-shared", "-fPIC", f"-I{folder / 'sources'}", *listed, "-o", str(rebuilt), "-lm"],
                   check=True)
    (tmp_path / "host.c").write_text(HOST_C)
    exe = tmp_path / "host"
    subprocess.run(["gcc", "-O1", f"-I{fmi_headers()}", str(tmp_path / "host.c"), "-o", str(exe), "-ldl"], check=True)
    U = _demo_inputs(80)
    np.savetxt(tmp_path / "inputs.txt", U, fmt="%.17g")
    md = read_model_description(str(fmus["native"]))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    args = [str(exe), str(so), md.guid, str(tmp_path / "inputs.txt")]
    args += [str(vr[n]) for n in PACKED_INPUTS] + [str(vr[n]) for n in PACKED_REAL_OUTPUTS]
    proc = subprocess.run(args, capture_output=True, text=True, env={"PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stdout[-500:] + proc.stderr[-2000:]
    lines = proc.stdout.splitlines()
    assert lines[-1] == "no libpython"
    args[1] = str(rebuilt)
    assert subprocess.run(args, capture_output=True, text=True, env={"PATH": "/usr/bin:/bin"}).stdout == proc.stdout
    host = np.array([[float(x) for x in ln.split()] for ln in lines[:-1]])
    n = len(PACKED_REAL_OUTPUTS)
    for inst, scale in ((0, 1.0), (1, 0.5)):
        r = Runner(fmus["python"], {}, name=f"i{inst}")
        ref = r.run(scale * U)[1:, :n]
        r.close()
        np.testing.assert_array_equal(host[inst::2], ref)


def _log(path: Path):
    """(messages as (topic, log time, bytes), metadata by name) of an MCAP log."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        messages = [(ch.topic, m.log_time, m.data) for _, ch, m in reader.iter_messages()]
    with open(path, "rb") as fh:
        metadata = {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}
    return messages, metadata


@pytest.mark.parametrize("scenario", ["demo.toml", "platform_tracking.toml"])
def test_swapping_in_the_native_unit_gives_the_same_log(fmus, scenario, tmp_path):
    """``fmu = "platform"`` -> ``"platform-native"``: every logged message is the same; the metadata
    differ only in the scenario text (the swap itself) and the units' FMU files."""
    from immersim.orchestrator.cli import main

    text = (ROOT / "scenarios" / scenario).read_text()
    assert 'fmu = "platform"' in text
    logs = {}
    for build, fmu in (("python", "platform"), ("native", "platform-native")):
        (tmp_path / build).mkdir()
        src = tmp_path / build / scenario
        src.write_text(text.replace('fmu = "platform"', f'fmu = "{fmu}"'))
        assert main(["run", str(src), "-o", str(tmp_path / f"{build}.mcap"), "-q"]) == 0
        logs[build] = _log(tmp_path / f"{build}.mcap")
    (py_msgs, py_meta), (nat_msgs, nat_meta) = logs["python"], logs["native"]
    assert len(py_msgs) > 100 and nat_msgs == py_msgs
    assert set(nat_meta) == set(py_meta)
    differ = {name for name in py_meta if nat_meta[name] != py_meta[name]}
    assert differ <= {"scenario", "fmus"}
    assert all("platform-native.fmu" in v for v in nat_meta["fmus"].values())


def test_build_command_builds_the_native_unit(fmus, capsys):
    from immersim.orchestrator.cli import main

    assert main(["build", "platform", "--native"]) == 0
    assert capsys.readouterr().out.strip() == str(fmus["native"])
    assert main(["build", "network", "--native"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("immersim: error: unknown unit 'network-native'") and "platform-native" in err


def _native_outcome(path: Path, name: str, value: float):
    """None when the native FMU's initialization accepts ``name = value``, else its ValueError's text."""
    r = Runner(path, None)
    r.set({name: value})
    r.fmu.enterInitializationMode()
    try:
        r.fmu.exitInitializationMode()
        return None
    except FMICallException:
        return " ".join(r.messages).removeprefix("ValueError: ")
    finally:
        r.fmu.freeInstance()


def _python_outcome(name: str, value: float):
    """The same for the Python build's wrapper (its configuration step, in this process: pythonfmu's
    binary does not survive many failed initializations in one process)."""
    from tests.fmpy_runner import wrapper_class

    slave = wrapper_class(ROOT / "fmus" / "platform")(instance_name="p1", resources=str(ROOT))
    slave.values[name] = value
    try:
        slave._config()
        return None
    except ValueError as exc:
        return str(exc)


def test_every_real_parameter_is_checked_as_the_python_build_checks_it(fmus):
    """Each Real parameter set to -1 (then 0): accepted or refused with the same message by both builds
    (the native parameter checks are a copy of the dataclasses' and must not drift)."""
    md = read_model_description(str(fmus["native"]))
    names = [v.name for v in md.modelVariables if v.causality == "parameter" and v.type == "Real"]
    refused = 0
    for name in names:
        for value in (-1.0, 0.0):
            native = _native_outcome(fmus["native"], name, value)
            assert native == _python_outcome(name, value), (name, value)
            refused += native is not None
    assert refused >= 20  # the > 0 checks of geometry, mass and washout, payload_mass, stroke limits, tolerances
