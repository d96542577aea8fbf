"""Build the platform unit as a native FMI 2.0 FMU (``platform-native.fmu``): no Python at run time.

The platform's whole macro step is CasADi-generated C (:mod:`immersim.models.platform.macrostep`).
This build compiles that same C (one translation unit per controller, generated exactly as the
Python build generates it at run time), the C port of the washout matrices
(``fmus/platform/native/washout.c``), the model step (``platform_model.c``) and the small FMI 2.0
layer (``fmi2_platform.c``) into ``binaries/linux64/platform_native.so`` with the
system C compiler, and ships every C source under ``sources/`` (``<SourceFiles>`` in the model
description) so it compiles elsewhere.

Everything that describes the interface comes from the Python wrapper's ``Var`` declarations: the
``<ModelVariables>`` are the Python build's own XML (``TableSlave.to_xml``), and the C variable
table ``platform_native.h`` (names, value references, types, causalities, start values, the
packed input/output orders) is generated from the same table. Only the rk4 integrator and the
full Lagrangian model are compiled; other choices are refused when set. Builds are incremental on
the sha256 of every input.
"""
from __future__ import annotations

import hashlib
import logging
import math
import os
import platform as _platform
import shutil
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from typing import Dict, List, Tuple
from xml.etree.ElementTree import SubElement, tostring

from .errors import BuildError

log = logging.getLogger(__name__)

UNIT = "platform"
NAME = "platform-native"                 #: the unit name in scenarios and the FMU's file name
IDENTIFIER = "platform_native"           #: modelIdentifier (a C identifier): the binary's name
MODEL = "full"                           #: the plant model the native build compiles
NATIVE_CHOICES = {"model": ("full",), "integrator": ("rk4",)}  #: supported subsets of the string parameters
#: the > 0 checks of PlatformParams and WashoutParams (their ``__post_init__``), in their order
POSITIVE = (("PlatformParams", "", ("a", "b", "e", "c", "M", "size_x", "size_y", "size_z")),
            ("WashoutParams", "washout.", ("omega_t", "zeta_t", "omega_b", "omega_r", "zeta_r", "omega_tc", "g")))
#: flags of the C compiler: the Python build's (codegen.CFLAGS) plus no fused multiply-adds
#: (washout.c must round as numpy does), hidden symbols except the FMI functions
EXTRA_CFLAGS = ["-ffp-contract=off", "-fvisibility=hidden", "-DCASADI_SYMBOL_EXPORT="]
_TYPE = {"Real": "PT_REAL", "Integer": "PT_INTEGER", "Boolean": "PT_BOOLEAN", "String": "PT_STRING"}
_CAUS = {"parameter": "PC_PARAMETER", "input": "PC_INPUT", "output": "PC_OUTPUT", "local": "PC_LOCAL"}


def native_dir() -> Path:
    """``fmus/platform/native``: the hand-written C of the native build."""
    from .build import _fmus_dir

    return _fmus_dir() / UNIT / "native"


def fmi_headers() -> Path:
    """Folder of the FMI 2.0 headers (2-clause BSD) shipped with FMPy."""
    import fmpy

    folder = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (folder / "fmi2Functions.h").exists():
        raise BuildError(f"unit {NAME}: the FMI 2.0 headers are not in {folder} (FMPy installation)")
    return folder


def wrapper_module():
    """The Python wrapper module of the platform (its ``Var`` table and packed orders)."""
    from immersim.fmus.platform import platform_fmu

    return platform_fmu


def _c_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _c_double(x: float) -> str:
    """A C literal of ``x`` that reads back as the same double (start values are finite)."""
    if not math.isfinite(x):
        raise BuildError(f"unit {NAME}: start value {x} is not finite")
    return repr(float(x))


def macros() -> List[Tuple[str, tuple, tuple, str]]:
    """(control, (pre, check, sub, post), (driver, sz_arg, sz_res), C source) per controller."""
    from immersim.models.platform.codegen import library_source
    from immersim.models.platform.control import CONTROLS, prefiltered_loop
    from immersim.models.platform.macrostep import macro_parts

    out = []
    for control in CONTROLS:
        fns, driver, extra_c = macro_parts(prefiltered_loop(control, MODEL))
        for f in fns:
            if f.sz_arg() > driver[1] or f.sz_res() > driver[2]:
                raise BuildError(f"unit {NAME}: generated {f.name()} needs larger argument arrays than its driver")
        out.append((control, fns, driver, library_source(driver[0], list(fns), extra_c)))
    return out


