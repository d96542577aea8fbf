"""Signal name patterns: ``*`` and ``?`` are wildcards, brackets are literal.

Variable names index vectors with brackets (``stroke[3]``, ``pair[1].distance``), which plain
``fnmatch`` would read as character classes and silently match nothing; every pattern a user
writes (``[log]`` selection, ``immersim plot``, sweep metrics) goes through :func:`matches`.
"""
from __future__ import annotations

import fnmatch
import re
from functools import lru_cache
from typing import Iterable


@lru_cache(maxsize=1024)
def literal_brackets(pattern: str) -> str:
    """The ``fnmatch`` pattern with every ``[`` made literal (an already escaped ``[[]`` is kept)."""
    return re.sub(r"\[\[\]|\[", lambda m: "[[]" if m.group(0) == "[" else m.group(0), pattern)


def matches(name: str, patterns: Iterable[str]) -> bool:
    """Whether ``name`` matches any of ``patterns``."""
    return any(fnmatch.fnmatchcase(name, literal_brackets(p)) for p in patterns)
