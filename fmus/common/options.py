"""Build options: the capacities a unit fixes when it is built (players, bodies, pairs).

FMI variables are fixed in ``modelDescription.xml``, so how many ``avatar[p].*`` or
``pair[k].*`` a unit has is chosen at build time. A unit declares its options once, at the top
of its wrapper, and builds its :class:`~immersim.fmus.common.Var` table from the values::

    OPTIONS = build_options(BuildOption("players", 4, 1, 32, "players with I/O"))
    CAPACITY = OPTIONS["players"]

The build (``immersim build network --option players=8``, or ``build = { players = 8 }`` in a
scenario) checks the values with :func:`check_options` and writes them as JSON
(:data:`CHOSEN_FILE`) next to this module in the FMU's packed copy; :func:`build_options` reads
them there when the FMU is loaded. Without the file (the source tree, a default build) every
option has its default, so a default build is the unit as declared.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Mapping, Tuple

#: the values of a sized build, written by the build into the packed copy of this folder
CHOSEN_FILE = "build_options.json"


@dataclass(frozen=True)
class BuildOption:
    """One integer capacity of a unit, fixed at build time.

    Parameters
    ----------
    name : str
        Option name (``players``), as given to ``--option name=N`` and ``build = { name = N }``.
    default : int
        The value of a default build.
    low, high : int
        Inclusive range of a build.
    description : str
        One line: which variables the option sizes.
    """

    name: str
    default: int
    low: int
    high: int
    description: str = ""


def check_options(who: str, declared: Tuple[BuildOption, ...], given: Mapping[str, object]) -> Dict[str, int]:
    """``given`` checked against ``declared``: every value, defaults filled in.

    Raises ``ValueError`` with one line ``<who>: ...`` (``who`` names the unit, e.g. ``unit
    network``) naming the option, for an unknown option, a value that is not an integer, or
    one outside the option's range.
    """
    known = {o.name: o for o in declared}
    out = {o.name: o.default for o in declared}
    for name, value in given.items():
        option = known.get(name)
        if option is None:
            if not known:
                raise ValueError(f"{who}: takes no build options (got {name!r})")
            raise ValueError(f"{who}: unknown build option {name!r} (options: {', '.join(known)})")
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{who}: build option {name} = {value!r} must be an integer")
        if not option.low <= value <= option.high:
            raise ValueError(f"{who}: build option {name} = {value} must be in {option.low}..{option.high}")
        out[name] = value
    return out


def _read_chosen() -> dict:
    path = Path(__file__).with_name(CHOSEN_FILE)
    return json.loads(path.read_text()) if path.exists() else {"unit": "?", "options": {}}


#: the build's values, read once, when this copy of the package is imported: a packed package's
#: name belongs to one build (its digest covers the options), so a copy imported earlier from
#: another folder (an FMU extracted by another importer, since removed) holds the same values
_CHOSEN = _read_chosen()


def build_options(*declared: BuildOption) -> Dict[str, int]:
    """The values of the declared options in this build: those the build wrote into
    :data:`CHOSEN_FILE`, the defaults for the others (all defaults without the file)."""
    return check_options(f"unit {_CHOSEN['unit']}", declared, _CHOSEN["options"])


def options_table(declared: Tuple[BuildOption, ...]) -> str:
    """Markdown table of a unit's build options (name, default, range, description)."""
    rows = ["| option | default | range | description |", "|---|---|---|---|"]
    rows += [f"| `{o.name}` | {o.default} | {o.low}..{o.high} | {o.description} |" for o in declared]
    return "\n".join(rows) + "\n"
