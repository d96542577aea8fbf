"""Per-step metrics: spatio-temporal inconsistency (eq. 3-1/3-2), traffic, desync, counters."""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np


def inconsistency(obj: np.ndarray, shown: np.ndarray, truth: np.ndarray, n_obj: int, mask=None):
    """Position error of every displayed copy against the controlling node's state.

    Eq. 3-1/3-2: node B shows ``A_B(t) = A(t - dt_a)`` while the owner shows ``A(t)``; the
    error of the copy is ``|A_B(t) - A(t)|``.

    Parameters
    ----------
    obj : (k,) int, object of each displayed copy
    shown : (k, 2) m, displayed positions
    truth : (n_obj, 2) m, ground truth (the owner's state)
    mask : (k,) bool, optional, copies to count (others are ignored)

    Returns
    -------
    per_max, per_rms : (n_obj,) m, max and RMS over the nodes showing each object (0 if none)
    total_max, total_rms : float, m, over all copies
    """
    dx = shown[:, 0] - np.take(truth[:, 0], obj)
    dy = shown[:, 1] - np.take(truth[:, 1], obj)
    return inconsistency_sq(obj, dx * dx + dy * dy, n_obj, mask)


def object_runs(obj: np.ndarray, n_obj: int):
    """Runs of the non-decreasing object indices ``obj`` (k,): copies per object (n_obj,),
    the objects present, and where each present object's run starts."""
    seen = np.bincount(obj, minlength=n_obj)
    present = np.flatnonzero(seen)
    return seen, present, (np.cumsum(seen) - seen)[present]


def inconsistency_sq(obj: np.ndarray, err2: np.ndarray, n_obj: int, mask=None, sorted_obj: bool = False,
                     segments=None):
    """As :func:`inconsistency`, from squared errors ``err2`` (k,) m^2 of the copies.

    ``sorted_obj``: ``obj`` is non-decreasing (the copies come grouped by object, as the
    grid's view pairs do), so the per-object maxima are segment reductions. The result is
    the same either way (a maximum does not depend on the order; the sums are the same
    sequential ``bincount`` sums). ``segments``: ``(bincount(obj), objects present, start of
    each present object's run)``, :func:`object_runs`, when the caller keeps them (sorted
    ``obj`` only).
    """
    n_valid = len(obj) if mask is None else int(np.count_nonzero(mask))
    if n_valid == 0:
        z = np.zeros(n_obj)
        return z, z.copy(), 0.0, 0.0
    if mask is not None:
        err2 = np.where(mask, err2, 0.0)
    per_max = np.zeros(n_obj)
    if sorted_obj:
        seen, present, starts = object_runs(obj, n_obj) if segments is None else segments
        per_max[present] = np.maximum.reduceat(err2, starts)
        if mask is None:
            cnt = seen
        else:
            cnt = np.zeros(n_obj, np.int64)
            cnt[present] = np.add.reduceat(mask, starts, dtype=np.int64)
    else:
        np.maximum.at(per_max, obj, err2)
        cnt = np.bincount(obj, weights=None if mask is None else mask.astype(float), minlength=n_obj)
    s2 = np.bincount(obj, weights=err2, minlength=n_obj)
    per_rms = np.sqrt(np.divide(s2, cnt, out=np.zeros(n_obj), where=cnt > 0))
    return np.sqrt(per_max), per_rms, float(np.sqrt(err2.max())), float(np.sqrt(err2.sum() / n_valid))


@dataclass
class StepMetrics:
    """Counters of one macro step (reset at each :meth:`NetworkModel.step`)."""

    inconsistency_max: float = 0.0
    inconsistency_rms: float = 0.0
    desync_frames: int = 0
    messages: int = 0
    bytes: int = 0
    handovers: int = 0
    dropped_frames: int = 0
    rejected_updates: int = 0
    lost_messages: int = 0
    remote_contacts: int = 0
    contacts: int = 0
    published: int = 0
    #: entities released by their owner (no region holds them) and claimed from no owner
    #: (``NetworkConfig.consistency.ownerless``; hand-overs between two owners are ``handovers``)
    released: int = 0
    claimed: int = 0
    online_nodes: int = 0
    frames: int = 0
    #: traffic of the last frame interval ((k-1) T, k T] ending in the step, heartbeats excluded
    #: (the FMU's ``messages``/``bytes``; kept in steps without a frame)
    frame_messages: int = 0
    frame_bytes: int = 0

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass
class Totals:
    """Counters accumulated over a run."""

    messages: int = 0
    bytes: int = 0
    handovers: int = 0
    dropped_frames: int = 0
    rejected_updates: int = 0
    lost_messages: int = 0
    remote_contacts: int = 0
    contacts: int = 0
    frames: int = 0
    by_type: dict = field(default_factory=dict)

    def add(self, m: StepMetrics) -> None:
        """Add the counters of one step (every field but ``by_type``)."""
        self.messages += m.messages
        self.bytes += m.bytes
        self.handovers += m.handovers
        self.dropped_frames += m.dropped_frames
        self.rejected_updates += m.rejected_updates
        self.lost_messages += m.lost_messages
        self.remote_contacts += m.remote_contacts
        self.contacts += m.contacts
        self.frames += m.frames


class FrameTraffic:
    """Frame traffic (messages, bytes) between frames, heartbeats excluded.

    Attributes
    ----------
    interval : [messages, bytes] since the last frame
    frame : (messages, bytes) of the interval that ended at the last frame
    prev : ``frame`` as it was at the end of the step before (None before the first step)
    steady : the last step's ``frame`` equals the one of the step before (see ``at_rest``)
    """

    def __init__(self) -> None:
        self.interval = [0, 0]
        self.frame = (0, 0)
        self.prev = None
        self.steady = False

    def add(self, messages: int, nbytes: int) -> None:
        self.interval[0] += messages
        self.interval[1] += nbytes

    def close_frame(self) -> None:
        """A frame ends: its interval's traffic becomes ``frame``."""
        self.frame = (self.interval[0], self.interval[1])
        self.interval = [0, 0]

    def close_step(self) -> None:
        self.steady = self.frame == self.prev
        self.prev = self.frame