def _choices() -> Dict[str, tuple]:
    from immersim.models.platform.control import CONTROLS, MODELS
    from immersim.models.platform.integrators import METHODS
    from immersim.models.platform.simulator import CUEING, ON_WORKSPACE

    return {"cueing": CUEING, "control": CONTROLS, "model": MODELS, "integrator": METHODS,
            "on_workspace": ON_WORKSPACE}


def header(vr_of: Dict[str, int], guid: str, parts) -> str:
    """``platform_native.h``: the variable table and packed layouts for the C layer."""
    from dataclasses import fields

    from immersim.models.platform import macrostep as ms
    from immersim.models.platform.control import NC, ControlParams
    from immersim.models.platform.cueing import NW, NWM, WashoutParams
    from immersim.models.platform.dynamics import NP
    from immersim.models.platform.params import PlatformParams

    w = wrapper_module()
    variables = w.platform.VARIABLES
    n = len(variables)
    if sorted(vr_of.values()) != list(range(n)):
        raise BuildError(f"unit {NAME}: value references are not 0..{n - 1}")
    by_vr = sorted(variables, key=lambda v: vr_of[v.name])

    def vrs(names) -> str:
        return "{" + ", ".join(str(vr_of[x]) for x in names) + "}"

    def vr_name(name: str) -> str:
        return "PLATFORM_VR_" + name.upper().replace(".", "_")

    platform_names = [f.name for f in fields(PlatformParams)]
    control_names = [f.name for f in fields(ControlParams)]
    washout_names = ["washout." + f.name for f in fields(WashoutParams)]
    if len(platform_names) != NP or len(control_names) != NC:
        raise BuildError(f"unit {NAME}: parameter vectors do not match the model's NP = {NP}, NC = {NC}")
    L = ["/* generated by immersim.orchestrator.native_build from the platform's Var declarations: do not edit */",
         "#ifndef PLATFORM_NATIVE_H", "#define PLATFORM_NATIVE_H", "",
         f"#define PLATFORM_MODEL_NAME {_c_str(NAME)}", f"#define PLATFORM_GUID {_c_str(guid)}",
         f"#define PLATFORM_NVARS {n}", f"#define PLATFORM_NW {NW}", f"#define PLATFORM_NWM {NWM}",
         f"#define PLATFORM_NIN {ms.NIN}", f"#define PLATFORM_NCTRL {ms.NCTRL}", f"#define PLATFORM_NSTATE {ms.NSTATE}",
         f"#define PLATFORM_NOUT {ms.NOUT}", f"#define PLATFORM_NP {NP}", f"#define PLATFORM_NC {NC}",
         f"#define PLATFORM_NWP {len(washout_names)}",
         f"#define PLATFORM_NREAL_OUT {len(w.PACKED_REAL_OUTPUTS)}", f"#define PLATFORM_NFLAGS {len(w.FLAG_OUTPUTS)}",
         f"#define PLATFORM_OFF_X {ms.X.start}", f"#define PLATFORM_OFF_W {ms.W.start}",
         f"#define PLATFORM_OFF_U {ms.U.start}", f"#define PLATFORM_OFF_RAW {ms.RAW.start}",
         f"#define PLATFORM_OFF_REACH {ms.REACH.start}",
         f"#define PLATFORM_OUT_AT_REST {ms.OUT['at_rest']}", f"#define PLATFORM_OUT_X_FINITE {ms.OUT['x_finite']}",
         f"#define PLATFORM_OUT_STROKE_FINITE {ms.OUT['stroke_finite']}",
         f"#define PLATFORM_TIME_RTOL {_c_double(w.platform.TIME_RTOL)}",
         f"#define PLATFORM_DRIVER_SZ_ARG {max(p[2][1] for p in parts)}",
         f"#define PLATFORM_DRIVER_SZ_RES {max(p[2][2] for p in parts)}", ""]
    for name in ("cueing", "control", "model", "integrator", "substeps", "rtol", "atol", "on_workspace",
                 "cos_beta_min", "size_z", "payload_mass", "stroke_min", "stroke_max"):
        L.append(f"#define {vr_name(name)} {vr_of[name]}")
    L += ["", "void platform_washout_matrices(const double* wp, double h, double* wm);", "",
          "#ifdef PLATFORM_NATIVE_TABLES",
          "enum { PT_REAL, PT_INTEGER, PT_BOOLEAN, PT_STRING };",
          "enum { PC_PARAMETER, PC_INPUT, PC_OUTPUT, PC_LOCAL };",
          "typedef struct { const char* name; int type, causality; double real_start; int int_start; "
          "const char* str_start; } platform_var;",
          "static const platform_var PLATFORM_VARS[PLATFORM_NVARS] = {"]
    for v in by_vr:
        real = float(v.start) if v.type == "Real" else 0.0
        integer = int(v.start) if v.type in ("Integer", "Boolean") else 0
        text = _c_str(str(v.start)) if v.type == "String" else "0"
        L.append(f"  {{{_c_str(v.name)}, {_TYPE[v.type]}, {_CAUS[v.causality]}, {_c_double(real)}, {integer}, {text}}},"
                 f"  /* vr {vr_of[v.name]} */")
    L += ["};",
          f"static const int PLATFORM_IN_VR[PLATFORM_NIN] = {vrs(w.PACKED_INPUTS)};",
          f"static const int PLATFORM_OUT_VR[PLATFORM_NREAL_OUT] = {vrs(w.PACKED_REAL_OUTPUTS)};",
          f"static const int PLATFORM_FLAG_VR[PLATFORM_NFLAGS] = {vrs([f[0] for f in w.FLAG_OUTPUTS])};",
          "static const int PLATFORM_FLAG_OUT[PLATFORM_NFLAGS] = {" + ", ".join(str(f[1]) for f in w.FLAG_OUTPUTS) + "};",
          f"static const int PLATFORM_P_VR[PLATFORM_NP] = {vrs(platform_names)};",
          f"static const int PLATFORM_C_VR[PLATFORM_NC] = {vrs(control_names)};",
          f"static const int PLATFORM_WASHOUT_VR[PLATFORM_NWP] = {vrs(washout_names)};",
          "typedef struct { const char* label; int vr; } platform_positive;",
          "static const platform_positive PLATFORM_POSITIVE[] = {"]
    for cls, prefix, names in POSITIVE:
        L += [f"  {{{_c_str(f'{cls}.{x}')}, {vr_of[prefix + x]}}}," for x in names]
    L += ["  {0, -1}", "};",
          "typedef struct { int vr; const char* const* python; const char* const* supported; const char* python_text;"
          " const char* supported_text; } platform_choice;"]
    rows = []
    for k, (name, allowed) in enumerate(_choices().items()):
        supported = NATIVE_CHOICES.get(name, allowed)
        L.append(f"static const char* const PLATFORM_CHOICE{k}_PY[] = {{{', '.join(map(_c_str, allowed))}, 0}};")
        L.append(f"static const char* const PLATFORM_CHOICE{k}_NATIVE[] = {{{', '.join(map(_c_str, supported))}, 0}};")
        rows.append(f"  {{{vr_of[name]}, PLATFORM_CHOICE{k}_PY, PLATFORM_CHOICE{k}_NATIVE, {_c_str(', '.join(allowed))}, "
                    f"{_c_str(', '.join(supported))}}},")
    L += ["static const platform_choice PLATFORM_CHOICES[] = {", *rows, "  {-1, 0, 0, 0, 0}", "};", "",
          "typedef int (*platform_driver_fn)(const double** arg, double** res, long long* iw, double* w);",
          "typedef int (*platform_casadi_fn)(const double** arg, double** res, long long* iw, double* w, int mem);",
          "typedef int (*platform_work_fn)(long long* sz_arg, long long* sz_res, long long* sz_iw, long long* sz_w);",
          "typedef struct { const char* control; platform_driver_fn driver; platform_casadi_fn post;"
          " platform_work_fn work[4]; } platform_macro;"]
    table = []
    for control, fns, driver, _ in parts:
        L.append(f"int {driver[0]}(const double** arg, double** res, long long* iw, double* w);")
        L.append(f"int {fns[3].name()}(const double** arg, double** res, long long* iw, double* w, int mem);")
        for f in fns:
            L.append(f"int {f.name()}_work(long long* sz_arg, long long* sz_res, long long* sz_iw, long long* sz_w);")
        table.append(f"  {{{_c_str(control)}, {driver[0]}, {fns[3].name()}, "
                     f"{{{', '.join(f.name() + '_work' for f in fns)}}}}},")
    L += [f"#define PLATFORM_NMACROS {len(parts)}", "static const platform_macro PLATFORM_MACROS[PLATFORM_NMACROS] = {",
          *table, "};", "#endif /* PLATFORM_NATIVE_TABLES */", "", "#endif", ""]
    return "\n".join(L)


