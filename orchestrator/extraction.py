"""An FMU's files on disk: one extraction per FMU content, kept between runs.

Loading an FMU needs its archive extracted (binary, resources). Each FMU is extracted once into
the cache (:func:`cache_root`: ``extracted/<sha256 of the FMU file>`` in the user's cache
folder, next to the built FMUs) and a run's unit folder is a symbolic link to that entry, so a
run neither unzips the FMU again nor, for a pythonfmu FMU, compiles its Python sources again:
their bytecode is written into the entry when it is made (``__pycache__``), and read by every
run, also one that may not write bytecode itself (``PYTHONDONTWRITEBYTECODE``).

* An entry is complete or absent: it is extracted into a temporary folder of the cache, its
  manifest (every file's size) written last, and renamed into place (``os.rename`` is atomic);
  of two processes extracting one FMU at once, the second uses the first one's entry.
* A reused entry is checked against its manifest (each file's size): a missing or cut file
  makes it extracted again. Keyed by the content, an entry is never stale.
* Each process holds a shared ``flock`` on the entries it uses; the cache keeps the
  :data:`KEEP` entries used last and removes an older one only when no process holds it.
* An entry also keeps the FMU's validated model description (:func:`store_model`), so a run
  reads a pickle instead of parsing and validating ``modelDescription.xml`` again.
* An FMU that may be instantiated only once per process gets its own copy per instance, as do
  all FMUs with ``IMMERSIM_FMU_CACHE=0``; ``IMMERSIM_FMU_CACHE=<folder>`` moves the cache.
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import json
import logging
import os
import pickle
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Dict, Optional

from ..models.cachefiles import cache_folder, write_atomic
from .errors import FmuLoadError

try:
    import fcntl
except ImportError:   # not POSIX: no shared locks, no cache
    fcntl = None

log = logging.getLogger(__name__)

#: entries kept in the cache (the ones used last); an entry in use is never removed
KEEP = 24
_MANIFEST = ".immersim-manifest.json"
_LOCK = ".immersim-lock"
#: a temporary folder of a process that died while extracting or removing: removed after this
_ABANDONED_S = 3600.0

#: extracted FMUs by (FMU path, mtime, size, parent of the unzip folder): see :func:`extract`
_EXTRACTED: Dict[tuple, str] = {}
#: sha256 of FMU files by (path, mtime, size, inode)
_DIGESTS: Dict[tuple, str] = {}
#: the cache entries this process uses: entry folder -> file descriptor of its shared lock
_HELD: Dict[str, int] = {}


def cache_root() -> Optional[Path]:
    """The extraction cache's folder: ``$IMMERSIM_FMU_CACHE``, else ``extracted/`` in the
    user's cache folder; None when ``IMMERSIM_FMU_CACHE`` is ``0`` or without POSIX file locks
    (no cache)."""
    if fcntl is None:
        return None
    return cache_folder("IMMERSIM_FMU_CACHE", "extracted")


def clear() -> None:
    """Forget which sibling instances share an extraction and release the cache entries this
    process holds (as in a fresh process: an entry is checked again at its next use)."""
    _EXTRACTED.clear()
    while _HELD:
        os.close(_HELD.popitem()[1])


def extract(path: Path, md: Any, unzip_dir: Optional[Path], unit: str) -> str:
    """The folder holding the files of FMU ``path`` for an instance of unit ``unit``.

    Instances whose ``unzip_dir`` share a parent folder (one run) load one folder when the FMU
    may be instantiated several times per process (FMI 2.0 ``canBeInstantiatedOnlyOncePerProcess
    = false``, FMI 3.0 likewise), as other masters do; that folder is the cache's entry, linked
    as ``unzip_dir`` (the entry itself without ``unzip_dir``). An FMU that may not gets its own
    extraction into ``unzip_dir`` (a library loaded from another path). Raises
    :class:`~immersim.orchestrator.errors.FmuLoadError` when the archive cannot be extracted.
    """
    once = bool(getattr(md.coSimulation, "canBeInstantiatedOnlyOncePerProcess", False))
    key = None
    if unzip_dir is not None and not once:
        st = os.stat(path)
        key = (os.path.abspath(path), st.st_mtime_ns, st.st_size, os.path.abspath(Path(unzip_dir).parent))
        done = _EXTRACTED.get(key)
        if done is not None and os.path.isfile(os.path.join(done, "modelDescription.xml")):
            return done
    folder = None if once else _linked(path, unzip_dir, unit)
    if folder is None:
        folder = _plain(path, unzip_dir, unit)
    if key is not None:
        if len(_EXTRACTED) >= 256:
            _EXTRACTED.clear()
        _EXTRACTED[key] = folder
    return folder


@functools.lru_cache(maxsize=None)
def model_checks_version() -> str:
    """A digest of the code that reads and checks a model description before it is stored
    (:mod:`.modeldesc`): a change of that code leaves older stored descriptions unused."""
    from . import modeldesc

    return hashlib.sha256(Path(modeldesc.__file__).read_bytes()).hexdigest()[:16]


def stored_model(path: Path) -> Optional[tuple]:
    """What :func:`.modeldesc.read_model` returned for FMU ``path`` (same content) in an earlier
    run, kept in the file's cache entry by :func:`store_model`; None when there is none."""
    name = _model_file(path)
    if name is None:
        return None
    try:
        with open(name, "rb") as fh:
            return pickle.load(fh)
    except FileNotFoundError:
        return None
    except Exception as exc:   # written by another version, or damaged: read the FMU again
        log.debug("stored model description %s not used: %s", name, exc)
        return None


