"""The runs to compare: MCAP logs given one by one, or every run of a sweep folder.

A sweep folder is one holding ``summary.csv`` (``immersim sweep -o DIR``); its runs are
labelled by their sweep point (``coll.backend = honeycomb``: the override keys whose value
varies between the runs) and can be coloured by one grid key. A log given by itself is
labelled by its file name.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from ..errors import ImmersimError
from ..mcapio import LogReadError, read_info
from ..sweep.common import FIXED_COLUMNS, TAIL_COLUMNS

#: unit of a built-in sweep metric
_BUILTIN_UNITS = {"wall_time": "s", "loop_time": "s", "realtime_factor": "x real time", "steps": "", "status": ""}


class RunsError(ImmersimError, ValueError):
    """What was given to compare is not a log or a sweep folder."""


@dataclass
class Run:
    """One run: its log, its legend label and, for a sweep run, its summary row."""

    label: str
    path: Path
    point: Dict[str, str] = field(default_factory=dict)
    row: Dict[str, str] = field(default_factory=dict)


@dataclass
class RunSet:
    """Runs to compare, in the order given (a sweep's in sweep order).

    Attributes
    ----------
    keys : list of str
        Override keys that vary between the sweep runs (legend and colour keys).
    metrics : dict of str -> dict
        Per metric column of the summaries: its definition (``sweep.json``; empty when unknown).
    sources : list of Path
        The folders and files given.
    """

    runs: List[Run]
    keys: List[str] = field(default_factory=list)
    metrics: Dict[str, Dict] = field(default_factory=dict)
    sources: List[Path] = field(default_factory=list)

    def colour_groups(self, by: Optional[str] = None) -> List[int]:
        """Per run, the index of its colour: one per distinct value of grid key ``by``
        (default: the first varying key; without one, one colour per run)."""
        by = by if by is not None else (self.keys[0] if self.keys else None)
        if by is None:
            return list(range(len(self.runs)))
        if by not in self.keys and not any(by in r.point for r in self.runs):
            raise RunsError(f"--color-by {by!r}: not a grid key of the sweep (keys: {', '.join(self.keys) or 'none'})")
        values = [r.point.get(by, "") for r in self.runs]
        order = list(dict.fromkeys(values))
        return [order.index(v) for v in values]

    def metric_unit(self, name: str) -> str:
        """Unit of a metric column: a built-in's, else the unit of the first logged signal its
        pattern matches ("1" for the mean of a Boolean: a share of steps); "" when unknown."""
        spec = self.metrics.get(name, {})
        builtin = spec.get("builtin")
        if builtin:
            return "s" if builtin.startswith("unit_time:") else _BUILTIN_UNITS.get(builtin, "")
        if not spec.get("signal"):
            return ""
        from ..patterns import matches

        for run in self.runs:
            if not run.path.exists():
                continue
            for topic, ch in _channels(run.path, run.path.stat().st_mtime_ns).items():
                for var in ch.signals:
                    if matches(f"{topic}.{var}", [spec["signal"]]):
                        kind = ch.schema["properties"][var].get("type")
                        return "1" if kind == "boolean" else ch.unit_of(var)
            return ""
        return ""


def run_series(runs: RunSet, patterns: Sequence[str], skip_missing: bool = False) -> Dict[str, Dict[int, tuple]]:
    """``unit.variable -> {run index: (t in s, values, unit, JSON schema type)}``, signals in
    log order (:func:`~immersim.orchestrator.analysis.logs.read_channels` of each run's log;
    with ``skip_missing`` a run without a log, e.g. a failed sweep run, is left out)."""
    from .logs import read_channels

    out: Dict[str, Dict[int, tuple]] = {}
    for i, run in enumerate(runs.runs):
        if skip_missing and not run.path.exists():
            continue
        for topic, ch in read_channels(run.path, patterns).items():
            for v, y in ch.values.items():
                out.setdefault(f"{topic}.{v}", {})[i] = (ch.t, y, ch.units[v], ch.types[v])
    return out


@lru_cache(maxsize=8)
def _channels(path: Path, mtime_ns: int) -> dict:
    """The channels of a log (cached per file version: a report asks once per metric)."""
    return read_info(path).channels


def _sweep_runs(folder: Path) -> RunSet:
    from ..sweep.summary import read_summary

    rows = read_summary(folder / "summary.csv")
    if not rows:
        raise RunsError(f"{folder / 'summary.csv'}: no runs")
    cols = list(rows[0])
    fixed_end = cols.index(FIXED_COLUMNS[2]) if FIXED_COLUMNS[2] in cols else 2
    keys = cols[2:fixed_end]
    metric_cols = [c for c in cols[cols.index(FIXED_COLUMNS[-1]) + 1:] if c not in TAIL_COLUMNS] \
        if FIXED_COLUMNS[-1] in cols else []
    info_file = folder / "sweep.json"
    defs = json.loads(info_file.read_text()).get("metrics", {}) if info_file.exists() else {}
    varying = [k for k in keys if len({r[k] for r in rows}) > 1]
    runs = []
    for r in rows:
        mcap = Path(r.get("mcap") or f"{r['id']}.mcap")
        path = mcap if mcap.is_absolute() and mcap.exists() else folder / mcap.name
        point = {k: r[k] for k in keys}
        label = ", ".join(f"{k} = {r[k]}" for k in varying if r[k] != "") or r["id"]
        runs.append(Run(label, path, point, r))
    return RunSet(runs, varying, {m: defs.get(m, {}) for m in metric_cols}, [folder])


def collect_runs(sources: Sequence[Path | str]) -> RunSet:
    """The runs of ``sources``: MCAP files and sweep folders (several sweep folders or a mix
    with files give one set, labels prefixed by the folder name when needed).

    Raises
    ------
    RunsError
        A source that is neither an existing file nor a folder with ``summary.csv``.
    """
    sets: List[RunSet] = []
    for src in map(Path, sources):
        if src.is_dir():
            if not (src / "summary.csv").exists():
                raise RunsError(f"{src}: a folder without summary.csv (not the output folder of immersim sweep)")
            sets.append(_sweep_runs(src))
        elif src.exists():
            sets.append(RunSet([Run(src.stem, src)], sources=[src]))
        else:
            raise LogReadError(f"log file {src} does not exist")
    if len(sets) == 1:
        return sets[0]
    runs = []
    for s in sets:
        prefix = f"{s.sources[0].name}: " if s.keys else ""
        runs += [Run(prefix + r.label, r.path, r.point, r.row) for r in s.runs]
    labels = [r.label for r in runs]
    for r in runs:  # the same file name in two folders: tell them apart by the path
        if labels.count(r.label) > 1:
            r.label = str(r.path)
    keys = list(dict.fromkeys(k for s in sets for k in s.keys))
    metrics = {m: d for s in sets for m, d in s.metrics.items()}
    return RunSet(runs, keys, metrics, [p for s in sets for p in s.sources])


def split_sources(items: Sequence[str]) -> Tuple[List[str], List[str]]:
    """``immersim plot A.mcap B.mcap SWEEP_DIR PATTERN ...``: the leading existing files and
    folders (or names ending in ``.mcap``) are sources, the rest signal patterns.

    Raises
    ------
    RunsError
        No source, or no pattern.
    """
    k = 0
    while k < len(items) and (Path(items[k]).exists() or items[k].endswith(".mcap")):
        k += 1
    sources, patterns = list(items[:k]), list(items[k:])
    if not sources:
        raise RunsError(f"{items[0]!r} is not an MCAP file or a sweep folder: give the logs before the patterns")
    if not patterns:
        raise RunsError("no signal pattern given (e.g. 'plat.stroke*' after the logs)")
    return sources, patterns