def _python_slave():
    """An instance of the Python wrapper (only to render its model description)."""
    w = wrapper_module()
    with tempfile.TemporaryDirectory(prefix="immersim_native_md_") as tmp:
        return w.platform(instance_name="native_build", resources=tmp)


def model_description(slave, guid: str, source_files: List[str]) -> bytes:
    """The Python build's ``modelDescription.xml`` with this build's name, GUID and binary."""
    root = slave.to_xml()
    root.set("modelName", NAME)
    root.set("guid", guid)
    root.set("generationTool", "immersim native build (CasADi C + FMI 2.0 C layer)")
    root.set("description", type(slave).description + " (native build: no Python at run time)")
    cosim = root.find("CoSimulation")
    for key, value in (("modelIdentifier", IDENTIFIER), ("needsExecutionTool", "false"),
                       ("canNotUseMemoryManagementFunctions", "false")):
        cosim.set(key, value)
    files = SubElement(cosim, "SourceFiles")
    for name in source_files:
        SubElement(files, "File", name=name)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + tostring(root, encoding="utf-8")


def _inputs_digest() -> str:
    """sha256 of everything the build reads: the model and wrapper sources, the C layer, this
    module, the casadi version and the compiler flags."""
    import casadi

    from immersim.models.platform.codegen import CFLAGS

    from .build import _fmus_dir, _models_dir, _py_files

    import pythonfmu

    versions = f"casadi {casadi.__version__} pythonfmu {pythonfmu.__version__}"
    h = hashlib.sha256(f"{versions}\n{' '.join(CFLAGS + EXTRA_CFLAGS)}\n".encode())
    paths = list(_py_files(_models_dir() / UNIT)) + list(_py_files(_fmus_dir() / "common"))
    paths += [_fmus_dir() / UNIT / f"{UNIT}_fmu.py", Path(__file__)] + sorted(native_dir().glob("*.[ch]"))
    for p in paths:
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def _platform_folder() -> str:
    if _platform.system() != "Linux" or _platform.machine() not in ("x86_64", "AMD64"):
        raise BuildError(f"unit {NAME}: the build compiles binaries/linux64 only (this is {_platform.system()} "
                         f"{_platform.machine()}); its sources/ compile with any C99 compiler")
    return "linux64"


