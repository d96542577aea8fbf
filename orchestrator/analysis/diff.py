"""Where two logs differ: per signal the largest differences and the first time beyond tolerance.

A sample pair ``a``, ``b`` is equal within tolerance when ``|a - b| <= atol + rtol * |b|``
(numpy's ``isclose`` convention; the defaults 0, 0 ask for bit-identical values, NaN equal to
NaN). Booleans compare as 0/1, Strings by equality. The logs may use different encodings.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, List, Optional

import numpy as np

from .logs import ChannelData, read_channels


@dataclass
class SignalDiff:
    """One signal present in both logs.

    Attributes
    ----------
    name, unit : str
    max_abs : float
        Largest ``|a - b|`` over the common samples (inf where one is NaN and the other not;
        for a String 1.0 when some sample differs, else 0.0).
    max_rel : float
        Largest ``|a - b| / max(|a|, |b|)`` (0 where both are 0).
    first_t : float or None
        Simulation time (s) of the first sample beyond tolerance; None when there is none.
    first_step : int or None
        Its sample index in the log (0: the initial values, k: after k macro steps).
    first_values : tuple
        ``(a, b)`` at that sample.
    samples : int
        Samples compared (those at times both logs have).
    unmatched : int
        Samples at times only one log has (counted as a difference).
    """

    name: str
    unit: str
    max_abs: float
    max_rel: float
    first_t: Optional[float]
    first_step: Optional[int]
    first_values: tuple
    samples: int
    unmatched: int = 0

    @property
    def differs(self) -> bool:
        return self.first_t is not None or self.unmatched > 0


@dataclass
class LogDiff:
    """Every compared signal of two logs and the signals only one of them holds."""

    a: Path
    b: Path
    rtol: float
    atol: float
    signals: List[SignalDiff] = field(default_factory=list)
    only_a: List[str] = field(default_factory=list)
    only_b: List[str] = field(default_factory=list)

    @property
    def differing(self) -> List[SignalDiff]:
        return [s for s in self.signals if s.differs]

    @property
    def equal(self) -> bool:
        return not self.differing and not self.only_a and not self.only_b

    def __str__(self) -> str:
        rows = [("signal", "max |a-b|", "max rel", "first beyond tolerance", "a", "b")]
        for s in self.differing:
            where = (f"t = {s.first_t:.9g} s (step {s.first_step})" if s.first_t is not None
                     else f"{s.unmatched} samples at times only one log has")
            rows.append((s.name + (f" [{s.unit}]" if s.unit else ""), f"{s.max_abs:.6g}", f"{s.max_rel:.3g}", where,
                         _short(s.first_values[0]), _short(s.first_values[1])))
        lines = []
        if len(rows) > 1:
            widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
            lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
        lines += [f"only in {self.a}: {n}" for n in self.only_a] + [f"only in {self.b}: {n}" for n in self.only_b]
        verdict = ("equal" if self.equal else
                   f"{len(self.differing)} differ" + (f", {len(self.only_a) + len(self.only_b)} in one log only"
                                                      if self.only_a or self.only_b else ""))
        lines.append(f"{self.a} vs {self.b}: {len(self.signals)} signals compared (rtol {self.rtol:g}, "
                     f"atol {self.atol:g}): {verdict}")
        return "\n".join(lines)


def _short(x) -> str:
    if x is None:
        return ""
    if isinstance(x, float):
        return repr(x)
    return str(x)


def _compare(name: str, unit: str, kind: str, ta: np.ndarray, ya: np.ndarray, tb: np.ndarray, yb: np.ndarray,
             rtol: float, atol: float) -> SignalDiff:
    if len(ta) == len(tb) and np.array_equal(ta, tb):
        ia = ib = slice(None)
        unmatched = 0
    else:
        _, ia, ib = np.intersect1d(ta, tb, assume_unique=True, return_indices=True)
        unmatched = len(ta) + len(tb) - 2 * len(ia)
    a, b, t = ya[ia], yb[ib], ta[ia]
    if kind == "string":
        bad = a != b
        d = bad.astype(float)
        rel = d
    else:
        a, b = a.astype(np.float64), b.astype(np.float64)
        nan_a, nan_b = np.isnan(a), np.isnan(b)
        with np.errstate(invalid="ignore"):
            d = np.where(nan_a & nan_b, 0.0, np.where(nan_a | nan_b, np.inf, np.abs(a - b)))
            scale = np.maximum(np.abs(a), np.abs(b))
            rel = np.where(d == 0.0, 0.0, np.where(scale > 0, d / np.where(scale > 0, scale, 1.0), np.inf))
        bad = d > atol + rtol * np.where(nan_b, 0.0, np.abs(b))
    hits = np.flatnonzero(bad)
    steps = np.arange(len(ta))[ia]
    first = int(hits[0]) if len(hits) else None
    return SignalDiff(name, unit, float(d.max()) if len(d) else 0.0, float(rel.max()) if len(rel) else 0.0,
                      None if first is None else float(t[first]) / 1e9,
                      None if first is None else int(steps[first]),
                      (None, None) if first is None else (a[first].item(), b[first].item()),
                      len(t), unmatched)


def _flat(channels: dict) -> dict:
    out = {}
    for topic, ch in channels.items():
        ch: ChannelData
        for v, arr in ch.values.items():
            out[f"{topic}.{v}"] = (ch.t_ns, arr, ch.units[v], ch.types[v])
    return out


def diff_logs(a: Path | str, b: Path | str, patterns: Iterable[str] = ("*",), rtol: float = 0.0,
              atol: float = 0.0) -> LogDiff:
    """Compare every signal matching ``patterns`` of logs ``a`` and ``b``.

    Parameters
    ----------
    a, b : path-like
        immersim MCAP logs (any encoding).
    patterns : iterable of str
        Globs over ``unit.variable``.
    rtol, atol : float
        Tolerance: a sample differs when ``|a - b| > atol + rtol * |b|``; must be >= 0.

    Returns
    -------
    LogDiff
        ``equal`` is True when every common signal is within tolerance at every common time
        and both logs hold the same signals at the same times; ``str()`` is the report of
        ``immersim diff``.
    """
    from ..errors import ScenarioError

    for label, tol in (("rtol", rtol), ("atol", atol)):
        if not (tol >= 0 and math.isfinite(tol)):
            raise ScenarioError(f"--{label} must be a finite number >= 0, got {tol!r}")
    patterns = list(patterns)
    sa, sb = _flat(read_channels(a, patterns)), _flat(read_channels(b, patterns))
    out = LogDiff(Path(a), Path(b), rtol, atol, only_a=[k for k in sa if k not in sb],
                  only_b=[k for k in sb if k not in sa])
    for name in (k for k in sa if k in sb):
        (ta, ya, unit, kind), (tb, yb, _, kind_b) = sa[name], sb[name]
        if "string" in (kind, kind_b):
            kind = "string"
        out.signals.append(_compare(name, unit, kind, ta, ya, tb, yb, rtol, atol))
    return out
