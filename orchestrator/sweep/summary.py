"""The summary table (CSV) and the comparison plots of a sweep."""
from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

from .common import FIXED_COLUMNS, TAIL_COLUMNS, _UNSAFE
from .runs import RunRow
from .spec import PlotSpec, SweepSpec, distinct_labels


# -- the summary -------------------------------------------------------------------------
@dataclass
class SweepResult:
    """Rows of a finished sweep and the files written."""

    spec: SweepSpec
    rows: List[RunRow]
    summary: Path
    plots: List[Path] = field(default_factory=list)

    @property
    def failed(self) -> List[RunRow]:
        return [r for r in self.rows if r.status != "completed"]

    def __str__(self) -> str:
        cols = ["id", "status", "steps", "wall_time_s"] + [m.name for m in self.spec.metrics]
        table = [cols] + [[_fmt(_cell(r, c, self.spec)) for c in cols] for r in self.rows]
        widths = [max(len(line[i]) for line in table) for i in range(len(cols))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in table]
        lines.append(f"{len(self.rows) - len(self.failed)} of {len(self.rows)} runs completed; "
                     f"summary: {self.summary}")
        lines += [f"plot: {p}" for p in self.plots]
        return "\n".join(lines)


def _cell(row: RunRow, col: str, spec: SweepSpec) -> Any:
    if col in spec.keys:
        v = spec.variants[row.index].overrides
        return v.get(col, "")
    if col in ("run",):
        return row.index
    if hasattr(row, col) and col not in ("metrics",):
        return getattr(row, col)
    return row.metrics.get(col, "")


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def summary_columns(spec: SweepSpec) -> List[str]:
    """Columns of ``summary.csv``: run, id, every override key, status, steps, t_end_s,
    wall_time_s, loop_time_s, every metric, reason, mcap."""
    return ["run", "id"] + spec.keys + list(FIXED_COLUMNS[2:]) + [m.name for m in spec.metrics] + list(TAIL_COLUMNS)


def write_summary(spec: SweepSpec, rows: Sequence[RunRow], path: Path) -> Path:
    """Write ``summary.csv`` (floats with full precision, ``repr``), rows in sweep order."""
    cols = summary_columns(spec)
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in sorted(rows, key=lambda r: r.index):
            w.writerow([_csv_value(_cell(r, c, spec)) for c in cols])
    os.replace(tmp, path)
    return path


def write_info(spec: SweepSpec, path: Path) -> Path:
    """Write ``sweep.json``: the sweep file, scenario, override keys and metric definitions
    (what ``immersim report`` needs beside ``summary.csv`` to give each metric its unit)."""
    import json

    metrics = {m.name: {"builtin": m.builtin, "signal": m.signal, "reduce": m.reduce,
                        "after": m.after if math.isfinite(m.after) else None} for m in spec.metrics}
    path.write_text(json.dumps({"sweep": str(spec.file), "scenario": str(spec.scenario), "keys": list(spec.keys),
                                "metrics": metrics}, indent=1) + "\n")
    return path


def _csv_value(value: Any) -> str:
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value)
    return str(value)


