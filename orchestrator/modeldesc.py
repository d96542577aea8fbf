"""FMU model descriptions: read and validate one without loading it, and refuse at load an
archive that cannot run here.

:func:`read_model` parses ``modelDescription.xml`` with FMPy (validated) and describes each
variable as a :class:`VarInfo`; :func:`check_archive` checks the binary of this platform and,
for a pythonfmu FMU, the slave module it names. Both raise
:class:`~immersim.orchestrator.errors.FmuLoadError` with one line naming the unit and the file.
"""
from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict

from . import extraction
from .errors import FmuLoadError

#: type families that may be connected to each other
_FAMILY = {
    "Real": "float", "Float64": "float", "Float32": "float",
    "Integer": "int", "Enumeration": "int", "Int8": "int", "UInt8": "int", "Int16": "int",
    "UInt16": "int", "Int32": "int", "UInt32": "int", "Int64": "int", "UInt64": "int",
    "Boolean": "bool", "String": "string", "Binary": "binary",
}


@dataclass(frozen=True)
class VarInfo:
    """What the master knows of one FMU variable."""

    name: str
    vr: int
    type: str
    causality: str
    variability: str
    unit: str
    start: Any
    description: str
    initial: str = ""       # "exact", "approx", "calculated" or "" (the standard's default)
    shape: tuple = ()       # FMI 3.0 array element: the array's shape (fmi3.variables)
    index: int = -1         # FMI 3.0 array element: its flat (row-major) position, else -1

    @property
    def family(self) -> str:
        return _FAMILY.get(self.type, self.type)


#: parsed model descriptions by (path, mtime, size): a scenario reads each FMU at check time
#: and again when it instantiates it, often several instances of one FMU
_MODELS: Dict[tuple, tuple] = {}


def read_model(path: Path, unit: str):
    """Read and validate an FMU's model description without instantiating it.

    A file read before (same path, modification time and size) is not parsed again, nor an
    FMI 2.0 file of the same content read by an earlier run (kept in its cache entry,
    :func:`.extraction.store_model`).

    Returns
    -------
    (fmpy ModelDescription, dict of name -> VarInfo)
    """
    try:
        st = os.stat(path)
        key = (os.path.abspath(path), st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    if key in _MODELS:
        md, variables = _MODELS[key]
        return md, dict(variables)
    stored = extraction.stored_model(path) if key is not None else None
    if stored is not None:
        md, variables = stored
    else:
        md, variables = _read_model(path, unit)
        if key is not None and md.fmiVersion.startswith("2"):
            extraction.store_model(path, (md, variables))
    if key is not None:
        if len(_MODELS) >= 64:
            _MODELS.clear()
        _MODELS[key] = md, variables
    return md, dict(variables)


def _read_model(path: Path, unit: str):
    import fmpy
    from fmpy.model_description import ValidationError

    if not zipfile.is_zipfile(path):
        raise FmuLoadError(f"unit {unit}: FMU file {path} is not a valid zip archive (corrupt or not an FMU)")
    try:
        md = fmpy.read_model_description(str(path), validate=True)
    except ValidationError as exc:
        raise FmuLoadError(f"unit {unit}: {path}: invalid modelDescription.xml: {exc}") from exc
    except Exception as exc:
        raise FmuLoadError(f"unit {unit}: {path}: cannot read modelDescription.xml: {exc}") from exc
    if md.fmiVersion.startswith("3"):
        from . import fmi3

        fmi3.check_supported(md, path, unit)
    if md.coSimulation is None:
        raise FmuLoadError(f"unit {unit}: {path} is not a co-simulation FMU")
    check_archive(path, md, unit)
    if md.fmiVersion.startswith("3"):
        return md, fmi3.variables(md)
    variables = {}
    for v in md.modelVariables:
        variables[v.name] = VarInfo(v.name, v.valueReference, v.type, v.causality or "local",
                                    v.variability or "", _unit_of(v), v.start, v.description or "",
                                    initial=v.initial or "")
    return md, variables


def _unit_of(v: Any) -> str:
    """A model variable's unit, or its declared type's."""
    declared = getattr(v, "declaredType", None)
    return v.unit or (getattr(declared, "unit", None) if declared is not None else None) or ""


def check_archive(path: Path, md: Any, unit: str) -> None:
    """Refuse at load an FMU whose archive cannot run here: no binary of its
    ``modelIdentifier`` for this platform (FMI 2.0 ``binaries/linux64/<id>.so``, FMI 3.0
    ``binaries/x86_64-linux/<id>.so``), or, for a pythonfmu FMU, a ``resources/slavemodule.txt``
    that is missing, empty or names a module the archive lacks (pythonfmu's binary crashes the
    process on those). Raises :class:`~immersim.orchestrator.errors.FmuLoadError`."""
    import fmpy

    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        mid = md.coSimulation.modelIdentifier
        folder = fmpy.platform if md.fmiVersion.startswith("2") else fmpy.platform_tuple
        binary = f"binaries/{folder}/{mid}{fmpy.sharedLibraryExtension}"
        if binary not in names:
            have = sorted({n.split("/")[1] for n in names if n.startswith("binaries/") and n.count("/") >= 2})
            others = sorted(n for n in names if n.startswith(f"binaries/{folder}/") and not n.endswith("/"))
            raise FmuLoadError(
                f"unit {unit}: FMU {path} has no binary for {folder}: "
                f"{binary} (modelIdentifier {mid!r}) is not in the archive"
                + (f"; it has {', '.join(others)}" if others else f"; platforms: {', '.join(have) or 'none'}"))
        if (getattr(md, "generationTool", None) or "").startswith("PythonFMU"):
            where = f"unit {unit}: pythonfmu FMU {path}"
            if "resources/slavemodule.txt" not in names:
                raise FmuLoadError(f"{where}: resources/slavemodule.txt is missing (it names the slave's module)")
            module = z.read("resources/slavemodule.txt").decode("utf-8", "replace").strip()
            if not module:
                raise FmuLoadError(f"{where}: resources/slavemodule.txt names no module")
            if f"resources/{module}.py" not in names:
                raise FmuLoadError(f"{where}: resources/{module}.py is missing (named by resources/slavemodule.txt)")
