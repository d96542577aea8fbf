"""Link model: latency = base + jitter, Bernoulli loss, sender-uplink bandwidth (seeded).

All draws come from one ``numpy.random.Generator`` owned by the model, so a run is
reproducible from its seed and its state can be saved and restored with the model.
"""
from __future__ import annotations

from typing import Dict

import numpy as np

from .config import LinkClass
from .paths import Paths

CLASS_INDEX = {"lan": 0, "wan": 1}
#: a batch over several link classes with exponential jitter and no loss may draw its jitter in
#: one call (``Paths.merge_draws``: ``Generator.exponential(mean, m)`` is ``mean *
#: standard_exponential(m)`` draw by draw, so one ``standard_exponential`` times the per-message
#: means gives the same draws in the same order as one call per class), for batches of at most
#: this many messages (a scalar mean is the faster draw for large ones)
MERGE_MAX = 512
_DEFAULT = Paths()


def _exponential_lossless(link: LinkClass) -> bool:
    """The link's latency is drawn by one exponential call per batch and nothing is lost."""
    return link.distribution == "exponential" and link.jitter_ms > 0.0 and link.loss <= 0.0


def latency_sum(rng: np.random.Generator, link: LinkClass, n: int) -> float:
    """``float(sample_latency(rng, link, n).sum())`` (s): the same draws and the same sum
    (numpy's of fewer than 8 values: in order from 0), in Python for a few exponential ones."""
    if n >= 8 or not _exponential_lossless(link):
        return float(sample_latency(rng, link, n).sum())
    base = link.latency_ms * 1e-3
    total = 0.0
    for j in rng.exponential(link.jitter_ms * 1e-3, n).tolist():
        x = base + j
        total += 0.0 if x < 0.0 else x        # np.maximum(x, 0.0)
    return total


def sample_latency(rng: np.random.Generator, link: LinkClass, n: int) -> np.ndarray:
    """One-way latencies (s) of ``n`` messages on ``link``.

    ``latency = base + jitter`` with jitter exponential (mean ``jitter_ms``), uniform on
    ``[0, 2 jitter_ms]`` or normal (sd ``jitter_ms``, latency clipped at 0).
    """
    base = link.latency_ms * 1e-3
    j = link.jitter_ms * 1e-3
    if j == 0.0:
        return np.full(n, base)
    if link.distribution == "exponential":
        jit = rng.exponential(j, n)
    elif link.distribution == "uniform":
        jit = rng.uniform(0.0, 2.0 * j, n)
    else:
        jit = rng.normal(0.0, j, n)
    return np.maximum(base + jit, 0.0)


def transmit(rng: np.random.Generator, links: Dict[str, LinkClass], send_t: np.ndarray, sender: np.ndarray,
             link_class: np.ndarray, nbytes: np.ndarray, busy_until: np.ndarray, scale: float = 1.0):
    """Arrival times and loss flags of a batch of messages.

    Each sender's uplink serialises its messages in the order given (bandwidth of the
    message's link class); the message then travels ``scale * latency``.

    Parameters
    ----------
    send_t : (n,) float, s
    sender : (n,) int, index into ``busy_until``
    link_class : (n,) int, 0 = lan, 1 = wan
    nbytes : (n,) int
    busy_until : (n_nodes,) float, s, updated in place (uplink busy until)
    scale : float, multiplies latencies (``latency_scale`` input)

    Returns
    -------
    arrival : (n,) float, s
    lost : (n,) bool
    """
    return TransmitPlan(links, sender, link_class, nbytes).run(rng, send_t, busy_until, scale)


