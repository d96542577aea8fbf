"""Plot logged signals: one subplot per signal, labelled with its unit."""
from __future__ import annotations

from pathlib import Path
from typing import List

from .mcapio import read_series


def plot_signals(log_file: Path | str, patterns: List[str], output: Path | str, max_signals: int = 24) -> Path:
    """Plot every ``unit.variable`` matching ``patterns`` from ``log_file`` into ``output`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = read_series(log_file, patterns)
    names = list(series)[:max_signals]
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 1.8 * len(names) + 0.6), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        t, y, unit = series[name]
        ax.plot(t, y, lw=1.0)
        ax.set_ylabel(f"[{unit}]" if unit else "", fontsize=8)
        ax.set_title(name, fontsize=9, loc="left")
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("simulation time [s]")
    fig.suptitle(Path(log_file).name, fontsize=10)
    fig.tight_layout()
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=110)
    plt.close(fig)
    return output
