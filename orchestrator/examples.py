"""The example scenarios shipped with immersim (``immersim examples``).

The folder ``scenarios/`` of the source tree installs as the package data
``immersim/scenarios``; in a checkout it is the same folder. Sweep files keep their place in
``sweeps/`` so that their relative ``scenario = "../x.toml"`` still holds after a copy.
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Sequence

from .errors import ScenarioError
from .scenario import tomllib


def examples_dir() -> Path:
    """The folder of the shipped example scenarios (installed package or checkout)."""
    import immersim.fmus  # its parent is the installed ``immersim`` folder, or the checkout

    return Path(immersim.fmus.__file__).resolve().parent.parent / "scenarios"


@dataclass(frozen=True)
class Example:
    """One shipped file: ``name`` is its path relative to :func:`examples_dir`."""

    name: str
    path: Path
    title: str


def list_examples() -> List[Example]:
    """Every shipped scenario and sweep file, scenarios first, each with its ``title`` (or
    ``description``) when the file has one."""
    root = examples_dir()
    files = sorted(root.rglob("*.toml"), key=lambda p: (len(p.relative_to(root).parts), str(p)))
    out = []
    for p in files:
        data = tomllib.loads(p.read_text())
        out.append(Example(p.relative_to(root).as_posix(), p, str(data.get("title") or data.get("description") or "")))
    return out


def _included(path: Path) -> List[Path]:
    """The files a shipped scenario includes (``include = [...]``), and theirs, as
    :func:`~immersim.orchestrator.include.compose` follows them."""
    from .include import compose
    from .tomlfiles import read_toml

    data, _ = read_toml(path, "scenario file")
    texts = compose(data, path, lambda f: read_toml(f, "scenario file") if f.is_file() else None)[2]
    return [Path(f).resolve() for f in texts]


def copy_examples(dest: Path | str, names: Optional[Sequence[str]] = None) -> List[Path]:
    """Copy the shipped files (all, or those named; a sweep brings its base scenario) to
    ``dest``, keeping the folder layout; an existing file is never overwritten.

    Returns the files written. Raises :class:`ScenarioError` for an unknown name or a file
    that exists already (before anything is copied).
    """
    dest = Path(dest)
    known = {e.name: e for e in list_examples()}
    wanted = list(known) if not names else []
    for n in names or []:
        key = n if n in known else f"{n}.toml" if f"{n}.toml" in known else None
        if key is None:
            raise ScenarioError(f"examples: no shipped scenario {n!r} (see immersim examples)")
        wanted.append(key)
        base = tomllib.loads(known[key].path.read_text()).get("scenario")
        if isinstance(base, str):  # a sweep file: its base scenario comes along
            rel = (known[key].path.parent / base).resolve().relative_to(examples_dir()).as_posix()
            wanted.append(rel)
    for n in list(wanted):   # and a scenario the files it includes
        wanted += [p.relative_to(examples_dir().resolve()).as_posix() for p in _included(known[n].path)]
    wanted = list(dict.fromkeys(wanted))
    for n in wanted:
        if (dest / n).exists():
            raise ScenarioError(f"examples: {dest / n} exists already; nothing copied")
    written = []
    for n in wanted:
        (dest / n).parent.mkdir(parents=True, exist_ok=True)
        written.append(Path(shutil.copyfile(known[n].path, dest / n)))
    return written