def build_native(dest_dir: Path | str | None = None, force: bool = False) -> Path:
    """Build ``dest_dir/platform-native.fmu`` unless it is up to date; returns its path.

    Raises :class:`BuildError` naming the unit when there is no C compiler or compiling fails.
    """
    from immersim.models.platform.codegen import CFLAGS, compiler

    from .build import fmu_target

    digest = _inputs_digest()
    fmu, stamp, current = fmu_target(NAME, dest_dir, digest, force)
    if current:
        return fmu
    folder = _platform_folder()
    missing = [n for n in ("fmi2_platform.c", "platform_model.c", "washout.c") if not (native_dir() / n).exists()]
    if missing:
        raise BuildError(f"unit {NAME}: the C layer is not installed ({', '.join(missing)} missing in {native_dir()})")
    cc = compiler()
    if cc is None:
        raise BuildError(f"unit {NAME}: no C compiler found ($CC, gcc or cc)")
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"immersim:{NAME}:{digest}")) + "}"
    slave = _python_slave()
    vr_of = {sv.name: sv.value_reference for sv in slave.vars.values()}
    parts = macros()
    sources: Dict[str, bytes] = {f"{IDENTIFIER}_{control}.c": src.encode() for control, _, _, src in parts}
    sources["platform_native.h"] = header(vr_of, guid, parts).encode()
    for p in sorted(native_dir().glob("*.[ch]")):
        sources[p.name] = p.read_bytes()
    for name in ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"):
        sources[name] = (fmi_headers() / name).read_bytes()
    c_files = sorted(n for n in sources if n.endswith(".c"))
    with tempfile.TemporaryDirectory(prefix="immersim_native_") as tmp:
        src_dir, out = Path(tmp) / "sources", Path(tmp) / f"{IDENTIFIER}.so"
        src_dir.mkdir()
        for name, data in sources.items():
            (src_dir / name).write_bytes(data)
        cmd = [cc, *CFLAGS, *EXTRA_CFLAGS, f"-I{src_dir}", *[str(src_dir / n) for n in c_files], "-o", str(out), "-lm"]
        log.info("unit %s: compiling %s", NAME, " ".join(c_files))
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise BuildError(f"unit {NAME}: compiling the native FMU failed: {proc.stderr.strip()[-2000:]}")
        staged = Path(tmp) / fmu.name
        with zipfile.ZipFile(staged, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("modelDescription.xml", model_description(slave, guid, c_files))
            z.write(out, f"binaries/{folder}/{IDENTIFIER}.so")
            for name, data in sorted(sources.items()):
                z.writestr(f"sources/{name}", data)
        shutil.move(str(staged), fmu)
    stamp.write_text(digest + "\n")
    log.info("unit %s: built %s", NAME, fmu)
    return fmu


if __name__ == "__main__":  # pragma: no cover - manual builds
    logging.basicConfig(level=logging.INFO)
    print(build_native(os.environ.get("IMMERSIM_BUILD_DIR")))
