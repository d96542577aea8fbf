"""One declaration per FMU variable; everything else is generated from it.

A unit declares a tuple of :class:`Var`. From that table the base slave registers the
pythonfmu variables, writes units and ``UnitDefinitions`` into ``modelDescription.xml``,
fills ``ModelStructure`` (outputs and initial unknowns) and renders the README table.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

CAUSALITIES = ("parameter", "input", "output", "local")
TYPES = ("Real", "Integer", "Boolean", "String")


@dataclass(frozen=True)
class Var:
    """An FMI 2.0 scalar variable.

    Parameters
    ----------
    name : str
        Variable name, FMI structured convention (``pose.y``, ``stroke[3]``).
    causality : {'parameter', 'input', 'output', 'local'}
    type : {'Real', 'Integer', 'Boolean', 'String'}
    start : float or int or bool or str
        Start value (required for parameters and inputs; outputs start here too).
    unit : str, optional
        SI unit string written into the model description (``m``, ``rad/s``, ``N``).
    description : str
        One line, with the thesis equation where one applies.
    variability : str, optional
        Defaults to ``fixed`` for parameters, ``continuous`` for Real inputs/outputs and
        ``discrete`` for other types.
    """

    name: str
    causality: str
    type: str = "Real"
    start: float | int | bool | str = 0.0
    unit: str = ""
    description: str = ""
    variability: str | None = None

    def __post_init__(self) -> None:
        if self.causality not in CAUSALITIES:
            raise ValueError(f"variable {self.name!r}: causality {self.causality!r} not in {CAUSALITIES}")
        if self.type not in TYPES:
            raise ValueError(f"variable {self.name!r}: type {self.type!r} not in {TYPES}")

    @property
    def effective_variability(self) -> str:
        if self.variability is not None:
            return self.variability
        if self.causality == "parameter":
            return "fixed"
        return "continuous" if self.type == "Real" else "discrete"


def vector(name: str, n: int, causality: str, unit: str = "", description: str = "",
           start: float | Sequence[float] = 0.0, type: str = "Real") -> tuple[Var, ...]:
    """Declare ``name[1] .. name[n]`` (1-based, as the thesis numbers actuators and axes)."""
    starts = list(start) if isinstance(start, (list, tuple)) else [start] * n
    return tuple(
        Var(f"{name}[{i + 1}]", causality, type, starts[i], unit, f"{description} ({i + 1} of {n})")
        for i in range(n)
    )


def markdown_table(variables: Iterable[Var]) -> str:
    """Render the variable table for a unit README (name, causality, type, unit, start, meaning)."""
    rows = ["| name | causality | type | unit | start | description |",
            "|---|---|---|---|---|---|"]
    for v in variables:
        start = repr(v.start) if isinstance(v.start, str) else v.start
        rows.append(f"| `{v.name}` | {v.causality} | {v.type} | {v.unit or '-'} | {start} | {v.description} |")
    return "\n".join(rows) + "\n"
