"""Persistent cache of the scene's generated meshes, their convex hulls and convex parts.

A generated mesh (``tank:5442``, ``missile:3:0.15``, ``box:...``, ``sphere:...``,
``cylinder:...``) is built by trimesh once and stored as one ``.npz`` (vertices, faces,
bounds, convex-hull vertices, the convex parts of :func:`.exit.convex_parts`) in
``meshes/`` of the user's cache folder, keyed by the mesh key and the code that makes it
(the sources of ``scene.py``, ``exit.py`` and this module, numpy's version and trimesh's
installed files). A later run, the 3D view and the collision unit alike, reads the arrays
back as a :class:`CachedMesh` without importing trimesh (with scipy, ~0.35 s).

An entry is written to a temporary file and renamed into place, so concurrent runs see it
complete or absent; an unreadable entry is made again (also one removed while being read);
the cache keeps the :data:`MAX_ENTRIES` used last. ``IMMERSIM_MESH_CACHE=0`` turns the
cache off (scenes hold trimesh meshes, as built), a folder moves it.
"""
from __future__ import annotations

import hashlib
import os
import zipfile
from pathlib import Path
from typing import Callable, List, Optional

import numpy as np

from ..cachefiles import cache_folder, write_atomic

__all__ = ["CachedMesh", "cache_dir", "generated"]

_VERSION: Optional[str] = None
#: entries kept: a new entry removes the ones used least recently beyond this count
MAX_ENTRIES = 256


class _Points:
    """A part or hull as trimesh shows it to the collision model: ``vertices`` and its
    ``convex_hull`` (the stored hull's vertices)."""

    __slots__ = ("vertices", "_hull")

    def __init__(self, vertices: np.ndarray, hull: Optional[np.ndarray]) -> None:
        self.vertices, self._hull = vertices, hull

    @property
    def convex_hull(self) -> "_Points":
        if self._hull is None:
            raise ValueError("the convex hull of this mesh could not be made (degenerate)")
        return _Points(self._hull, self._hull)


class CachedMesh(_Points):
    """The arrays of a trimesh mesh that the collision model and the 3D view read:
    ``vertices`` (n, 3) m, ``faces`` (m, 3), ``bounds`` (2, 3), ``extents``, ``convex_hull.vertices``,
    ``split()`` (its convex parts); any other attribute is the trimesh mesh's (:meth:`trimesh`)."""

    __slots__ = ("faces", "bounds", "_parts", "_mesh")

    def __init__(self, vertices, faces, bounds, hull, parts) -> None:
        super().__init__(vertices, hull)
        self.faces, self.bounds, self._parts, self._mesh = faces, bounds, parts, None

    def split(self, only_watertight: bool = False) -> List[_Points]:
        """The convex parts (each its own hull, as :func:`.exit.convex_parts` made them)."""
        return [_Points(p, p) for p in self._parts]

    def trimesh(self):
        """The same triangles as a ``trimesh.Trimesh`` (made once, unprocessed)."""
        if self._mesh is None:
            import trimesh

            self._mesh = trimesh.Trimesh(self.vertices, self.faces, process=False)
        return self._mesh

    @property
    def extents(self) -> np.ndarray:
        """Edge lengths (3,) of the axis-aligned bounding box, m."""
        return np.ptp(self.bounds, axis=0)

    def __getattr__(self, name: str):
        """Anything else (``ray``, ``copy``, ``nearest`` ...) from :meth:`trimesh`."""
        if name.startswith("__") or name in ("vertices", "_hull", *CachedMesh.__slots__):
            raise AttributeError(name)
        return getattr(self.trimesh(), name)


def cache_dir() -> Optional[Path]:
    """``$IMMERSIM_MESH_CACHE``, else ``meshes/`` in immersim's user cache folder; None
    when ``IMMERSIM_MESH_CACHE`` is ``0``."""
    return cache_folder("IMMERSIM_MESH_CACHE", "meshes")


def _version() -> str:
    """The code that makes a mesh: the sources of this package's mesh modules, numpy's
    version and trimesh's installed files (found without importing trimesh)."""
    global _VERSION
    if _VERSION is None:
        from importlib.util import find_spec

        h = hashlib.sha256(np.__version__.encode())
        here = Path(__file__).parent
        for name in ("scene.py", "exit.py", "meshcache.py"):
            h.update((here / name).read_bytes())
        spec = find_spec("trimesh")
        origin = Path(spec.origin) if spec and spec.origin else None
        for f in (origin, origin.parent / "creation.py") if origin else ():
            st = f.stat()
            h.update(f"{f}:{st.st_size}:{st.st_mtime_ns}".encode())
        _VERSION = h.hexdigest()
    return _VERSION


def generated(key: str, make: Callable[[], object]):
    """The mesh of ``key``: read from the cache, else ``make()`` (a trimesh mesh) stored
    there; ``make()`` itself when the cache is off."""
    root = cache_dir()
    if root is None:
        return make()
    path = root / (hashlib.sha256(f"{key}\n{_version()}".encode()).hexdigest()[:32] + ".npz")
    try:
        with np.load(path, allow_pickle=False) as z:
            mesh = _mesh(z)
        try:
            os.utime(path)   # (used last: kept by the pruning)
        except OSError:   # a read-only cache
            pass
        return mesh
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):   # absent, cut or damaged
        pass
    mesh = make()
    arrays = _arrays(mesh)
    try:
        root.mkdir(parents=True, exist_ok=True)
        write_atomic(path, lambda f: np.savez(f, **arrays))
        _prune(root)
    except OSError:   # a read-only or full cache: the run goes on with the mesh it made
        pass
    return _mesh(arrays)


def _mesh(z) -> CachedMesh:
    """The :class:`CachedMesh` of the arrays of :func:`_arrays` (a dict or a loaded ``.npz``)."""
    hull = z["hull"] if z["has_hull"] else None
    return CachedMesh(z["vertices"], z["faces"], z["bounds"], hull, [z[f"part{k}"] for k in range(int(z["n_parts"]))])


def _prune(root: Path) -> None:
    """Remove the entries beyond :data:`MAX_ENTRIES`, least recently used first."""
    entries = []
    for f in root.glob("*.npz"):
        try:
            entries.append((f.stat().st_mtime_ns, f))
        except OSError:   # removed meanwhile by another run
            pass
    for _, f in sorted(entries, reverse=True)[MAX_ENTRIES:]:
        try:
            f.unlink()
        except OSError:
            pass


def _arrays(mesh) -> dict:
    from .exit import convex_parts

    try:
        hull, has_hull = np.asarray(mesh.convex_hull.vertices, float), True
    except Exception:   # (as the collision model's readers: qhull fails on a flat mesh)
        hull, has_hull = np.zeros((0, 3)), False
    parts = convex_parts(mesh)
    out = {"vertices": np.array(mesh.vertices), "faces": np.array(mesh.faces), "bounds": np.array(mesh.bounds),
           "hull": hull, "has_hull": np.bool_(has_hull), "n_parts": np.int64(len(parts))}
    out.update({f"part{k}": np.asarray(p) for k, p in enumerate(parts)})
    return out