class TransmitPlan:
    """What :func:`transmit` derives from a batch's senders, link classes and sizes alone.

    A frame whose messages have the same senders, classes and sizes as an earlier one (a
    small scene, frame after frame) reuses the plan; :meth:`run` then only draws the
    latencies and losses (the same draws, in the same order, as without a plan) and
    serialises on the uplinks: message ``i`` of sender ``s`` leaves at
    ``max(send, busy_s) + sum of the transmission times tx = 8 bytes / bandwidth`` of the
    messages before it and itself. ``merge``: several link classes may draw in one call
    (``Paths.merge_draws``); a merged batch of at most ``float_batch`` messages is timed in
    Python floats (:meth:`run_floats`).
    """

    def __init__(self, links: Dict[str, LinkClass], sender: np.ndarray, link_class: np.ndarray,
                 nbytes: np.ndarray, merge: bool = _DEFAULT.merge_draws,
                 float_batch: int = _DEFAULT.float_batch) -> None:
        self.n = len(sender)
        self.merge = merge
        self.floats = None   # the plan as Python lists (small merged batches, see run_floats)
        self._inputs = None  # (links, sender, link_class, nbytes) while the array plan is not built
        if self.n <= float_batch and self._plan_floats(links, sender.tolist(), link_class.tolist(), nbytes.tolist()):
            self._inputs = (links, sender, link_class, nbytes)   # the array plan: on the first run()
        else:
            self._plan_arrays(links, sender, link_class, nbytes)

    def _merges(self, links: Dict[str, LinkClass], counts: list) -> bool:
        """The classes with messages (``counts`` per class in CLASS_INDEX order) are drawn in
        one call: several of them, each with exponential jitter and no loss, in a batch of at
        most ``MERGE_MAX`` messages."""
        used = [links[name] for name, m in zip(CLASS_INDEX, counts) if m]
        return self.merge and len(used) > 1 and sum(counts) <= MERGE_MAX and all(map(_exponential_lossless, used))

    def _plan_arrays(self, links, sender: np.ndarray, link_class: np.ndarray, nbytes: np.ndarray) -> None:
        n = self.n
        self.classes = []        # (link, selection, count) in CLASS_INDEX order
        tx = np.zeros(n)
        counts = []
        for name, k in CLASS_INDEX.items():
            sel = link_class == k
            m = int(np.count_nonzero(sel))
            counts.append(m)
            if not m:
                continue
            link = links[name]
            if link.bandwidth_mbps > 0:
                tx[sel] = nbytes[sel] * 8.0 / (link.bandwidth_mbps * 1e6)
            self.classes.append((link, slice(None) if m == n else np.flatnonzero(sel), m))
        # one draw for every class (exponential jitter, no loss): the per-message jitter means
        # in class order, the same sequence of draws as one call per class
        self.merged = None
        if self._merges(links, counts):
            idx = np.concatenate([np.arange(n)[sel] for _, sel, _ in self.classes])
            mean = np.concatenate([np.full(m, link.jitter_ms * 1e-3) for link, _, m in self.classes])
            base = np.concatenate([np.full(m, link.latency_ms * 1e-3) for link, _, m in self.classes])
            self.merged = (idx, mean, base)
        self.serial = n > 0 and bool(tx.any())
        if self.serial:
            # serialise per sender in the given order: start_i = max(send_i, end of previous on that uplink)
            order = np.lexsort((np.arange(n), sender))
            s_sorted, tx_sorted = sender[order], tx[order]
            # send times within one batch are equal per sender in our use, so a cumulative sum suffices
            diff = s_sorted[1:] != s_sorted[:-1]
            first = np.empty(n, bool)
            first[0] = True
            first[1:] = diff
            last = np.empty(n, bool)
            last[-1] = True
            last[:-1] = diff
            self.order, self.first, self.last = order, first, last
            self.grp = np.cumsum(first) - 1
            self.csum = np.cumsum(tx_sorted)
            self.base = (self.csum - tx_sorted)[first][self.grp]
            self.s_first, self.s_last = s_sorted[first], s_sorted[last]

    def _plan_floats(self, links, sender: list, link_class: list, nbytes: list) -> bool:
        """:attr:`floats` of a merged batch (or one of a single exponential, lossless class),
        derived in Python as :meth:`_plan_arrays` derives its arrays (the same transmission
        times, uplink order, cumulative sums); False (and nothing set) for any other batch."""
        n = self.n
        per_class = [[i for i, c in enumerate(link_class) if c == k] for k in CLASS_INDEX.values()]
        used = [links[name] for name, m in zip(CLASS_INDEX, per_class) if m]
        if self._merges(links, [len(m) for m in per_class]):
            self._draw = None      # one standard_exponential call, times each message's mean
        elif len(used) == 1 and _exponential_lossless(used[0]):
            self._draw = used[0].jitter_ms * 1e-3   # sample_latency's exponential(mean, n): mean 1 below
        else:
            return False
        tx = [0.0] * n
        lat = [None] * n        # (its draw, mean, base latency) per message; draws in class order
        j = 0
        for name, msgs in zip(CLASS_INDEX, per_class):
            link = links[name]
            bw = link.bandwidth_mbps
            mean = 1.0 if self._draw is not None else link.jitter_ms * 1e-3
            for i in msgs:
                if bw > 0:
                    tx[i] = nbytes[i] * 8.0 / (bw * 1e6)
                lat[i] = (j, mean, link.latency_ms * 1e-3)
                j += 1
        if not any(tx):
            self.floats = ([(i,) + lat[i] for i in range(n)], None, None)
            return True
        # per message in uplink order: (message, its draw, mean, base latency, sender group,
        # cumulative transmission time, the group's start offset); per group the first
        # message and the sender, and the senders in group order
        order = sorted(range(n), key=sender.__getitem__)     # stable: (sender, message) order
        rows, heads, s_last = [], [], []
        csum, g, prev, b0 = 0.0, -1, None, 0.0
        for i in order:
            s, t = sender[i], tx[i]
            csum += t
            if s != prev:
                g, prev, b0 = g + 1, s, csum - t
                heads.append((i, s))
                s_last.append(s)
            rows.append((i,) + lat[i] + (g, csum, b0))
        self.floats = (rows, heads, s_last)
        return True

    def run(self, rng: np.random.Generator, send_t: np.ndarray, busy_until: np.ndarray, scale: float = 1.0):
        """Arrival times (n,) s and loss flags (n,) of the batch sent at ``send_t`` (n,) s."""
        if self._inputs is not None:   # a small plan: its arrays on first use
            self._plan_arrays(*self._inputs)
            self._inputs = None
        n = self.n
        arrival = np.empty(n)
        lost = np.zeros(n, bool)
        if n == 0:
            return arrival, lost
        if self.merged is not None:
            idx, mean, base = self.merged
            arrival[idx] = scale * np.maximum(base + rng.standard_exponential(len(mean)) * mean, 0.0)
        else:
            for link, sel, m in self.classes:
                arrival[sel] = scale * sample_latency(rng, link, m)
                if link.loss > 0:
                    lost[sel] = rng.random(m) < link.loss
        if self.serial:
            t_sorted = send_t[self.order]
            start0 = np.maximum(t_sorted[self.first], busy_until[self.s_first])
            end = np.maximum(start0[self.grp], t_sorted) + self.csum - self.base
            done = np.empty(n)
            done[self.order] = end
            arrival += done
            busy_until[self.s_last] = end[self.last]
        else:
            arrival += send_t
        return arrival, lost

    def run_floats(self, rng: np.random.Generator, send: list, busy_until: np.ndarray, scale: float = 1.0) -> list:
        """:meth:`run` of a small batch (``floats`` not None: lossless, exponential jitter) in
        Python floats: the same draws (one ``standard_exponential`` call for a merged batch,
        one ``exponential`` for a single class) and the same operations in the same order. ``send`` (n,) s as a list; returns the arrival
        times (n,) s as a list (nothing is lost)."""
        rows, heads, s_last = self.floats
        n = self.n
        arrival = [0.0] * n
        if n == 0:
            return arrival
        d = (rng.standard_exponential(n) if self._draw is None else rng.exponential(self._draw, n)).tolist()
        # (base latency, draw and mean are >= 0: np.maximum(base + draw * mean, 0.0) is the sum itself)
        if heads is None:
            for i, j, mean, base in rows:
                arrival[i] = scale * (base + d[j] * mean) + send[i]
            return arrival
        busy = busy_until.tolist()
        # the uplink is free at max(send, busy until) (np.maximum(a, b))
        start0 = [send[i] if send[i] >= busy[s] else busy[s] for i, s in heads]
        ends = [0.0] * len(heads)
        for i, j, mean, base, g, c, b0 in rows:
            a, tq = start0[g], send[i]
            e = (a if a >= tq else tq) + c - b0
            arrival[i] = scale * (base + d[j] * mean) + e
            ends[g] = e                                       # the group's last message ends last
        for s, e in zip(s_last, ends):
            busy_until[s] = e
        return arrival
