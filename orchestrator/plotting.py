"""Plot logged signals of one or more runs: one panel per signal, one colour per run.

Every matched signal is drawn: more than ``per_page`` panels go to several pages
(``out.png``, ``out-2.png``, ...), more than ``max_signals`` is an error naming the count.
Reals are lines; Integers, Booleans and Strings are steps (held from their sample to the next)
with their values on the y axis.
"""
from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

from .errors import ImmersimError
from .analysis.runs import RunSet, collect_runs, run_series

_STYLES = ("-", "--", ":", "-.")


class TooManySignals(ImmersimError, ValueError):
    """More signals match than a plot may hold."""


def _series(runs: RunSet, patterns: Sequence[str]) -> Dict[str, List[Optional[tuple]]]:
    """``unit.variable -> per run (t in s, values, unit, type) or None``, signals in log order."""
    return {name: [per_run.get(i) for i in range(len(runs.runs))]
            for name, per_run in run_series(runs, patterns).items()}


def _levels(per_run: List[Optional[tuple]]) -> Optional[List[str]]:
    """The y tick labels of a Boolean or String signal (None for numbers)."""
    kinds = {s[3] for s in per_run if s is not None}
    if "string" in kinds:
        return sorted({str(x) for s in per_run if s is not None for x in s[1]})
    if kinds == {"boolean"}:
        return ["False", "True"]
    return None


def _draw(ax, t: np.ndarray, y: np.ndarray, kind: str, levels: Optional[List[str]], **style) -> None:
    if kind == "string":
        ax.step(t, [levels.index(str(x)) for x in y], where="post", **style)
    elif kind in ("boolean", "integer"):
        ax.step(t, y.astype(float), where="post", **style)
    else:
        ax.plot(t, y, **style)


def page_paths(output: Path, pages: int) -> List[Path]:
    """``output`` for the first page, ``<stem>-<k><suffix>`` for page k >= 2."""
    return [output] + [output.with_name(f"{output.stem}-{k}{output.suffix}") for k in range(2, pages + 1)]


def overlay_figures(sources: Sequence[Path | str] | Path | str, patterns: List[str], color_by: Optional[str] = None,
                    per_page: int = 12, max_signals: int = 120) -> list:
    """The pages of :func:`plot_signals` as matplotlib figures (the caller closes them)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = collect_runs([sources] if isinstance(sources, (str, Path)) else sources)
    groups = runs.colour_groups(color_by)
    series = _series(runs, patterns)
    names = list(series)
    if len(names) > max_signals:
        raise TooManySignals(f"{len(names)} signals match {' '.join(patterns)}: more than {max_signals} "
                             f"(--max-signals); narrow the patterns")
    colours = plt.get_cmap("tab10").colors
    seen: Dict[int, int] = {}
    styles = []
    for g in groups:  # runs sharing a colour get other line styles
        styles.append(dict(color=colours[g % len(colours)], ls=_STYLES[seen.get(g, 0) % len(_STYLES)], lw=1.0))
        seen[g] = seen.get(g, 0) + 1
    pages = [names[i:i + per_page] for i in range(0, len(names), per_page)]
    title = runs.sources[0].name if len(runs.sources) == 1 else f"{len(runs.runs)} runs"
    figures = []
    for k, page in enumerate(pages, 1):
        fig, axes = plt.subplots(len(page), 1, figsize=(8, 1.8 * len(page) + 1.0), sharex=True, squeeze=False)
        for ax, name in zip(axes[:, 0], page):
            per_run = series[name]
            levels = _levels(per_run)
            for run, s, style in zip(runs.runs, per_run, styles):
                if s is not None:
                    _draw(ax, s[0], s[1], s[3], levels, label=run.label, **style)
            unit = next(s[2] for s in per_run if s is not None)
            if levels is not None:
                ax.set_yticks(range(len(levels)), [lv[:16] for lv in levels], fontsize=7)
            ax.set_ylabel(f"[{unit}]" if unit else "", fontsize=8)
            ax.set_title(name, fontsize=9, loc="left")
            ax.grid(True, alpha=0.3)
        axes[-1, 0].set_xlabel("simulation time [s]")
        if len(runs.runs) > 1:
            fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="upper right", fontsize=7)
        fig.suptitle(title + (f" ({k}/{len(pages)})" if len(pages) > 1 else ""), fontsize=10, x=0.02, ha="left")
        fig.tight_layout(rect=(0, 0, 0.78 if len(runs.runs) > 1 else 1, 1))
        figures.append(fig)
    return figures


def plot_signals(sources: Sequence[Path | str] | Path | str, patterns: List[str], output: Path | str,
                 color_by: Optional[str] = None, per_page: int = 12, max_signals: int = 120) -> List[Path]:
    """Overlay every ``unit.variable`` matching ``patterns`` of the runs in ``sources``.

    Parameters
    ----------
    sources : path-like or sequence of them
        MCAP logs and sweep folders (see :func:`~immersim.orchestrator.analysis.runs.collect_runs`).
    patterns : list of str
        Globs over ``unit.variable``.
    output : path-like
        Image file (PNG, or any format matplotlib writes); pages after the first get ``-2``, ``-3`` ...
    color_by : str, optional
        Grid key giving the colours of a sweep's runs (default: the first key that varies).
    per_page, max_signals : int
        Panels per page; more matched signals than ``max_signals`` raise :class:`TooManySignals`.

    Returns
    -------
    list of Path
        The pages written.
    """
    import matplotlib.pyplot as plt

    figures = overlay_figures(sources, patterns, color_by, per_page, max_signals)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    written = page_paths(output, len(figures))
    for fig, path in zip(figures, written):
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return written
