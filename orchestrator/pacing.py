"""Real-time pacing: simulated time follows wall time times a factor.

A :class:`Pacer` is an observer (read only): after step ``k`` ends at simulated time ``t``
it waits until the wall clock reaches ``wall0 + (t - t0) / factor``. A step that ends after
its deadline is *late*: the pacer does not wait then, so the run catches up by stepping as
fast as it can, and no step is ever skipped. The lateness of every step is kept for the
summary (late steps, worst and 99th percentile).
"""
from __future__ import annotations

import math
import time
from typing import Callable, Dict, List


class Pacer:
    """Paces a run so that simulated time follows ``factor`` x wall time.

    Parameters
    ----------
    factor : float
        Simulated seconds per wall second (1.0: real time; 2.0: twice as fast), > 0.
    start_ns : int
        Simulated start time of the run, ns.
    clock : callable, optional
        Monotonic wall clock in ns (default ``time.perf_counter_ns``).
    sleep : callable, optional
        Waits a number of seconds (default ``time.sleep``). Tests pass a simulated clock and sleep.
    spin_ns : int
        The last part of a wait spent polling the clock instead of sleeping (the kernel wakes a
        sleeper up to a few hundred microseconds late).
    """

    def __init__(self, factor: float, start_ns: int, clock: Callable[[], int] = time.perf_counter_ns,
                 sleep: Callable[[float], None] = time.sleep, spin_ns: int = 200_000) -> None:
        if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
            raise ValueError(f"real-time factor {factor!r} must be a finite number > 0")
        self.factor = float(factor)
        self.start_ns = start_ns
        self.clock, self.sleep, self.spin_ns = clock, sleep, spin_ns
        self.wall0 = None
        #: lateness of each paced step, ns (0 for a step that ended before its deadline)
        self.lateness: List[int] = []

    def deadline(self, t_ns: int) -> int:
        """The wall time (clock ns) by which the step ending at simulated ``t_ns`` is due."""
        return self.wall0 + round((t_ns - self.start_ns) / self.factor)

    def __call__(self, k: int, t_ns: int) -> None:
        """Observer call after step ``k`` (0: the initial state at the start time)."""
        now = self.clock()
        if self.wall0 is None:   # the initial state: the wall clock starts here
            self.wall0 = now
            return
        due = self.deadline(t_ns)
        if now > due:
            self.lateness.append(now - due)
            return
        self.lateness.append(0)
        if due - now > self.spin_ns:
            self.sleep((due - now - self.spin_ns) / 1e9)
        while self.clock() < due:
            pass

    def summary(self, threshold_ns: int = 0) -> Dict[str, float]:
        """Late steps (lateness above ``threshold_ns``), worst and p99 lateness in ms."""
        late = sorted(self.lateness)
        n = len(late)
        p99 = late[min(n - 1, math.ceil(0.99 * n) - 1)] if n else 0
        return {"factor": self.factor, "steps": n, "late_steps": sum(1 for x in late if x > threshold_ns),
                "worst_ms": (late[-1] if n else 0) / 1e6, "p99_ms": p99 / 1e6}

    def line(self) -> str:
        """The summary as one line for the command's output."""
        s = self.summary()
        return (f"real time x{s['factor']:g}: {s['late_steps']} of {s['steps']} steps late, "
                f"worst {s['worst_ms']:.3f} ms, p99 {s['p99_ms']:.3f} ms, none skipped")
