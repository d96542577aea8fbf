"""Build unit folders ``fmus/<unit>/`` into FMI 2.0 co-simulation FMUs with pythonfmu.

A unit folder holds one wrapper script ``<unit>_fmu.py`` (a :class:`TableSlave` subclass),
its README and reference output. The FMU packs the script, ``immersim.fmus.common`` and the
whole ``immersim.models`` package into ``resources/`` so that, at run time, the FMU needs only
the third-party packages. Builds are incremental: an FMU is rebuilt only when the sha256 of
its sources (and of the pythonfmu version) changes.

Sized builds: a unit declares its capacities as build options (``BUILD_OPTIONS`` in its
wrapper, :mod:`immersim.fmus.common.options`). ``build_unit(..., options={"players": 8})``
checks them, writes them into the packed copy (``fmus/common/build_options.json``), where the
wrapper reads them when it declares its variables, and names the FMU after them
(``network-players8.fmu``). The options are part of the digest; options equal to their
defaults are dropped, so a default build is the plain ``<unit>.fmu``.

Code isolation: pythonfmu FMUs share the interpreter of the master that loads them, and Python
imports a module name once per process. So that an FMU always runs the code it was built
from -- not the ``immersim`` the master imported, nor another build loaded earlier (an
ablation that swaps a unit for an older FMU of it) -- the packed package is named
``immersim_<digest>`` and the script ``<unit>_fmu_<digest>`` (12 hex digits of the source
digest), and the script's ``immersim.`` imports are rewritten to it. Instances of one build
share their modules; different builds never do.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import sys
import tempfile
import zipfile
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Iterable, List, Mapping, Optional

from .errors import BuildError

log = logging.getLogger(__name__)

LAYOUT = 2  #: archive layout version, part of the build digest (2: per-build package names)

def _models_dir() -> Path:
    import immersim.models  # the installed location, editable or not

    return Path(immersim.models.__file__).resolve().parent


def _fmus_dir() -> Path:
    import immersim.fmus

    return Path(immersim.fmus.__file__).resolve().parent


def user_cache_dir() -> Path:
    """immersim's folder in the user's cache (:func:`immersim.models.cachefiles.user_cache_dir`)."""
    from ..models.cachefiles import user_cache_dir

    return user_cache_dir()


def default_build_dir() -> Path:
    """Where built FMUs go: ``$IMMERSIM_BUILD_DIR``, else ``build/fmus`` of the checkout,
    else ``fmus/`` in :func:`user_cache_dir` for an installed package (a wheel)."""
    env = os.environ.get("IMMERSIM_BUILD_DIR")
    if env:
        return Path(env)
    root = _fmus_dir().parent
    if (root / "pyproject.toml").exists():
        return root / "build" / "fmus"
    return user_cache_dir() / "fmus"


def unit_names() -> List[str]:
    """Names of the built-in units (folders ``fmus/<unit>/`` with a ``<unit>_fmu.py``)."""
    return sorted(p.parent.name for p in _fmus_dir().glob("*/*_fmu.py") if p.stem == f"{p.parent.name}_fmu")


def _py_files(folder: Path) -> Iterable[Path]:
    return sorted(p for p in folder.rglob("*.py") if "__pycache__" not in p.parts)


@dataclass
class UnitSources:
    """The files one FMU is made of, relative to the FMU's ``resources/`` folder."""

    script: Path
    files: List[tuple]  # (source path, archive path relative to resources)

    def digest(self, options: str = "") -> str:
        """sha256 of the sources, the pythonfmu version, the layout and the build ``options``
        (their JSON; none: the digest of a default build)."""
        import pythonfmu

        h = hashlib.sha256(f"pythonfmu {pythonfmu.__version__}\nlayout {LAYOUT}\n".encode())
        for src, arc in sorted(self.files, key=lambda f: str(f[1])):
            h.update(str(arc).encode() + b"\0" + src.read_bytes() + b"\0")
        if options:
            h.update(b"options\0" + options.encode())
        return h.hexdigest()


def unit_sources(unit_dir: Path) -> UnitSources:
    """Collect the script of ``unit_dir`` and the immersim packages it is packed with."""
    unit_dir = Path(unit_dir).resolve()
    script = unit_dir / f"{unit_dir.name}_fmu.py"
    if not script.exists():
        raise BuildError(f"unit folder {unit_dir}: no wrapper script {script.name}")
    files = [(script, Path(script.name))]
    for extra in sorted(unit_dir.glob("*.py")):
        if extra != script:
            files.append((extra, Path(extra.name)))
    common = _fmus_dir() / "common"
    files.append((_fmus_dir() / "__init__.py", Path("immersim/fmus/__init__.py")))
    files += [(p, Path("immersim/fmus/common") / p.relative_to(common)) for p in _py_files(common)]
    models = _models_dir()
    files += [(p, Path("immersim/models") / p.relative_to(models)) for p in _py_files(models)]
    for data in sorted(models.rglob("*.json")):
        files.append((data, Path("immersim/models") / data.relative_to(models)))
    return UnitSources(script, files)