def store_model(path: Path, model: tuple) -> None:
    """Keep ``model`` (a validated model description and its variables) in the cache entry of
    FMU ``path``, if the entry exists (written to a temporary file, then renamed)."""
    name = _model_file(path)
    if name is None or not os.path.isdir(os.path.dirname(name)):
        return
    try:
        write_atomic(name, lambda fh: pickle.dump(model, fh, protocol=pickle.HIGHEST_PROTOCOL), suffix=".part")
    except OSError as exc:
        log.debug("model description of %s not stored: %s", path, exc)


def _model_file(path: Path) -> Optional[str]:
    root = cache_root()
    if root is None:
        return None
    import fmpy

    try:
        return os.path.join(root, digest(path), f".immersim-model-{model_checks_version()}-fmpy{fmpy.__version__}.pickle")
    except OSError:
        return None


def _plain(path: Path, unzip_dir: Optional[Path], unit: str) -> str:
    """Extract into ``unzip_dir`` (a new temporary folder when None)."""
    import fmpy

    try:
        return str(fmpy.extract(str(path), unzipdir=str(unzip_dir) if unzip_dir else None))
    except Exception as exc:
        raise FmuLoadError(f"unit {unit}: cannot extract {path}: {exc}") from exc


def _linked(path: Path, unzip_dir: Optional[Path], unit: str) -> Optional[str]:
    """The cache entry of ``path``, as ``unzip_dir`` (a symbolic link to it) when given; None
    when there is no usable cache (off, not writable) or ``unzip_dir`` exists already."""
    root = cache_root()
    if root is None or (unzip_dir is not None and os.path.lexists(unzip_dir)):
        return None
    try:
        entry = cached(path, root, unit)
        if entry is None or unzip_dir is None:
            return entry
        os.makedirs(os.path.dirname(os.path.abspath(unzip_dir)), exist_ok=True)
        os.symlink(entry, unzip_dir, target_is_directory=True)
    except OSError as exc:
        log.debug("unit %s: no cached extraction (%s): extracting %s", unit, exc, path)
        return None
    return str(unzip_dir)


def digest(path: Path) -> str:
    """sha256 of a file (memoised by path, modification time, size and inode)."""
    st = os.stat(path)
    key = (os.path.abspath(path), st.st_mtime_ns, st.st_size, st.st_ino)
    found = _DIGESTS.get(key)
    if found is None:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        if len(_DIGESTS) >= 256:
            _DIGESTS.clear()
        found = _DIGESTS[key] = h.hexdigest()
    return found


def cached(path: Path, root: Path, unit: str) -> Optional[str]:
    """The complete cache entry of FMU ``path`` under ``root``, extracted now if needed and
    held (shared lock) by this process; None if another process keeps a damaged entry busy.
    Raises OSError when the cache cannot be written, FmuLoadError for a bad archive."""
    entry = os.path.join(root, digest(path))
    state = _hold(entry)
    if state == "ok":
        return entry
    os.makedirs(root, exist_ok=True)
    if state == "damaged" and not _remove(root, entry):
        return None
    _create(path, root, entry, unit)
    return entry if _hold(entry) == "ok" else None


