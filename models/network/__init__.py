"""Network unit (thesis ch. 2-3): hybrid-P2P architecture and consistency control.

A discrete-event model of the network service platform (supernode), control platforms and
render nodes, their groups and clusters, PDUs, links, ownership, dead reckoning and cached
master/slave rendering. See :class:`NetworkModel` and :class:`NetworkConfig`; :class:`Paths`
chooses between the fast and plain forms of the model's steps (the same outputs).
"""
from .config import LinkClass, NetworkConfig
from .model import NetworkModel
from .paths import Paths

__all__ = ["LinkClass", "NetworkConfig", "NetworkModel", "Paths"]
