"""Configuration of the network unit: one dataclass holding every option and ablation switch."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Dict

TOPOLOGIES = ("hybrid_p2p", "client_server", "full_mesh")
OWNERSHIP_RULES = ("mahalanobis", "euclidean", "none")
OWNERSHIP_FOCI = ("frame", "reach")   # readings of eq. 3-12 (consistency.ellipsoid_axes)
JITTER_DISTRIBUTIONS = ("exponential", "uniform", "normal")
STATE_TRAFFIC = ("object_view", "neighbour_nodes")   # who gets an object's STATE records (messages.py)


@dataclass(frozen=True)
class LinkClass:
    """Statistics of one link class (§2.3 links; our model, the thesis gives no numbers).

    Parameters
    ----------
    latency_ms : float
        Base one-way latency (ms).
    jitter_ms : float
        Scale of the additive jitter (ms): mean of the exponential, half-width of the
        uniform ``[0, 2 jitter]`` (mean ``jitter``), or standard deviation of the normal
        (clipped so that latency stays >= 0).
    loss : float
        Probability that a message is lost, in [0, 1).
    bandwidth_mbps : float
        Uplink bandwidth of the sender (Mbit/s); ``<= 0`` means unlimited.
    distribution : {'exponential', 'uniform', 'normal'}
    """

    latency_ms: float = 0.0
    jitter_ms: float = 0.0
    loss: float = 0.0
    bandwidth_mbps: float = 0.0
    distribution: str = "exponential"

    def __post_init__(self) -> None:
        if self.latency_ms < 0 or self.jitter_ms < 0:
            raise ValueError(f"link class: latency_ms = {self.latency_ms} and jitter_ms = {self.jitter_ms} must be >= 0")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"link class: loss = {self.loss} must be in [0, 1)")
        if self.distribution not in JITTER_DISTRIBUTIONS:
            raise ValueError(f"link class: distribution {self.distribution!r} not in {JITTER_DISTRIBUTIONS}")


@dataclass(frozen=True)
class NetworkConfig:
    """Everything the network model needs (sizes, scene, links, consistency switches).

    Sizes
    -----
    groups : number of control platforms, each with one avatar and one render group.
    render_nodes : render nodes per group (the first online is the master F-RP, §3.5.1).
    entities : free dynamic entities in the scene.
    driven_groups : groups whose avatars are driven from outside (:meth:`set_input`); the
        others follow a seeded autopilot (random throttle/steer changes).

    Ablation switches
    -----------------
    topology : 'hybrid_p2p' (thesis), 'client_server' (all traffic relayed by the supernode),
        'full_mesh' (every render node broadcasts to every other one, no grid).
    prediction_order : dead-reckoning order 0, 1 or 2 (§3.6.3).
    ownership : 'mahalanobis' (eq. 3-11/3-12), 'euclidean' (nearest avatar, Yonekura) or
        'none' (a fixed owner per entity, never handed over).
    ownership_foci : reading of eq. 3-12, see :func:`consistency.ellipsoid_axes`.
    ownerless : entities outside every ownership region belong to no avatar (§3.6.3): nobody
        publishes them, every node shows its own prediction from its last record, and a region
        (or an avatar touching one) claims them again; False: such an entity keeps its last owner.
    grid : 10x10 scene grid with 9-cell neighbourhoods (§3.3) on/off.
    state_traffic : who gets a published object's STATE record (hybrid_p2p and client_server;
        a full mesh broadcasts): 'object_view' every node whose 9-cell neighbourhood holds the
        object, wherever its owner is; 'neighbour_nodes' (§3.3, hybrid P2P between neighbours)
        only those of them whose avatar is in the 9-cell neighbourhood of the owner's avatar.
    frame_phase : frame clocks with their own phase: each render group (its master and the slaves
        locked to it, §3.5.2) shows its frame ``k`` at ``k T + phi_g``, ``phi_g`` uniform in
        ``[0, T)`` (seeded, a stream of its own); a STATE record sent at the owner's frame arrives
        after its latency and is shown at the receiver's first frame at or after the arrival, so
        the display error follows the latency continuously; False: every clock in phase (a
        record is shown at the first frame tick at or after its arrival).
    dis_threshold : DIS-style update: an owner publishes an object only when the receivers'
        dead-reckoned position would be off by more than this (m) or ``dis_heartbeat_s`` has
        passed; ``<= 0`` publishes every frame.
    """

    groups: int = 4
    render_nodes: int = 3
    entities: int = 32
    driven_groups: int = 0
    seed: int = 0
    # scene
    scene_size: float = 100.0
    grid_cells: int = 10
    grid: bool = True
    scene_id: int = 1
    # time
    frame_s: float = 0.033
    compose_ms: float = 2.0
    # links per class; 'lan' = inside a site (controller, its render group), 'wan' = between sites
    links: Dict[str, LinkClass] = field(default_factory=lambda: {
        "lan": LinkClass(0.3, 0.1, 0.0, 1000.0),
        "wan": LinkClass(20.0, 5.0, 0.0, 100.0),
    })
    topology: str = "hybrid_p2p"
    # consistency
    prediction_order: int = 1
    ownership: str = "mahalanobis"
    ownership_scale: float = 30.0
    ownership_min_axis: float = 5.0
    ownership_foci: str = "reach"    # eq. 3-12 reading: 'reach' (foci a apart) or 'frame' (literal: one frame apart)
    dis_threshold: float = 0.0
    dis_heartbeat_s: float = 1.0
    # world
    max_accel: float = 4.0
    max_speed: float = 25.0
    drag: float = 0.3
    wheelbase: float = 2.7
    max_steer_rad: float = 0.5
    restitution: float = 0.5
    # contact masses (kg; inf: immovable): avatar-entity impulses and separations are split by
    # inverse mass (response.py). Equal masses: no entity leaves a collision faster than its
    # speed plus the avatar's (e <= 1); an infinite avatar mass (the former rule) gives it up to
    # (1 + e) times the approach speed and lets a pinned entity gain energy
    avatar_mass: float = 1000.0
    entity_mass: float = 1000.0
    # ownership hand-over hysteresis: an entity handed over (region or collision) keeps its new
    # owner at least this long (s), so the collision report and the region rule do not flap
    handover_hold_s: float = 0.2
    avatar_radius: float = 2.0
    entity_radius: float = 1.0
    entity_speed: float = 2.0
    entity_drag: float = 0.02
    autopilot_change_s: float = 2.0
    avatar_start: str = "cluster"    # 'cluster' (disc of radius 5 sqrt(G) m at the centre) or 'uniform'
    substeps: int = 4
    # measurement: evaluate the display error of every copy each frame (eq. 3-1/3-2); the network
    # itself does not depend on it, so large runs can switch it off to time the protocol alone
    measure: bool = True
    # membership
    heartbeat_s: float = 1.0
    heartbeat_timeout_s: float = 3.0
    # pastry (§2.3.1)
    pastry_b: int = 4
    pastry_L: int = 16
    pastry_M: int = 16
    # entities outside every ownership region: no owner (§3.6.3), see the class docstring
    ownerless: bool = False
    # STATE records to every viewer of the object, or only to the owner's neighbour nodes (§3.3)
    state_traffic: str = "object_view"
    # render groups' frame clocks with seeded phases, records shown at the receiver's first frame after arrival
    frame_phase: bool = False

    def __post_init__(self) -> None:
        checks = [
            (self.groups >= 1, f"groups = {self.groups} must be >= 1"),
            (self.render_nodes >= 1, f"render_nodes = {self.render_nodes} must be >= 1"),
            (self.entities >= 0, f"entities = {self.entities} must be >= 0"),
            (0 <= self.driven_groups <= self.groups, f"driven_groups = {self.driven_groups} must be in [0, groups]"),
            (self.topology in TOPOLOGIES, f"topology {self.topology!r} not in {TOPOLOGIES}"),
            (self.ownership in OWNERSHIP_RULES, f"ownership {self.ownership!r} not in {OWNERSHIP_RULES}"),
            (not (self.ownerless and self.ownership == "none"), "ownerless needs an ownership rule (not 'none')"),
            (self.state_traffic in STATE_TRAFFIC, f"state_traffic {self.state_traffic!r} not in {STATE_TRAFFIC}"),
            (self.prediction_order in (0, 1, 2), f"prediction_order = {self.prediction_order} must be 0, 1 or 2"),
            (self.scene_size > 0, f"scene_size = {self.scene_size} must be > 0"),
            (self.ownership_foci in OWNERSHIP_FOCI, f"ownership_foci {self.ownership_foci!r} not in {OWNERSHIP_FOCI}"),
            (self.avatar_start in ("cluster", "uniform"), f"avatar_start {self.avatar_start!r} not in ('cluster', 'uniform')"),
            (self.avatar_mass > 0 and self.entity_mass > 0 and math.isfinite(self.entity_mass),
             f"avatar_mass = {self.avatar_mass}, entity_mass = {self.entity_mass} must be > 0 (entity finite)"),
            (self.handover_hold_s >= 0, f"handover_hold_s = {self.handover_hold_s} must be >= 0"),
            (self.grid_cells >= 1, f"grid_cells = {self.grid_cells} must be >= 1"),
            (self.frame_s > 0, f"frame_s = {self.frame_s} must be > 0"),
            (self.ownership_scale > 0.5, f"ownership_scale = {self.ownership_scale} must be > 0.5 (eq. 3-12)"),
            ("lan" in self.links and "wan" in self.links, "links must define classes 'lan' and 'wan'"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ValueError(f"NetworkConfig: {msg}")

    @property
    def n_render(self) -> int:
        return self.groups * self.render_nodes

    def with_links(self, **kw) -> "NetworkConfig":
        """Copy with every link class's fields replaced by ``kw`` (e.g. ``latency_ms=0``)."""
        return replace(self, links={k: replace(v, **kw) for k, v in self.links.items()})
