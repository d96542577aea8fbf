"""Reading scenario and sweep files, and naming their keys, in plain Python.

What :mod:`.scenario`, :mod:`.values` and :mod:`.schema` share without importing pydantic:
the TOML reader (``tomllib``), :func:`read_toml`, :func:`key_path`, :func:`did_you_mean` and
:func:`show` (a value as an error message quotes it). A run whose scenario comes from the
checked-scenario cache (:mod:`.scenariocache`) imports these and not :mod:`.schema`.
"""
from __future__ import annotations

import difflib
import re
import sys
from pathlib import Path
from typing import Any, Dict, List, Tuple

from .errors import ScenarioError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["tomllib", "read_toml", "key_path", "did_you_mean", "show"]


def read_toml(path: Path, what: str) -> Tuple[Dict[str, Any], str]:
    """Read a TOML file (data, text): every way it can be unreadable is one :class:`ScenarioError`."""
    if not path.exists():
        raise ScenarioError(f"{what} {path} does not exist")
    if path.is_dir():
        raise ScenarioError(f"{path}: is a folder, not a {what}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{path}: not a UTF-8 text file (byte 0x{raw[exc.start]:02x} at offset "
                            f"{exc.start})") from None
    try:
        return tomllib.loads(text), text
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: invalid TOML: {exc}") from None


def key_path(loc: Tuple[Any, ...]) -> str:
    """``('units', 2, 'parameters', 'M')`` -> ``units[2].parameters.M`` (union tags dropped)."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif isinstance(part, str) and part.startswith("<") and part.endswith(">"):
            continue
        elif re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", str(part)):
            out += f".{part}" if out else str(part)
        else:
            out += f"[{str(part)!r}]"
    return out


def did_you_mean(word: Any, known: List[str]) -> str:
    """``" (did you mean 'x'?)"`` for the closest known word, else the list of known words."""
    close = difflib.get_close_matches(str(word), known, n=1, cutoff=0.6)
    if close:
        return f" (did you mean {close[0]!r}?)"
    return f" (expected one of {', '.join(sorted(known))})" if known else ""


def show(x: Any) -> str:
    """``repr(x)`` cut to 60 characters, as error messages quote a value."""
    text = repr(x)
    return text if len(text) <= 60 else text[:57] + "..."
