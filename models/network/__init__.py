"""Network unit (thesis ch. 2-3): hybrid-P2P architecture and consistency control.

A discrete-event model of the network service platform (supernode), control platforms and
render nodes, their groups and clusters, PDUs, links, ownership, dead reckoning and cached
master/slave rendering. See :class:`NetworkModel` and :class:`NetworkConfig`.
"""
from .config import LinkClass, NetworkConfig
from .model import NetworkModel

__all__ = ["LinkClass", "NetworkConfig", "NetworkModel"]
