"""Checked scenarios kept between runs: a scenario file read again is not checked again.

Checking a scenario (:func:`.scenario.parse_scenario`) needs the schema's pydantic models
(:mod:`.schema`): importing pydantic and building its validators takes far longer than the
check itself, and a large share of a short run's start. :func:`store` keeps the checked
:class:`~.scenario.Scenario` in the user's cache folder (``scenarios/<key>.pickle``) and
:func:`load` returns it when the same file is read again, without importing the schema.

* The key is the digest of the file's path (as given) and text, the overrides, the Python
  version and the code that makes a Scenario from them (:func:`code_version`: the loader's
  modules' sources and the installed pydantic's). An entry also holds the texts of the files the
  scenario includes; a hit reads them again and is used only when each is unchanged.
* Only a scenario that passed its check is stored, so errors are always reported by the
  check itself. An entry is written to a temporary file and renamed into place; an entry that
  cannot be read is ignored (and replaced by the next store). The cache keeps the
  :data:`KEEP` entries used last (a hit touches its entry).
* ``IMMERSIM_SCENARIO_CACHE=0`` turns the cache off; ``IMMERSIM_SCENARIO_CACHE=<folder>``
  moves it.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import logging
import os
import pickle
import sys
import time
from pathlib import Path
from typing import Any, Dict, Optional

from ..models.cachefiles import cache_folder, write_atomic

log = logging.getLogger(__name__)

__all__ = ["KEEP", "cache_root", "code_version", "load", "store"]

#: entries kept in the cache (the ones used last)
KEEP = 256
#: the modules whose code shapes a checked Scenario (this package's)
_SOURCES = ("scenario", "schema", "expand", "include", "tomlfiles", "errors", "foxglove", "live",
            "scenariocache")


def cache_root() -> Optional[Path]:
    """The cache's folder: ``$IMMERSIM_SCENARIO_CACHE``, else ``scenarios/`` in the user's
    cache folder; None when ``IMMERSIM_SCENARIO_CACHE`` is ``0`` (no cache)."""
    return cache_folder("IMMERSIM_SCENARIO_CACHE", "scenarios")


@functools.lru_cache(maxsize=None)
def code_version() -> str:
    """A digest of the code that checks a scenario: the sources of the loader's modules
    (:data:`_SOURCES`), the installed pydantic (its ``version.py``: path, size and content
    time), and the Python version. Another version leaves older entries unused."""
    h = hashlib.sha256(sys.version.encode())
    here = Path(__file__).parent
    for name in _SOURCES:
        h.update((here / f"{name}.py").read_bytes())
    spec = importlib.util.find_spec("pydantic")
    if spec is not None and spec.origin:
        ver = Path(spec.origin).parent / "version.py"
        st = os.stat(ver)
        h.update(f"{ver}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()


def _entry(path: Path, text: str, overrides: Optional[Dict[str, Any]]) -> Optional[Path]:
    root = cache_root()
    if root is None:
        return None
    key = repr((code_version(), str(path), text, list((overrides or {}).items())))
    return root / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.pickle"


def load(path: Path, text: str, overrides: Optional[Dict[str, Any]] = None):
    """The Scenario :func:`store` kept for scenario file ``path`` with ``text`` and
    ``overrides``, when every file it includes still holds the text it had; else None.
    Never raises for a missing, cut or unreadable entry (None)."""
    try:
        entry = _entry(path, text, overrides)
        if entry is None or not entry.is_file():
            return None
        with open(entry, "rb") as f:
            sc = pickle.load(f)
        for file, was in sc.included.items():
            if Path(file).read_bytes().decode("utf-8") != was:
                return None
        _touch(entry)
        return sc
    except Exception as exc:   # (a damaged entry, an included file gone: check the file again)
        log.debug("scenario cache: %s not used: %s", path, exc)
        return None


def store(sc, overrides: Optional[Dict[str, Any]] = None) -> None:
    """Keep the checked Scenario ``sc`` (as :func:`.scenario.parse_scenario` returned it for
    its file ``sc.file``, text ``sc.text`` and ``overrides``) for :func:`load`; removes the
    entries used longest ago beyond :data:`KEEP`. A cache that cannot be written is skipped."""
    try:
        entry = _entry(sc.file, sc.text, overrides)
        if entry is None:
            return
        data = pickle.dumps(sc, protocol=pickle.HIGHEST_PROTOCOL)
        entry.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(entry, lambda f: f.write(data))
        _touch(entry)
        _prune(entry.parent)
    except Exception as exc:
        log.debug("scenario cache: %s not stored: %s", sc.file, exc)


def _touch(entry: Path) -> None:
    """Mark ``entry`` used now (the clock's own resolution: file systems keep coarser times)."""
    now = time.time_ns()
    os.utime(entry, ns=(now, now))


def _prune(root: Path) -> None:
    entries = [p for p in root.iterdir() if p.suffix == ".pickle"]
    if len(entries) <= KEEP:
        return
    entries.sort(key=lambda p: p.stat().st_mtime_ns)
    for p in entries[:len(entries) - KEEP]:
        try:
            p.unlink()
        except OSError:
            pass
