"""Shared pieces of the network model tests: lossy link classes and a driven run."""
from __future__ import annotations

from immersim.models.network import LinkClass, NetworkModel

T = 0.033
#: both link classes with jitter and loss (a narrow wan uplink)
LOSSY = {"lan": LinkClass(0.3, 0.2, 0.05, 1000.0), "wan": LinkClass(20.0, 8.0, 0.1, 50.0)}


def trace(cfg, steps, drive=False, paths=None):
    """``(model, [step outputs as dicts])`` of ``steps`` frames of ``T`` s; with ``drive`` the
    driven groups throttle 0.8 for the first half, -0.6 after, steering ``0.2 (g - 1)``."""
    m = NetworkModel(cfg, paths)
    out = []
    for k in range(steps):
        if drive:
            for g in range(cfg.driven_groups):
                m.set_input(g, 0.8 if k < steps // 2 else -0.6, 0.2 * (g - 1))
        out.append(m.step(T).as_dict())
    return m, out