def _hold(entry: str) -> str:
    """Take a shared lock on ``entry`` and check it: "ok", "absent" or "damaged" (a file of
    its manifest missing or of another size; then no lock is kept)."""
    if entry in _HELD and os.path.isfile(os.path.join(entry, _MANIFEST)):
        return "ok"
    try:
        fd = os.open(os.path.join(entry, _LOCK), os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return "absent"
    try:
        fcntl.flock(fd, fcntl.LOCK_SH)
        if os.stat(os.path.join(entry, _LOCK)).st_ino != os.fstat(fd).st_ino:
            raise FileNotFoundError   # removed while we waited for the lock
        with open(os.path.join(entry, _MANIFEST), encoding="utf-8") as fh:
            sizes = json.load(fh)
        if any(os.stat(os.path.join(entry, name)).st_size != size for name, size in sizes.items()):
            raise ValueError("a file has another size than extracted")
        os.utime(fd)   # used now (what the cache keeps)
    except FileNotFoundError:
        os.close(fd)
        return "absent" if not os.path.isdir(entry) else "damaged"
    except (OSError, ValueError) as exc:
        log.debug("extraction %s is damaged: %s", entry, exc)
        os.close(fd)
        return "damaged"
    old = _HELD.pop(entry, None)
    if old is not None:
        os.close(old)
    _HELD[entry] = fd
    return "ok"


def _create(path: Path, root: Path, entry: str, unit: str) -> None:
    """Extract ``path`` into a temporary folder of ``root``, write its manifest and lock file,
    and rename it to ``entry`` (or drop it when another process was first)."""
    part = tempfile.mkdtemp(prefix=".part-", dir=root)
    try:
        _plain(path, Path(part), unit)
        sizes = {}
        for folder, _, files in os.walk(part):
            for name in files:
                full = os.path.join(folder, name)
                sizes[os.path.relpath(full, part)] = os.path.getsize(full)
        _compile(part, entry)
        open(os.path.join(part, _LOCK), "wb").close()
        with open(os.path.join(part, _MANIFEST), "w", encoding="utf-8") as fh:
            json.dump(sizes, fh)
        try:
            os.rename(part, entry)
        except OSError:
            if not os.path.isdir(entry):   # not a lost race: a real failure
                raise
            return
        part = None
        log.debug("extracted %s into the cache: %s", path, entry)
    finally:
        if part is not None:
            shutil.rmtree(part, ignore_errors=True)
    _prune(root)


def _compile(part: str, entry: str) -> None:
    """Write the bytecode of the FMU's Python sources (``__pycache__``, named for ``entry``),
    which every run reads, also one that may not write bytecode (``PYTHONDONTWRITEBYTECODE``)."""
    import compileall

    compileall.compile_dir(part, ddir=entry, quiet=2, workers=1)


def _remove(root: Path, entry: str) -> bool:
    """Remove ``entry`` unless a process holds it (renamed aside first: never half-removed
    under its name). Returns whether it is gone."""
    lock = os.path.join(entry, _LOCK)
    try:
        fd = os.open(lock, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        fd = None   # no lock file: nobody can hold it
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return False
        aside = tempfile.mkdtemp(prefix=".trash-", dir=root)
        try:
            os.rename(entry, os.path.join(aside, "entry"))
        except FileNotFoundError:
            pass
        shutil.rmtree(aside, ignore_errors=True)
        return True
    finally:
        if fd is not None:
            os.close(fd)


def _prune(root: Path) -> None:
    """Keep the :data:`KEEP` entries used last; remove older ones no process holds, and
    temporary folders left by processes that died."""
    try:
        names = os.listdir(root)
    except OSError:
        return
    now, entries = time.time(), []
    for name in names:
        full = os.path.join(root, name)
        try:
            if name.startswith((".part-", ".trash-")):
                if now - os.stat(full).st_mtime > _ABANDONED_S:
                    shutil.rmtree(full, ignore_errors=True)
            elif not name.startswith("."):
                entries.append((os.stat(os.path.join(full, _LOCK)).st_mtime, full))
        except OSError:
            continue
    entries.sort(reverse=True)
    for _, full in entries[KEEP:]:
        if full not in _HELD:
            _remove(root, full)


def forget_python_code(folder: Path) -> int:
    """Drop the Python modules and ``sys.path`` entries that live under ``folder``.

    A pythonfmu FMU runs in this interpreter: loading it puts its ``resources/`` on ``sys.path``
    and imports its modules from there. When the run's extraction folder is removed, those module
    objects would stay in ``sys.modules`` pointing at deleted files, and a later run of the same
    FMU in this process (a sweep worker, a benchmark) would reuse them and fail on its first
    lazy import of a sibling module. Call this after the instances are freed, before the folder
    goes. Returns the number of modules dropped.

    A module is under ``folder`` when its file (or package path) starts with one of the folder's
    spellings: as given, absolute, resolved, or a ``sys.path`` entry that resolves into it (the
    spelling its modules were found through). Only the few ``sys.path`` entries are resolved, not
    every loaded module's file.
    """
    folder = Path(folder)
    real = os.path.join(os.path.realpath(folder), "")
    spellings = {os.path.join(str(p), "") for p in (folder, folder.absolute())} | {real}
    inside_path = []   # the sys.path entries to drop
    for entry in sys.path:
        try:
            spelled = os.path.join(os.fspath(entry), "")
        except TypeError:
            continue
        if spelled.startswith(tuple(spellings)) or os.path.join(os.path.realpath(spelled), "").startswith(real):
            inside_path.append(entry)
            spellings.add(spelled)
    prefixes = tuple(spellings)

    def inside(p) -> bool:
        try:
            return p is not None and os.fspath(p).startswith(prefixes)
        except TypeError:
            return False

    def module_inside(m) -> bool:
        file = getattr(m, "__file__", None)
        if file is not None:   # a module, or a package by its __init__ (its __path__ is that folder)
            return inside(file)
        # a namespace package: the folders of its last search (``_NamespacePath._path``, as
        # iterating would search sys.path again: a listdir per entry) when it has them
        path = getattr(m, "__path__", None)   # (no truth test: len() searches too)
        return path is not None and any(inside(p) for p in list(getattr(path, "_path", path)))

    names = [n for n, m in list(sys.modules.items()) if module_inside(m)]
    for n in names:
        del sys.modules[n]
    dropped = set(map(id, inside_path))
    sys.path[:] = [p for p in sys.path if id(p) not in dropped]
    importlib.invalidate_caches()
    return len(names)
