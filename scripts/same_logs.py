"""Compare the signals of two immersim MCAP logs, sample by sample, exactly.

Usage::

    .venv/bin/python scripts/same_logs.py A.mcap B.mcap [PATTERN ...]

Every signal matching the patterns (default ``*``: every numeric signal of every unit) must be
present in both logs with the same times and the same values, bit for bit (NaN equals NaN).
The logs may use different encodings (JSON or ROS 1: the values are compared, not the bytes).
Exit status 0 when they are the same, 1 when not (the differing signals are listed, with the
first differing time), 2 on an unreadable log.

Used to check that a change keeps every output: run a scenario with the code before and
after (e.g. a ``git worktree`` of the old commit first on ``PYTHONPATH``) and compare the logs.
"""
from __future__ import annotations

import argparse
import logging
import sys

import numpy as np

from immersim.orchestrator.mcapio import LogReadError, read_series

log = logging.getLogger("same_logs")


def differences(a: str, b: str, patterns: list) -> list:
    """Signals that differ between logs ``a`` and ``b``, as (name, reason) pairs."""
    sa, sb = read_series(a, patterns), read_series(b, patterns)
    out = [(k, f"only in {a}") for k in sorted(set(sa) - set(sb))]
    out += [(k, f"only in {b}") for k in sorted(set(sb) - set(sa))]
    for k in sorted(set(sa) & set(sb)):
        (ta, ya, _), (tb, yb, _) = sa[k], sb[k]
        if len(ta) != len(tb) or not np.array_equal(ta, tb):
            out.append((k, f"times differ ({len(ta)} vs {len(tb)} samples)"))
        elif not np.array_equal(ya, yb, equal_nan=True):
            i = int(np.flatnonzero(~((ya == yb) | (np.isnan(ya) & np.isnan(yb))))[0])
            out.append((k, f"first difference at t = {ta[i]:.9g} s: {float(ya[i])!r} vs {float(yb[i])!r}"))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("patterns", nargs="*", default=["*"])
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        diff = differences(args.a, args.b, args.patterns)
        n = len(read_series(args.a, args.patterns))
    except LogReadError as exc:
        log.error("%s", exc)
        return 2
    for name, why in diff:
        log.info("%s: %s", name, why)
    log.info("%s and %s: %d signals, %s", args.a, args.b, n, "the same" if not diff else f"{len(diff)} differ")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())
