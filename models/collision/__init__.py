"""Collision unit (thesis ch. 4-5): scenes of meshes and three interchangeable detectors.

``make_backend(name, scene, pairs, config, shortcuts)`` returns a :class:`CollisionBackend`
whose ``query(poses, dt)`` gives per-pair contact, distance, penetration depth, contact point
and normal, time of impact and closing speed, plus candidate / narrow-phase counts
(:class:`Shortcuts`: the speed mechanisms, all on by default, none changing an output):

* ``fcl`` (default): python-fcl BVHs and dynamic AABB tree, exact (:mod:`.fcl_backend`);
* ``basis_point``: the scan-line basis-point detector of ch. 5 (:mod:`.basis_point`);
* ``honeycomb``: the ray-casting honeycomb decomposition of ch. 4 (:mod:`.honeycomb`).
"""
from .backend import (BackendConfig, CollisionBackend, PairResult, PairSpec, PairSpecError,
                      QueryResult, Shortcuts, parse_pairs)
from .scene import (Body, MeshError, MeshWarning, Scene, SceneError, TANK_TRIS, load_mesh, make_missile,
                    make_tank, parse_scene)

BACKENDS = ("fcl", "basis_point", "honeycomb")


def make_backend(name: str, scene: Scene, pairs="", config: BackendConfig | None = None,
                 shortcuts: Shortcuts | None = None) -> CollisionBackend:
    """Create the backend ``name`` (one of :data:`BACKENDS`) for ``scene`` and ``pairs``."""
    if name == "fcl":
        from .fcl_backend import FclBackend as cls
    elif name == "basis_point":
        from .basis_point import BasisPointBackend as cls
    elif name == "honeycomb":
        from .honeycomb import HoneycombBackend as cls
    else:
        raise ValueError(f"unknown collision backend {name!r}; choose one of {', '.join(BACKENDS)}")
    return cls(scene, pairs, config, shortcuts)


__all__ = ["BACKENDS", "make_backend", "BackendConfig", "CollisionBackend", "PairResult", "PairSpec",
           "PairSpecError", "QueryResult", "Shortcuts", "parse_pairs", "Body", "MeshError", "MeshWarning", "Scene",
           "SceneError", "TANK_TRIS", "load_mesh", "make_missile", "make_tank", "parse_scene"]
