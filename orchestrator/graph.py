"""Gauss-Seidel stepping order from the connection graph.

Units are sorted topologically (a unit steps after every unit it reads from). Ties keep the
scenario file's order. A cycle (algebraic loop across units) is broken at a documented place:
inside each strongly connected component, units step in scenario order, and every connection
that goes *backwards* in that order (from a unit stepped later to one stepped earlier) is
*delayed*: its destination reads the source's value from the previous macro step, as under
Jacobi. A connection the scenario declares ``delayed`` is delayed wherever its units step and
does not order them (it is left out of the graph): two units joined only by delayed
connections step on each other's previous values, so they may step at the same time. The
delayed connections are reported.
"""
from __future__ import annotations

from typing import Dict, List, Sequence, Set, Tuple

from .scenario import Connection


def strongly_connected(nodes: Sequence[str], edges: Dict[str, Set[str]]) -> List[List[str]]:
    """Tarjan's algorithm; components in reverse topological order."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    stack: List[str] = []
    on: Set[str] = set()
    out: List[List[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ()), key=nodes.index):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(comp)

    for v in nodes:
        if v not in index:
            visit(v)
    return out


def gauss_seidel_order(units: Sequence[str], connections: Sequence[Connection]) -> Tuple[List[str], List[Connection]]:
    """Return ``(order, delayed)`` for the units and their connections.

    Parameters
    ----------
    units : sequence of str
        Instance names in scenario order.
    connections : sequence of Connection

    Returns
    -------
    order : list of str
        Stepping order.
    delayed : list of Connection
        Connections whose destination steps before their source (the places a cycle is broken)
        and those declared ``delayed``.
    """
    units = list(units)
    edges: Dict[str, Set[str]] = {u: set() for u in units}
    for c in connections:
        if c.src_unit != c.dst_unit and not c.delayed:
            edges[c.src_unit].add(c.dst_unit)
    comps = strongly_connected(units, edges)
    comp_of = {u: i for i, comp in enumerate(comps) for u in comp}
    # condensation DAG, Kahn's algorithm with scenario-order tie-break
    cedges: Dict[int, Set[int]] = {i: set() for i in range(len(comps))}
    indeg = {i: 0 for i in range(len(comps))}
    for u, targets in edges.items():
        for v in targets:
            a, b = comp_of[u], comp_of[v]
            if a != b and b not in cedges[a]:
                cedges[a].add(b)
                indeg[b] += 1
    first = {i: min(units.index(u) for u in comp) for i, comp in enumerate(comps)}
    ready = sorted((i for i, d in indeg.items() if d == 0), key=first.get)
    order: List[str] = []
    while ready:
        i = ready.pop(0)
        order.extend(sorted(comps[i], key=units.index))
        for j in cedges[i]:
            indeg[j] -= 1
            if indeg[j] == 0:
                ready.append(j)
        ready.sort(key=first.get)
    pos = {u: k for k, u in enumerate(order)}
    delayed = [c for c in connections if c.delayed or pos[c.src_unit] >= pos[c.dst_unit]]
    return order, delayed