def fmu_target(name: str, dest_dir: Path | str | None, digest: str, force: bool) -> tuple:
    """``(fmu, stamp, current)``: the path of ``dest_dir/<name>.fmu`` (``dest_dir`` created,
    :func:`default_build_dir` by default), of its sha256 stamp, and whether the FMU is up to
    date with the inputs' ``digest`` (never when ``force``)."""
    dest_dir = Path(dest_dir) if dest_dir is not None else default_build_dir()
    dest_dir.mkdir(parents=True, exist_ok=True)
    fmu, stamp = dest_dir / f"{name}.fmu", dest_dir / f"{name}.fmu.sha256"
    current = not force and fmu.exists() and stamp.exists() and stamp.read_text().strip() == digest
    if current:
        log.info("unit %s: up to date (%s)", name, fmu)
    return fmu, stamp, current


def unit_options(unit_dir: Path | str, given: Optional[Mapping[str, Any]] = None,
                 who: Optional[str] = None) -> Dict[str, int]:
    """The build options of ``given`` that differ from their defaults, checked against the
    unit's ``BUILD_OPTIONS`` (read from its wrapper); :class:`BuildError` with one line naming
    the unit (``who``, by default ``unit <name>``) and the option for an unknown option or a
    value out of range."""
    if not given:
        return {}
    from immersim.fmus.common.options import check_options

    unit_dir = Path(unit_dir).resolve()
    script = unit_dir / f"{unit_dir.name}_fmu.py"
    if not script.exists():
        raise BuildError(f"unit folder {unit_dir}: no wrapper script {script.name}")
    declared = declared_options(script)
    try:
        values = check_options(who or f"unit {unit_dir.name}", declared, given)
    except ValueError as exc:
        raise BuildError(str(exc)) from None
    defaults = {o.name: o.default for o in declared}
    return {k: v for k, v in sorted(values.items()) if v != defaults[k]}


def declared_options(script: Path) -> tuple:
    """The ``BuildOption`` declarations of a wrapper script's ``BUILD_OPTIONS = (BuildOption(...),
    ...)``, read from its source without running it (no import of the unit's model): each
    argument must be a literal. None declared: ``()``."""
    import ast

    from immersim.fmus.common.options import BuildOption

    for node in ast.parse(script.read_text(), str(script)).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "BUILD_OPTIONS" for t in node.targets):
            try:
                return tuple(BuildOption(*map(ast.literal_eval, call.args),
                                         **{k.arg: ast.literal_eval(k.value) for k in call.keywords})
                             for call in node.value.elts)
            except (AttributeError, TypeError, ValueError) as exc:
                raise BuildError(f"{script}: BUILD_OPTIONS must be a tuple of BuildOption(...) with literal "
                                 f"arguments ({exc})") from None
    return ()


def parse_options(items: Iterable[str]) -> Dict[str, int]:
    """``["players=8", ...]`` (``immersim build --option``) as ``{"players": 8}``."""
    out: Dict[str, int] = {}
    for item in items:
        name, eq, value = item.partition("=")
        try:
            out[name.strip()] = int(value)
        except ValueError:
            raise BuildError(f"--option {item}: expected NAME=INTEGER, e.g. players=8") from None
        if not eq or not name.strip():
            raise BuildError(f"--option {item}: expected NAME=INTEGER, e.g. players=8")
    return out


def sized_name(unit: str, options: Mapping[str, int]) -> str:
    """The FMU file name (without ``.fmu``) of a build: ``network``, ``network-players8``."""
    return "-".join([unit] + [f"{k}{v}" for k, v in sorted(options.items())])


