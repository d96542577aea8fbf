"""Link model: latency = base + jitter, Bernoulli loss, sender-uplink bandwidth (seeded).

All draws come from one ``numpy.random.Generator`` owned by the model, so a run is
reproducible from its seed and its state can be saved and restored with the model.
"""
from __future__ import annotations

from typing import Dict

import numpy as np

from .config import LinkClass

CLASS_INDEX = {"lan": 0, "wan": 1}


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
    n = len(send_t)
    arrival = np.empty(n)
    lost = np.zeros(n, bool)
    if n == 0:
        return arrival, lost
    tx = np.zeros(n)
    for name, k in CLASS_INDEX.items():
        sel = link_class == k
        if not sel.any():
            continue
        link = links[name]
        m = int(sel.sum())
        arrival[sel] = scale * sample_latency(rng, link, m)
        if link.loss > 0:
            lost[sel] = rng.random(m) < link.loss
        if link.bandwidth_mbps > 0:
            tx[sel] = nbytes[sel] * 8.0 / (link.bandwidth_mbps * 1e6)
    if tx.any():
        # serialise per sender in the given order: start_i = max(send_i, end of previous on that uplink)
        order = np.lexsort((np.arange(n), sender))
        s_sorted, t_sorted, tx_sorted = sender[order], send_t[order], tx[order]
        end = np.empty(n)
        # send times within one batch are equal per sender in our use, so a cumulative sum suffices
        diff = s_sorted[1:] != s_sorted[:-1]
        first = np.empty(n, bool)
        first[0] = True
        first[1:] = diff
        start0 = np.maximum(t_sorted, busy_until[s_sorted])
        grp = np.cumsum(first) - 1
        csum = np.cumsum(tx_sorted)
        base = (csum - tx_sorted)[first][grp]
        end = np.maximum(start0[first][grp], t_sorted) + csum - base
        done = np.empty(n)
        done[order] = end
        arrival += done
        last = np.empty(n, bool)
        last[-1] = True
        last[:-1] = diff
        busy_until[s_sorted[last]] = end[last]
    else:
        arrival += send_t
    return arrival, lost