def read_summary(path: Path | str) -> List[Dict[str, str]]:
    """The rows of a ``summary.csv`` as dicts of strings."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


# -- plots -------------------------------------------------------------------------------
def _as_number(v: Any) -> Optional[float]:
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float)):
        return float(v)
    return None


@dataclass
class ComparisonData:
    """What a comparison plot draws.

    Attributes
    ----------
    numeric : bool
        ``x`` is numeric (else categories, plotted at 0, 1, ... with ``categories`` as labels).
    categories : list of str
    lines : dict
        ``y column -> {hue label -> (x values, y values)}``, sorted by x, non-finite y dropped.
    plotted : int
        Runs drawn (completed and setting ``x``).
    """

    numeric: bool
    categories: List[str]
    lines: Dict[str, Dict[str, Tuple[List[float], List[float]]]]
    plotted: int


def _value_labels(values: Sequence[Any]) -> Dict[str, str]:
    """``str(value) -> short label`` for the distinct values (see :func:`distinct_labels`)."""
    uniq = list(dict.fromkeys(values))
    return dict(zip(map(str, uniq), distinct_labels(uniq)))


def comparison_data(spec: SweepSpec, rows: Sequence[RunRow], plot: PlotSpec) -> ComparisonData:
    """The lines of one comparison plot: completed runs that set ``plot.x``, grouped by hue
    (default: every other override key that varies), one line per group and ``y`` column."""
    done = [r for r in sorted(rows, key=lambda r: r.index)
            if r.status == "completed" and _cell(r, plot.x, spec) != ""]
    xs = [_cell(r, plot.x, spec) for r in done]
    numeric = bool(xs) and all(_as_number(x) is not None for x in xs)
    cats = list(dict.fromkeys(map(str, xs)))
    hue = plot.hue if plot.hue is not None else tuple(
        k for k in spec.keys if k != plot.x and len({str(v.overrides.get(k, "")) for v in spec.variants}) > 1)
    short = {h: _value_labels([_cell(r, h, spec) for r in done]) for h in hue}
    groups: Dict[str, List[Tuple[float, RunRow]]] = {}
    for r, x in zip(done, xs):
        label = ", ".join(f"{h}={short[h][str(_cell(r, h, spec))]}" for h in hue)
        groups.setdefault(label, []).append((_as_number(x) if numeric else float(cats.index(str(x))), r))
    lines: Dict[str, Dict[str, Tuple[List[float], List[float]]]] = {}
    for ycol in plot.y:
        lines[ycol] = {}
        for label, pts in groups.items():
            xy = sorted((x, _as_number(_cell(r, ycol, spec))) for x, r in pts)
            xy = [(x, y) for x, y in xy if y is not None and math.isfinite(y)]
            if xy:
                lines[ycol][label] = ([x for x, _ in xy], [y for _, y in xy])
    return ComparisonData(numeric, cats, lines, len(done))


def plot_comparison(spec: SweepSpec, rows: Sequence[RunRow], plot: PlotSpec, output: Path) -> Path:
    """One PNG (matplotlib Agg): a subplot per ``plot.y`` column against ``plot.x``, a line per
    hue group; see :func:`comparison_data`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = comparison_data(spec, rows, plot)
    fig, axes = plt.subplots(len(plot.y), 1, figsize=(7, 2.6 * len(plot.y) + 0.8), squeeze=False)
    for ax, ycol in zip(axes[:, 0], plot.y):
        width = 0.8 / max(1, len(data.lines[ycol]))
        for i, (label, (x, y)) in enumerate(data.lines[ycol].items()):
            if data.numeric:
                ax.plot(x, y, marker="o", lw=1.2, label=label or None)
            else:  # categories: grouped bars, one colour per hue group
                offset = (i - (len(data.lines[ycol]) - 1) / 2) * width
                ax.bar([xi + offset for xi in x], y, width=width, label=label or None)
        ax.set_xscale("log" if plot.logx and data.numeric else "linear")  # (resets the tick locator)
        if not data.numeric:
            ax.set_xticks(range(len(data.categories)), distinct_labels(data.categories))
        if plot.logy:
            ax.set_yscale("log")
        else:
            ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_ylabel(ycol)
        ax.grid(True, alpha=0.3)
        if any(data.lines[ycol]) and ax is axes[0, 0] and len(data.lines[ycol]) > 1:
            ax.legend(fontsize=7)
    axes[-1, 0].set_xlabel(plot.x)
    fig.suptitle(f"{spec.file.name}: {data.plotted} of {len(rows)} runs plotted (completed, with {plot.x})",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(output, dpi=110)
    plt.close(fig)
    return output


def plot_file_name(plot: PlotSpec) -> str:
    """``<name>.png`` or ``<y1>-<y2>_vs_<x>.png``, file-system safe."""
    stem = plot.name or f"{'-'.join(plot.y)}_vs_{plot.x}"
    return _UNSAFE.sub("-", stem).strip("-") + ".png"


