"""Straight-line Python generated once for a per-step hot path (a slot's input gathering, the
3D view's poses): the generated code reads its constants and objects by name from a namespace
instead of looping over tuples of them every step."""
from __future__ import annotations

from typing import Any, Callable, Dict, List


class Generated:
    """The namespace and body of one generated function.

    Parameters
    ----------
    **names
        Values the body refers to by these names (functions, constants).
    """

    def __init__(self, **names: Any) -> None:
        self.ns: Dict[str, Any] = dict(names)
        self._objects: Dict[int, str] = {}

    def const(self, value: Any) -> str:
        """A new name for ``value``."""
        key = f"k{len(self.ns)}"
        self.ns[key] = value
        return key

    def obj(self, value: Any) -> str:
        """The name of object ``value``, one per object: ``S0``, ``S1``, ... (:attr:`objects`)."""
        if id(value) not in self._objects:
            key = self._objects[id(value)] = f"S{len(self._objects)}"
            self.ns[key] = value
        return self._objects[id(value)]

    @property
    def objects(self) -> List[str]:
        """The names :meth:`obj` gave, in order."""
        return list(self._objects.values())

    def function(self, signature: str, body: List[str], label: str) -> Callable:
        """Compile ``def {signature}:`` with the ``body`` lines (indented here) and return it;
        ``label`` names it in tracebacks (``<label>``)."""
        src = "\n".join([f"def {signature}:"] + [f"    {line}" for line in body])
        name = signature.split("(", 1)[0]
        exec(compile(src, f"<{label}>", "exec"), self.ns)
        return self.ns[name]