def build_unit(unit_dir: Path | str, dest_dir: Path | str | None = None, force: bool = False,
               options: Optional[Mapping[str, Any]] = None) -> Path:
    """Build ``unit_dir`` into ``dest_dir/<unit>.fmu`` unless it is up to date.

    ``options`` (e.g. ``{"players": 8}``) sizes the unit (see the module docstring); a build
    with options other than the defaults goes to ``dest_dir/<unit>-<option><value>....fmu``.
    Returns the FMU path. Raises :class:`BuildError` naming the unit on any failure.
    """
    from pythonfmu.builder import FmuBuilder

    from immersim.fmus.common.options import CHOSEN_FILE

    from .fmu import forget_python_code

    unit_dir = Path(unit_dir).resolve()
    sources = unit_sources(unit_dir)
    sized = unit_options(unit_dir, options)
    chosen = json.dumps({"unit": unit_dir.name, "options": sized}, sort_keys=True) if sized else ""
    digest = sources.digest(chosen)
    fmu, stamp, current = fmu_target(sized_name(unit_dir.name, sized), dest_dir, digest, force)
    if current:
        return fmu
    package, script_name = packed_names(unit_dir.name, digest)
    with tempfile.TemporaryDirectory(prefix=f"immersim_build_{unit_dir.name}_") as tmp:
        stage = Path(tmp) / "stage"
        for src, arc in sources.files:
            if arc.parts[0] == "immersim":  # the packed package, under its build's own name
                target = stage / package / Path(*arc.parts[1:])
            elif src == sources.script:
                target = stage / script_name
            else:
                target = stage / arc
            target.parent.mkdir(parents=True, exist_ok=True)
            if arc.parent == Path("."):  # the unit's own scripts: absolute imports of the package
                target.write_text(_IMPORTS.sub(package + ".", src.read_text()))
            else:
                shutil.copy2(src, target)
        if chosen:   # read by immersim.fmus.common.options when the wrapper declares its variables
            (stage / package / "fmus" / "common" / CHOSEN_FILE).write_text(chosen + "\n")
        script = stage / script_name
        extra = [stage / package] + [stage / arc for _, arc in sources.files[1:] if arc.parent == Path(".")]
        out = Path(tmp) / "out"
        # pythonfmu imports the script by module name: keep sys.path and sys.modules clean
        saved_path = list(sys.path)
        try:
            built = FmuBuilder.build_FMU(script, dest=out, project_files=extra)
        except Exception as exc:
            raise BuildError(f"unit {unit_dir.name}: pythonfmu build of {sources.script} failed: {exc}") from exc
        finally:
            sys.path[:] = saved_path
            forget_python_code(stage)  # the modules the build imported from the stage, about to go
        if built.stem != unit_dir.name:
            raise BuildError(
                f"unit {unit_dir.name}: the wrapper's modelName is {built.stem!r}; it must equal the folder name")
        _check_archive(built, unit_dir.name, package, script_name)
        shutil.move(str(built), fmu)
    stamp.write_text(digest + "\n")
    log.info("unit %s: built %s%s", unit_dir.name, fmu, f" ({chosen})" if chosen else "")
    return fmu


_IMPORTS = re.compile(r"\bimmersim\.(?=(?:fmus|models)\b)")


def packed_names(unit: str, digest: str) -> tuple:
    """Names of the packed package and wrapper script of one build (see the module docstring)."""
    tag = digest[:12]
    return f"immersim_{tag}", f"{unit}_fmu_{tag}.py"


def _check_archive(fmu: Path, unit: str, package: str, script_name: str) -> None:
    with zipfile.ZipFile(fmu) as z:
        names = set(z.namelist())
    for needed in ("modelDescription.xml", f"resources/{script_name}", f"resources/{package}/models/__init__.py"):
        if needed not in names:
            raise BuildError(f"unit {unit}: built FMU lacks {needed}")


#: built-in units compiled to native code (no Python at run time), see :mod:`.native_build`
NATIVE_UNITS = ("platform-native",)


def builtin_names() -> List[str]:
    """Every built-in unit name a scenario may use: the unit folders and :data:`NATIVE_UNITS`."""
    return unit_names() + list(NATIVE_UNITS)


def build_all(units: Optional[Iterable[str]] = None, dest_dir: Path | str | None = None,
              force: bool = False, options: Optional[Mapping[str, Any]] = None) -> List[Path]:
    """Build the named built-in units (all by default, the native ones included), each with
    the build ``options`` (see :func:`build_unit`; only for named units with options)."""
    from .native_build import build_native

    if options and not units:
        raise BuildError("build options need the units they size: name them (immersim build network --option ...)")
    names = list(units) if units else builtin_names()
    if not units:   # (codegen imports casadi: only when every unit is asked for)
        from immersim.models.platform.codegen import compiler

        if compiler() is None:
            log.warning("no C compiler ($CC, gcc or cc): the native units %s are not built", ", ".join(NATIVE_UNITS))
            names = unit_names()
    known = builtin_names()
    for name in names:
        if name not in known:
            raise BuildError(f"unknown unit {name!r}; built-in units are {', '.join(known) or 'none'}")
    if options:
        for name in names:
            check_build_options(name, options)
    return [build_native(dest_dir, force) if name in NATIVE_UNITS
            else build_unit(_fmus_dir() / name, dest_dir, force, options) for name in names]


def check_build_options(name: str, options: Mapping[str, Any], who: Optional[str] = None) -> Dict[str, int]:
    """:func:`unit_options` of the built-in unit ``name`` (a native unit takes none)."""
    if name in NATIVE_UNITS:
        raise BuildError(f"{who or f'unit {name}'}: takes no build options")
    return unit_options(_fmus_dir() / name, options, who)


def capacity_hint(name: str, options: Optional[Mapping[str, Any]] = None) -> str:
    """For an error about a variable a built-in unit lacks: ``" (built with players = 4,
    entity_outputs = 16; build = { ... } in its [[units]] table sizes it)"``, or ``""`` for
    a unit without build options (or not built in)."""
    if name not in unit_names():
        return ""
    declared = declared_options(_fmus_dir() / name / f"{name}_fmu.py")
    if not declared:
        return ""
    built = ", ".join(f"{o.name} = {(options or {}).get(o.name, o.default)}" for o in declared)
    return f" (built with {built}; build = {{ ... }} in its [[units]] table sizes it)"
