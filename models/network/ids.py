"""128-bit node IDs and Pastry-style prefix routing (§2.3.1).

Node IDs are the MD5 of a node's identity string (the thesis: "a 128-bit Node ID from a hash
of the node's network identity"). IDs are read as ``128 / b`` digits of base ``2^b``. Each node
keeps

- a leaf set: the ``L/2`` numerically closest smaller and ``L/2`` larger IDs (on the ring);
- a routing table of ``128/b`` rows and ``2^b`` columns: row ``l``, column ``d`` holds a node
  whose ID shares the first ``l`` digits with this node and has digit ``d`` at position ``l``
  (the proximity-closest one; proximity here is the hash distance of a seeded coordinate);
- a neighbourhood set of ``M`` nodes closest by proximity.

Routing a key: if it falls inside the leaf-set range, deliver to the numerically closest
leaf (one hop); otherwise forward to the routing-table entry sharing one more digit; in the
rare case that entry is empty, to any known node with an equally long prefix that is
numerically closer. Each prefix hop gains at least one digit, so a route takes about
``ceil(log_{2^b} N)`` hops plus the final leaf-set hop.
"""
from __future__ import annotations

import hashlib
from bisect import bisect_left
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence

ID_BITS = 128
RING = 1 << ID_BITS


def node_id(identity: str) -> int:
    """128-bit ID of ``identity`` (MD5, big-endian integer)."""
    return int.from_bytes(hashlib.md5(identity.encode("utf-8")).digest(), "big")


def digits(x: int, b: int) -> List[int]:
    """The ``128/b`` base-``2^b`` digits of ``x``, most significant first."""
    n = ID_BITS // b
    mask = (1 << b) - 1
    return [(x >> (ID_BITS - b * (i + 1))) & mask for i in range(n)]


def shared_prefix(x: int, y: int, b: int) -> int:
    """Number of leading base-``2^b`` digits that ``x`` and ``y`` share."""
    z = x ^ y
    if z == 0:
        return ID_BITS // b
    return (ID_BITS - z.bit_length()) // b


def ring_distance(x: int, y: int) -> int:
    """Distance of two IDs on the ``2^128`` ring."""
    d = (x - y) % RING
    return min(d, RING - d)


@dataclass
class PastryNode:
    """Routing state of one node."""

    nid: int
    leaf: List[int] = field(default_factory=list)
    table: List[List[Optional[int]]] = field(default_factory=list)
    neighbours: List[int] = field(default_factory=list)
    leaf_lo: int = 0
    leaf_hi: int = 0


class PastryOverlay:
    """Pastry overlay over a set of node IDs, tables built from full membership (§2.3.1).

    Parameters
    ----------
    ids : sequence of int
        Distinct 128-bit node IDs.
    b, L, M : int
        Digit width (bits), leaf-set size and neighbourhood-set size.
    proximity : dict, optional
        Node ID -> coordinate used as network proximity when filling the table.
    """

    def __init__(self, ids: Sequence[int], b: int = 4, L: int = 16, M: int = 16,
                 proximity: Optional[Dict[int, float]] = None) -> None:
        if not 1 <= b <= 8 or ID_BITS % b:
            raise ValueError(f"Pastry: b = {b} must divide 128 and lie in 1..8")
        if len(set(ids)) != len(ids):
            raise ValueError("Pastry: node IDs must be distinct")
        self.b, self.L, self.M = b, L, M
        self.sorted = sorted(ids)
        self.prox = proximity or {i: (i % 1_000_003) / 1_000_003 for i in ids}
        self.nodes: Dict[int, PastryNode] = {i: self._build(i) for i in self.sorted}

    def _build(self, nid: int) -> PastryNode:
        ids, n = self.sorted, len(self.sorted)
        k = bisect_left(ids, nid)
        half = self.L // 2
        leaf = []
        for j in range(1, min(half, n - 1) + 1):
            leaf.append(ids[(k - j) % n])
            leaf.append(ids[(k + j) % n])
        m = min(half, n - 1)
        leaf_lo, leaf_hi = ids[(k - m) % n], ids[(k + m) % n]
        leaf = sorted(set(leaf) - {nid})
        rows, cols = ID_BITS // self.b, 1 << self.b
        table: List[List[Optional[int]]] = [[None] * cols for _ in range(rows)]
        mine = digits(nid, self.b)
        for other in ids:
            if other == nid:
                continue
            l = shared_prefix(nid, other, self.b)
            d = digits(other, self.b)[l]
            cur = table[l][d]
            if cur is None or abs(self.prox[other] - self.prox[nid]) < abs(self.prox[cur] - self.prox[nid]):
                table[l][d] = other
        del mine
        neighbours = sorted((o for o in ids if o != nid), key=lambda o: abs(self.prox[o] - self.prox[nid]))[: self.M]
        return PastryNode(nid, leaf, table, neighbours, leaf_lo, leaf_hi)

    def closest(self, key: int) -> int:
        """The live node numerically closest to ``key`` (the key's root)."""
        return min(self.sorted, key=lambda i: (ring_distance(i, key), i))

    def _in_leaf_range(self, node: PastryNode, key: int) -> bool:
        """Whether ``key`` lies between the node's farthest smaller and larger leaves."""
        if 2 * (self.L // 2) + 1 >= len(self.sorted):
            return True
        span = (node.leaf_hi - node.leaf_lo) % RING
        return (key - node.leaf_lo) % RING <= span

    def route(self, start: int, key: int) -> List[int]:
        """Route ``key`` from node ``start``; returns the path of node IDs (start first)."""
        path = [start]
        cur = self.nodes[start]
        for _ in range(4 * ID_BITS):
            if self._in_leaf_range(cur, key):
                best = min(cur.leaf + [cur.nid], key=lambda i: (ring_distance(i, key), i))
                if best != cur.nid:
                    path.append(best)
                return path
            l = shared_prefix(cur.nid, key, self.b)
            nxt = cur.table[l][digits(key, self.b)[l]] if l < ID_BITS // self.b else None
            if nxt is None:  # rare case: any known node at least as good in prefix and closer
                known = cur.leaf + cur.neighbours + [x for row in cur.table for x in row if x is not None]
                here = ring_distance(cur.nid, key)
                cands = [x for x in known if shared_prefix(x, key, self.b) >= l and ring_distance(x, key) < here]
                if not cands:
                    return path
                nxt = min(cands, key=lambda i: (ring_distance(i, key), i))
            path.append(nxt)
            cur = self.nodes[nxt]
        raise RuntimeError(f"Pastry: route of key {key:032x} from {start:032x} did not converge")
