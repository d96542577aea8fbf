"""Configuration of the network unit: the sizes and five small groups of options and ablation switches."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Dict, Iterable, Tuple

TOPOLOGIES = ("hybrid_p2p", "client_server", "full_mesh")
OWNERSHIP_RULES = ("mahalanobis", "euclidean", "none")
OWNERSHIP_FOCI = ("frame", "reach")   # readings of eq. 3-12 (consistency.ellipsoid_axes)
JITTER_DISTRIBUTIONS = ("exponential", "uniform", "normal")
STATE_TRAFFIC = ("object_view", "neighbour_nodes")   # who gets an object's STATE records (messages.py)


def _check(checks: Iterable[Tuple[bool, str]]) -> None:
    """Raise ``ValueError('NetworkConfig: <msg>')`` for the first failed ``(ok, msg)``."""
    for ok, msg in checks:
        if not ok:
            raise ValueError(f"NetworkConfig: {msg}")


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
class SceneConfig:
    """The scene, its grid and the frame clocks.

    scene_size : side of the square scene (m). grid_cells : cells per side of the scene grid;
    grid : the grid with 9-cell neighbourhoods (§3.3) on/off. scene_id : the scene's id in the
    supernode's index table (§3.2.2). frame_s : frame period T (s); compose_ms : time to compose
    a FRAME packet (ms). frame_phase : frame clocks with their own phase (default: each master
    runs its own 33 ms loop, §3.4.1, and nothing in the thesis aligns the loops of different
    groups): every node's clock has a phase uniform in ``[0, T)`` (seeded, a stream of its own)
    and a group shows its frame ``k`` at ``k T + phi_g``, ``phi_g`` its master's phase, the slaves
    locked to it (§3.5.2: they show the master's cached frame at its update); a STATE record is
    shown at the receiver's first frame at or after its arrival, so the display error follows
    the latency continuously; False: every clock in phase (the first frame tick after arrival).
    """

    scene_size: float = 100.0
    grid_cells: int = 10
    grid: bool = True
    scene_id: int = 1
    frame_s: float = 0.033
    compose_ms: float = 2.0
    frame_phase: bool = True

    def __post_init__(self) -> None:
        _check([
            (self.scene_size > 0, f"scene_size = {self.scene_size} must be > 0"),
            (self.grid_cells >= 1, f"grid_cells = {self.grid_cells} must be >= 1"),
            (self.frame_s > 0, f"frame_s = {self.frame_s} must be > 0"),
        ])


@dataclass(frozen=True)
class NetConfig:
    """Links and topology.

    links : :class:`LinkClass` per class: 'lan' inside a site (controller, its render group),
    'wan' between sites. topology : 'hybrid_p2p' (thesis), 'client_server' (all traffic relayed
    by the supernode), 'full_mesh' (every render node broadcasts to every other one, no grid).
    state_traffic : who gets a published object's STATE record (hybrid_p2p and client_server; a
    full mesh broadcasts): 'object_view' every node whose 9-cell neighbourhood holds the object,
    wherever its owner is; 'neighbour_nodes' (default; §3.3: only neighbour nodes exchange
    avatar and entity state) only those of them whose avatar is in the 9-cell neighbourhood of
    the owner's avatar.
    """

    links: Dict[str, LinkClass] = field(default_factory=lambda: {
        "lan": LinkClass(0.3, 0.1, 0.0, 1000.0),
        "wan": LinkClass(20.0, 5.0, 0.0, 100.0),
    })
    topology: str = "hybrid_p2p"
    state_traffic: str = "neighbour_nodes"

    def __post_init__(self) -> None:
        _check([
            (self.topology in TOPOLOGIES, f"topology {self.topology!r} not in {TOPOLOGIES}"),
            (self.state_traffic in STATE_TRAFFIC, f"state_traffic {self.state_traffic!r} not in {STATE_TRAFFIC}"),
            ("lan" in self.links and "wan" in self.links, "links must define classes 'lan' and 'wan'"),
        ])


@dataclass(frozen=True)
class ConsistencyConfig:
    """Dead reckoning, ownership and DIS-style updates (§3.6).

    prediction_order : dead-reckoning order 0, 1 or 2 (§3.6.3). ownership : 'mahalanobis'
    (eq. 3-11/3-12), 'euclidean' (nearest avatar, Yonekura) or 'none' (a fixed owner per entity,
    never handed over); ownership_scale, ownership_min_axis (m) : the region's size (eq. 3-12);
    ownership_foci : reading of eq. 3-12, see :func:`consistency.ellipsoid_axes`. ownerless :
    entities outside every ownership region belong to no avatar (default; §3.6.3 treats the
    prediction of entities that belong to no role): nobody publishes them, every node shows its
    own prediction (the scene's entity law from its last record), and a region (or an avatar
    touching one) claims them again; False: such an entity keeps its last owner; no effect with
    ownership 'none' (fixed owners). handover_hold_s : an
    entity handed over (region or collision) keeps its new owner at least this long (s), so the
    collision report and the region rule do not flap. dis_threshold : an owner publishes an object
    only when the receivers' dead-reckoned position would be off by more than this (m) or
    ``dis_heartbeat_s`` has passed; ``<= 0`` publishes every frame.
    """

    prediction_order: int = 1
    ownership: str = "mahalanobis"
    ownership_scale: float = 30.0
    ownership_min_axis: float = 5.0
    ownership_foci: str = "reach"
    ownerless: bool = True
    handover_hold_s: float = 0.2
    dis_threshold: float = 0.0
    dis_heartbeat_s: float = 1.0

    def __post_init__(self) -> None:
        _check([
            (self.ownership in OWNERSHIP_RULES, f"ownership {self.ownership!r} not in {OWNERSHIP_RULES}"),
            (self.prediction_order in (0, 1, 2), f"prediction_order = {self.prediction_order} must be 0, 1 or 2"),
            (self.ownership_foci in OWNERSHIP_FOCI, f"ownership_foci {self.ownership_foci!r} not in {OWNERSHIP_FOCI}"),
            (self.handover_hold_s >= 0, f"handover_hold_s = {self.handover_hold_s} must be >= 0"),
            (self.ownership_scale > 0.5, f"ownership_scale = {self.ownership_scale} must be > 0.5 (eq. 3-12)"),
        ])


@dataclass(frozen=True)
class WorldConfig:
    """Motion of avatars and entities, and their contacts (world.py, response.py).

    Avatars (bicycle model): max_accel (m/s2), max_speed (m/s), drag (1/s), wheelbase (m),
    max_steer_rad, autopilot_change_s (s between an undriven avatar's random throttle/steer
    changes), avatar_start : 'cluster' (disc of radius 5 sqrt(G) m at the centre) or 'uniform'.
    Entities: entity_speed (initial, m/s), entity_drag (1/s). Contacts: avatar_radius,
    entity_radius (m), restitution e, avatar_mass and entity_mass (kg; an infinite avatar mass is
    immovable): impulses and separations are split by inverse mass, so with equal masses no entity
    leaves a collision faster than its speed plus the avatar's (e <= 1). avatar_length,
    avatar_width (m): the avatar's footprint box, whose turn in a collision response the position
    correction adds (World.bounce_avatar; 0: none). substeps : integration substeps per frame.
    """

    max_accel: float = 4.0
    max_speed: float = 25.0
    drag: float = 0.3
    wheelbase: float = 2.7
    max_steer_rad: float = 0.5
    restitution: float = 0.5
    avatar_mass: float = 1000.0
    entity_mass: float = 1000.0
    avatar_radius: float = 2.0
    avatar_length: float = 0.0
    avatar_width: float = 0.0
    entity_radius: float = 1.0
    entity_speed: float = 2.0
    entity_drag: float = 0.02
    autopilot_change_s: float = 2.0
    avatar_start: str = "cluster"
    substeps: int = 4

    def __post_init__(self) -> None:
        _check([
            (self.avatar_start in ("cluster", "uniform"), f"avatar_start {self.avatar_start!r} not in ('cluster', 'uniform')"),
            (self.avatar_length >= 0 and self.avatar_width >= 0,
             f"avatar_length = {self.avatar_length}, avatar_width = {self.avatar_width} must be >= 0"),
            (self.avatar_mass > 0 and self.entity_mass > 0 and math.isfinite(self.entity_mass),
             f"avatar_mass = {self.avatar_mass}, entity_mass = {self.entity_mass} must be > 0 (entity finite)"),
        ])


@dataclass(frozen=True)
class MembershipConfig:
    """Heartbeats to the supernode (§3.2) and the Pastry overlay (§2.3.1).

    heartbeat_s : period of a node's heartbeat (s); heartbeat_timeout_s : silence after which the
    supernode drops a node (s). pastry_b : digit size in bits; pastry_L, pastry_M : leaf set and
    neighbourhood set sizes.
    """

    heartbeat_s: float = 1.0
    heartbeat_timeout_s: float = 3.0
    pastry_b: int = 4
    pastry_L: int = 16
    pastry_M: int = 16

    def __post_init__(self) -> None:
        _check([
            (self.heartbeat_s > 0, f"heartbeat_s = {self.heartbeat_s} must be > 0"),
            (self.heartbeat_timeout_s > 0, f"heartbeat_timeout_s = {self.heartbeat_timeout_s} must be > 0"),
            (self.pastry_b >= 1, f"pastry_b = {self.pastry_b} must be >= 1"),
        ])


#: the option groups of :class:`NetworkConfig`, by attribute name
GROUPS = {"scene": SceneConfig, "net": NetConfig, "consistency": ConsistencyConfig, "world": WorldConfig,
          "membership": MembershipConfig}


@dataclass(frozen=True)
class NetworkConfig:
    """Everything the network model needs: the sizes, and the options in five groups.

    Build one from flat keywords with :meth:`from_flat` (``NetworkConfig.from_flat(groups=3,
    restitution=0.2)``) and copy one with :meth:`replace` (flat keywords too); each keyword goes to
    the group that holds it (``cfg.world.restitution``), a group may also be given whole.

    groups : number of control platforms, each with one avatar and one render group.
    render_nodes : render nodes per group (the first online is the master F-RP, §3.5.1).
    entities : free dynamic entities in the scene.
    driven_groups : groups whose avatars are driven from outside (:meth:`NetworkModel.set_input`);
        the others follow a seeded autopilot (random throttle/steer changes).
    seed : seed of every random draw. measure : evaluate the display error of every copy each
        frame (eq. 3-1/3-2); the network does not depend on it (large runs time the protocol alone).
    scene, net, consistency, world, membership : :class:`SceneConfig`, :class:`NetConfig`,
        :class:`ConsistencyConfig`, :class:`WorldConfig`, :class:`MembershipConfig`.
    """

    groups: int = 4
    render_nodes: int = 3
    entities: int = 32
    driven_groups: int = 0
    seed: int = 0
    measure: bool = True
    scene: SceneConfig = field(default_factory=SceneConfig)
    net: NetConfig = field(default_factory=NetConfig)
    consistency: ConsistencyConfig = field(default_factory=ConsistencyConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    membership: MembershipConfig = field(default_factory=MembershipConfig)

    def __post_init__(self) -> None:
        _check([
            (self.groups >= 1, f"groups = {self.groups} must be >= 1"),
            (self.render_nodes >= 1, f"render_nodes = {self.render_nodes} must be >= 1"),
            (self.entities >= 0, f"entities = {self.entities} must be >= 0"),
            (0 <= self.driven_groups <= self.groups, f"driven_groups = {self.driven_groups} must be in [0, groups]"),
        ])

    @classmethod
    def from_flat(cls, **kw) -> "NetworkConfig":
        """The default configuration with the flat keywords ``kw`` applied (see :meth:`replace`)."""
        return cls().replace(**kw)

    def replace(self, **kw) -> "NetworkConfig":
        """Copy with ``kw`` applied: sizes, whole groups, or any group's field by its own name.

        Raises ``TypeError`` naming an unknown keyword, ``ValueError`` as the groups' checks do.
        """
        top = {k: kw.pop(k) for k in list(kw) if k in _TOP}
        for name, group in GROUPS.items():
            sub = {k: kw.pop(k) for k in list(kw) if k in _FIELDS[name]}
            if sub:
                top[name] = replace(top.get(name, getattr(self, name)), **sub)
        if kw:
            raise TypeError(f"NetworkConfig: unknown option(s) {', '.join(sorted(kw))}")
        return replace(self, **top)

    @property
    def n_render(self) -> int:
        return self.groups * self.render_nodes

    def with_links(self, **kw) -> "NetworkConfig":
        """Copy with every link class's fields replaced by ``kw`` (e.g. ``latency_ms=0``)."""
        return self.replace(links={k: replace(v, **kw) for k, v in self.net.links.items()})


_TOP = frozenset(f.name for f in fields(NetworkConfig))
_FIELDS = {name: frozenset(f.name for f in fields(group)) for name, group in GROUPS.items()}
