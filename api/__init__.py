"""immersim: co-simulation of motion-platform distributed VR (FMI 2.0 units, an orchestrator,
MCAP logs), and its Python API for scripts and notebooks::

    import immersim

    log = immersim.run("scenarios/campus_drive.toml", {"coll.backend": "honeycomb"})
    df = immersim.read_log(log)                  # pandas DataFrame: time [s] x unit.variable
    df.attrs["units"]["plat.stroke[1]"]          # 'm'
    d = immersim.diff_logs(log, "other.mcap")    # per signal: largest differences, first time

Nothing is imported until a function is used (the units' own code imports ``immersim`` too).
"""
from __future__ import annotations

from typing import Any

__all__ = ["run", "execute", "read_log", "read_channels", "diff_logs"]

#: public name -> module under ``immersim`` that defines it
_WHERE = {"run": "orchestrator.api", "execute": "orchestrator.api", "read_log": "orchestrator.analysis.logs",
          "read_channels": "orchestrator.analysis.logs", "diff_logs": "orchestrator.analysis.diff"}


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'immersim' has no attribute {name!r}")
    from importlib import import_module

    return getattr(import_module(f"{__name__}.{_WHERE[name]}"), name)


def __dir__():
    return sorted(list(globals()) + __all__)
