"""immersim's user cache folders and their atomic writes, shared by the orchestrator's
extraction cache and the collision model's mesh cache (plain Python: the FMUs bundle it)."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import IO, Callable, Optional

__all__ = ["cache_folder", "user_cache_dir", "write_atomic"]


def user_cache_dir() -> Path:
    """immersim's folder in the user's cache (``$XDG_CACHE_HOME/immersim``, by default
    ``~/.cache/immersim`` on Linux; the platform's own place elsewhere, by platformdirs)."""
    import platformdirs

    return Path(platformdirs.user_cache_dir("immersim", appauthor=False))


def cache_folder(env_var: str, sub: str) -> Optional[Path]:
    """``$env_var`` as a folder, else ``sub`` in :func:`user_cache_dir`; None when ``env_var``
    is ``0``, ``off``, ``no`` or ``false`` (the cache turned off)."""
    env = os.environ.get(env_var, "")
    if env.lower() in ("0", "off", "no", "false"):
        return None
    return Path(env) if env else user_cache_dir() / sub


def write_atomic(path, write: Callable[[IO[bytes]], None], suffix: str = ".tmp") -> None:
    """``write(f)`` into a temporary file beside ``path``, then renamed to ``path``: readers
    see the file complete or absent. The temporary file is removed on any error (re-raised)."""
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.fspath(path)) or ".", suffix=suffix)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
