"""Frame phase 6a: what every render node shows of the avatars (§3.5.2, §3.6.3).

A master shows its cache dead-reckoned to the frame time (its own avatar as it is); a slave
shows the frame its master last sent it that arrived in time, up to ``HIST - 1`` frames old.
The shown avatars of the last ``HIST`` frames are kept per viewer group.
"""
from __future__ import annotations

from typing import Dict, Optional

import numpy as np

from .consistency import dead_reckon
from .records import T_COL

HIST = 16  # frames of displayed-avatar history kept for slaves that lag


class AvatarHistory:
    """Displayed avatars (HIST, viewer group, avatar, xy) m, slot ``k % HIST`` for frame ``k``.

    Small scenes keep a frame's slot as the flat list of :meth:`shown_scalar` until the array
    is read (:attr:`hist`).
    """

    def __init__(self, groups: int) -> None:
        self._hist = np.zeros((HIST, groups, groups, 2))
        self.rows: Dict[int, list] = {}        # slots not yet in the array
        self._dest: Optional[tuple] = None     # slot positions of the avatar cache rows (shown_scalar)

    @property
    def hist(self) -> np.ndarray:
        rows = self.rows
        if rows:
            h = self._hist
            for slot, row in rows.items():
                h[slot].flat = row
            rows.clear()
        return self._hist

    def write(self, net, t: float, P: np.ndarray) -> None:
        """The avatars every master shows at frame ``net.k`` (time ``t``, truth ``P``), and the
        largest lag of a slave behind it (``metrics.desync_frames``)."""
        cfg, G, k = net.cfg, net.cfg.groups, net.k
        sl, diag, sl_list = net.groups.slave_nodes(G)
        if G * G <= net.paths.scalar_view:   # (as a list, into the array when read: see hist)
            self.rows[k % HIST] = self.shown_scalar(net, t, P)
        else:
            slot = self.hist[k % HIST]
            blk = net.records.cache[:G * G]           # avatars are objects 0..G-1: object-major block
            av = dead_reckon(blk[:, 1:3], blk[:, 3:5], blk[:, 5:7], t - blk[:, T_COL], cfg.consistency.prediction_order)
            slot[...] = av.reshape(G, G, 2).transpose(1, 0, 2)
            slot[diag, diag] = P[:G]                  # a master shows its own avatar as it is
        if sl_list:
            shown = net.groups.shown_frame
            if len(sl_list) > net.paths.scalar_view:
                oldest = int(shown[sl].min())
            else:
                sf = shown.tolist()
                oldest = min([sf[i] for i in sl_list])
            net.metrics.desync_frames = max(net.metrics.desync_frames, k - oldest)

    def shown_scalar(self, net, t: float, P: np.ndarray) -> list:
        """The avatars every master shows at frame time ``t`` (s), as the flat (viewer, avatar,
        xy) list of a history slot (m): each master's cached avatar records dead-reckoned
        (:func:`consistency.dead_reckon`, the same operations in Python floats), its own avatar
        the truth ``P[g]``."""
        G, order = net.cfg.groups, net.cfg.consistency.prediction_order
        if self._dest is None:   # where cache row i (object i // G, viewer i % G) goes in the slot
            self._dest = ([(i, 2 * ((i % G) * G + i // G)) for i in range(G * G) if i % G != i // G],
                          [2 * (g * G + g) for g in range(G)])
        dest, diag = self._dest     # (the rows of other groups' avatars; the diagonal is the truth)
        out = [0.0] * (2 * G * G)
        rows = net.records.cache[:G * G, :net.records.ncol].tolist()
        if order == 1:
            for i, j in dest:
                c = rows[i]
                dt = t - c[T_COL]
                out[j] = c[1] + c[3] * dt
                out[j + 1] = c[2] + c[4] * dt
        elif order == 0:
            for i, j in dest:
                c = rows[i]
                out[j] = c[1]
                out[j + 1] = c[2]
        else:
            for i, j in dest:
                c = rows[i]
                dt = t - c[T_COL]
                hd = 0.5 * dt
                out[j] = c[1] + dt * (c[3] + hd * c[5])
                out[j + 1] = c[2] + dt * (c[4] + hd * c[6])
        for j, (x, y) in zip(diag, net.positions_list(P)):   # a master shows its own avatar as it is
            out[j] = x
            out[j + 1] = y
        return out

    # -- what a render node shows ------------------------------------------------------------
    def shown_row(self, net, node: int):
        """History slot and group of what render node ``node`` shows now: its master's current
        frame, or the frame the slave shows (at most ``HIST - 1`` frames old)."""
        grp = net.reg.group_list[node]
        k = net.k
        frame = k if node == net.groups.master[grp] else int(net.groups.shown_frame[node])
        return max(frame, k - HIST + 1) % HIST, grp

    def perceived_list(self, net, node: int) -> list:
        """The avatars (G, 2) render node ``node`` shows now, flattened ``[x0, y0, x1, y1, ...]`` (m)."""
        slot, grp = self.shown_row(net, node)
        row = self.rows.get(slot)
        if row is not None:    # a small scene's slot not yet in the array: its group's part
            n = 2 * net.cfg.groups
            return row[n * grp:n * (grp + 1)]
        return self.hist[slot, grp].ravel().tolist()
