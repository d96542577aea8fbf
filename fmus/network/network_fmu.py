"""FMI 2.0 co-simulation wrapper of the network unit (thesis ch. 2-3).

A capacity of ``players`` players (build option, 4 by default: control platform + avatar +
render group each) and ``entity_outputs`` entity poses (16); the structural parameter
``players`` chooses how many are active. Driver inputs travel as
ControllerPackets to the group's master and act when they arrive; collision responses
(``contact[p].*``) bounce or stop avatar ``p`` at the start of the step. The model itself is
:class:`immersim.models.network.NetworkModel`.
"""

import math
from operator import itemgetter

from immersim.fmus.common import OUTPUTS_UNCHANGED, BuildOption, TableSlave, Var, build_options
from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network.world import World
from immersim.models.network.config import OWNERSHIP_FOCI, OWNERSHIP_RULES, STATE_TRAFFIC, TOPOLOGIES

#: capacities fixed at build time (``immersim build network --option players=8``)
BUILD_OPTIONS = (
    BuildOption("players", 4, 1, 32, "players with I/O: avatar[p].*, contact[p].*, perceived[p].*"),
    BuildOption("entity_outputs", 16, 0, 64, "free entities with pose outputs entity[e].x, .y, .z"),
)
OPTIONS = build_options(*BUILD_OPTIONS)
CAPACITY = OPTIONS["players"]
N_ENTITY_OUT = OPTIONS["entity_outputs"]
#: per-avatar outputs in the order of the block written each step
AVATAR_FIELDS = ("x", "y", "z", "yaw", "vx", "vy", "f_x", "f_y", "f_z", "w_x", "w_y", "w_z", "jolt", "jolt_acc")


def _player_vars():
    out = []
    for p in range(1, CAPACITY + 1):
        a = f"avatar[{p}]"
        out += [
            Var(f"{a}.throttle", "input", "Real", 0.0, "1", f"player {p} throttle in [-1, 1] (ControllerPacket mAcceleration / max_accel)"),
            Var(f"{a}.steer", "input", "Real", 0.0, "1", f"player {p} steering in [-1, 1] (ControllerPacket mTinyOrient)"),
            Var(f"contact[{p}].active", "input", "Boolean", False, "", f"player {p}'s avatar is in contact (collision response this step)"),
            Var(f"contact[{p}].nx", "input", "Real", 0.0, "1", f"contact normal x, pointing from the obstacle to avatar {p}"),
            Var(f"contact[{p}].ny", "input", "Real", 0.0, "1", f"contact normal y, pointing from the obstacle to avatar {p}"),
            Var(f"contact[{p}].depth", "input", "Real", 0.0, "m", f"penetration depth of avatar {p} in the obstacle: removed along the normal (position correction, not felt as jolt)"),
        ]
    for p in range(1, CAPACITY + 1):
        a = f"avatar[{p}]"
        out += [
            Var(f"{a}.x", "output", "Real", 0.0, "m", f"ground-truth x of avatar {p}"),
            Var(f"{a}.y", "output", "Real", 0.0, "m", f"ground-truth y of avatar {p}"),
            Var(f"{a}.z", "output", "Real", 0.0, "m", f"ground-truth z of avatar {p} (flat ground)"),
            Var(f"{a}.yaw", "output", "Real", 0.0, "rad", f"heading of avatar {p}"),
            Var(f"{a}.vx", "output", "Real", 0.0, "m/s", f"velocity x of avatar {p}"),
            Var(f"{a}.vy", "output", "Real", 0.0, "m/s", f"velocity y of avatar {p}"),
            Var(f"{a}.f_x", "output", "Real", 0.0, "m/s2", f"body-frame specific force x (forward) of avatar {p}"),
            Var(f"{a}.f_y", "output", "Real", 0.0, "m/s2", f"body-frame specific force y (left) of avatar {p}: v * yaw rate"),
            Var(f"{a}.f_z", "output", "Real", 0.0, "m/s2", f"body-frame specific force z (up) of avatar {p}, gravity included: +9.81 on flat ground (a 'minus 1 g' cue input needs offset -9.81)"),
            Var(f"{a}.w_x", "output", "Real", 0.0, "rad/s", f"body-frame angular rate x of avatar {p}"),
            Var(f"{a}.w_y", "output", "Real", 0.0, "rad/s", f"body-frame angular rate y of avatar {p}"),
            Var(f"{a}.w_z", "output", "Real", 0.0, "rad/s", f"body-frame angular rate z (yaw rate) of avatar {p}"),
            Var(f"{a}.jolt", "output", "Real", 0.0, "m/s", f"velocity change |dv| of avatar {p} (m/s, not an acceleration) from the collision responses applied at the start of the step, summed"),
            Var(f"{a}.jolt_acc", "output", "Real", 0.0, "m/s2", "jolt / step size: the acceleration that, held for the step, gives the same velocity change (a platform's jolt input)"),
            Var(f"perceived[{p}].x", "output", "Real", 0.0, "m", f"x of avatar {p} as shown by a slave render node of player 1 (cached frame)"),
            Var(f"perceived[{p}].y", "output", "Real", 0.0, "m", f"y of avatar {p} as shown by a slave render node of player 1 (cached frame)"),
        ]
    for e in range(1, N_ENTITY_OUT + 1):
        out += [Var(f"entity[{e}].{c}", "output", "Real", 0.0, "m", f"ground-truth {c} of free entity {e}") for c in "xyz"]
    return tuple(out)


#: the largest scene side (m): 1000 km, far beyond a VR scene; squared distances stay finite
MAX_SCENE_SIZE = 1e6


class network(TableSlave):
    modelName = "network"
    description = "hybrid-P2P distributed VR network: supernode, render groups, ownership, dead reckoning, cached rendering"
    CAN_HANDLE_STATE = True
    VARIABLES = (
        Var("players", "parameter", "Integer", min(2, CAPACITY), "", f"active players 1..{CAPACITY} (one control platform, avatar and render group each)"),
        Var("render_nodes", "parameter", "Integer", 3, "", "render nodes per group; the first online is the master F-RP (§3.5.1)"),
        Var("entities", "parameter", "Integer", 16, "", f"free dynamic entities in the scene (outputs for the first {N_ENTITY_OUT})"),
        Var("seed", "parameter", "Integer", 0, "", "seed of every random draw (placement, latency, loss)"),
        Var("topology", "parameter", "String", "hybrid_p2p", "", "hybrid_p2p | client_server | full_mesh"),
        Var("prediction_order", "parameter", "Integer", 1, "", "dead-reckoning order 0, 1, 2 (§3.6.3)"),
        Var("ownership", "parameter", "String", "mahalanobis", "", "entity ownership rule: mahalanobis (eq. 3-11/3-12) | euclidean | none"),
        Var("ownership_foci", "parameter", "String", "reach", "", "reading of eq. 3-12: reach (foci a apart, the region reaches ahead) | frame (literal: foci one frame apart, a circle)"),
        Var("ownerless", "parameter", "Boolean", True, "", "an entity outside every ownership region has no owner: nobody publishes it, every node shows its own prediction, the scene's entity law from its last record (§3.6.3); false: it keeps its last owner; no effect with ownership none"),
        Var("grid", "parameter", "Boolean", True, "", "10x10 scene grid with 9-cell neighbourhoods (§3.3)"),
        Var("state_traffic", "parameter", "String", "neighbour_nodes", "", "who gets an object's STATE records: object_view (every node whose 9 cells hold the object), or neighbour_nodes (only those whose avatar is in the 9 cells of the owner's avatar, §3.3)"),
        Var("frame_phase", "parameter", "Boolean", True, "", "every node's frame clock at its own seeded phase in [0, 33 ms), a group's slaves locked to its master: a record is shown at the receiver's first frame after its arrival (false: every clock in phase, records shown at the first tick after arrival)"),
        Var("latency_ms", "parameter", "Real", 20.0, "ms", "base one-way latency of WAN links (between sites)"),
        Var("jitter_ms", "parameter", "Real", 5.0, "ms", "mean of the exponential jitter added to WAN latency"),
        Var("loss", "parameter", "Real", 0.0, "1", "WAN message loss probability"),
        Var("bandwidth_mbps", "parameter", "Real", 100.0, "Mbit/s", "WAN uplink bandwidth per node (<= 0: unlimited)"),
        Var("dis_threshold", "parameter", "Real", 0.0, "m", "DIS update threshold; <= 0 publishes every frame"),
        Var("scene_size", "parameter", "Real", 100.0, "m", "side of the square scene"),
        Var("entity_speed", "parameter", "Real", 2.0, "m/s", "initial speed of the free entities"),
        Var("avatar_length", "parameter", "Real", 0.0, "m", "length of an avatar's footprint box: a collision response that turns the avatar moves it out by the box's turn as well (0: no box)"),
        Var("avatar_width", "parameter", "Real", 0.0, "m", "width of an avatar's footprint box (see avatar_length)"),
        Var("latency_scale", "input", "Real", 1.0, "1", "multiplies every link latency (inject latency bursts), >= 0"),
    ) + _player_vars() + (
        Var("inconsistency_max", "output", "Real", 0.0, "m", "max position error of any displayed copy in the step (eq. 3-1/3-2)"),
        Var("inconsistency_rms", "output", "Real", 0.0, "m", "RMS position error over displayed copies at the last frame"),
        Var("desync_frames", "output", "Integer", 0, "", "largest lag (frames) of a slave behind its master in the step"),
        Var("messages", "output", "Integer", 0, "", "messages sent in the last frame interval ((k-1)T, kT] ending in the step, heartbeats excluded"),
        Var("bytes", "output", "Integer", 0, "", "bytes (PDU headers + payloads) of those messages"),
        Var("handovers", "output", "Integer", 0, "", "entity ownership hand-overs in the step"),
        Var("dropped_frames", "output", "Integer", 0, "", "slave frames dropped at the tick in the step (§3.5.2)"),
        Var("rejected_updates", "output", "Integer", 0, "", "updates from non-owners rejected in the step"),
        Var("online_nodes", "output", "Integer", 0, "", "nodes in the supernode's heartbeat index table"),
        Var("at_rest", "output", "Boolean", False, "", "stepping on with unchanged inputs changes no output (no input changed, frame traffic as in the step before, nothing moves, nothing pending, dis_threshold <= 0)"),
    )

    def _param_error(self, name, msg):
        return ValueError(f"{self.instance_name}: parameter {name} = {self.values[name]!r} {msg} (t = {self._time:g} s)")

    def setup_model(self):
        v = self.values
        if not 1 <= v["players"] <= CAPACITY:
            raise self._param_error("players", f"must be in 1..{CAPACITY} (build option players)")
        if v["render_nodes"] < 1:
            raise self._param_error("render_nodes", "must be >= 1")
        if v["entities"] < 0:
            raise self._param_error("entities", "must be >= 0")
        if v["topology"] not in TOPOLOGIES:
            raise self._param_error("topology", f"must be one of {', '.join(TOPOLOGIES)}")
        if v["ownership"] not in OWNERSHIP_RULES:
            raise self._param_error("ownership", f"must be one of {', '.join(OWNERSHIP_RULES)}")
        if v["ownership_foci"] not in OWNERSHIP_FOCI:
            raise self._param_error("ownership_foci", "must be reach or frame")
        if v["state_traffic"] not in STATE_TRAFFIC:
            raise self._param_error("state_traffic", f"must be one of {', '.join(STATE_TRAFFIC)}")
        if v["prediction_order"] not in (0, 1, 2):
            raise self._param_error("prediction_order", "must be 0, 1 or 2")
        for name in ("latency_ms", "jitter_ms", "scene_size"):
            if v[name] < 0 or (name == "scene_size" and v[name] == 0):
                raise self._param_error(name, "must be positive")
        for name in ("avatar_length", "avatar_width"):
            if v[name] < 0:
                raise self._param_error(name, "must be >= 0")
        if v["scene_size"] > MAX_SCENE_SIZE:   # squared distances of larger scenes overflow
            raise self._param_error("scene_size", f"must be at most {MAX_SCENE_SIZE:g} m")
        if not 0 <= v["loss"] < 1:
            raise self._param_error("loss", "must be in [0, 1)")
        wan = LinkClass(v["latency_ms"], v["jitter_ms"], v["loss"], v["bandwidth_mbps"])
        cfg = NetworkConfig.from_flat(
            groups=v["players"], render_nodes=v["render_nodes"], entities=v["entities"], driven_groups=v["players"],
            seed=v["seed"], topology=v["topology"], prediction_order=v["prediction_order"], ownership=v["ownership"],
            ownership_foci=v["ownership_foci"], ownerless=bool(v["ownerless"]),
            state_traffic=v["state_traffic"], frame_phase=bool(v["frame_phase"]),
            grid=bool(v["grid"]), dis_threshold=v["dis_threshold"], scene_size=v["scene_size"],
            entity_speed=v["entity_speed"], avatar_length=v["avatar_length"], avatar_width=v["avatar_width"], links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": wan})
        self.model = NetworkModel(cfg)
        self._key = None         # see _output_key
        self._out = None         # the Real outputs the last step wrote (see _check_outputs)
        self._check_all = True   # the next output check reads every output
        self._ints = None        # the Integer outputs last written (see _write_outputs)
        self._slave = 1 if cfg.render_nodes > 1 else 0
        self._names()
        self._write_outputs(full=True)

    def _names(self):
        """Variable names used every step, built once (no string formatting per step)."""
        G, E = self.model.cfg.groups, self.model.cfg.entities
        q = range(1, G + 1)
        self._in_names = [(f"avatar[{p}].throttle", f"avatar[{p}].steer", f"contact[{p}].active",
                           f"contact[{p}].nx", f"contact[{p}].ny", f"contact[{p}].depth") for p in q]
        self._avatar_names = [f"avatar[{p}].{n}" for p in q for n in AVATAR_FIELDS]
        self._perceived_names = [f"perceived[{p}].{c}" for p in q for c in "xy"]
        self._entity_names = [f"entity[{e}].{c}" for e in range(1, min(E, N_ENTITY_OUT) + 1) for c in "xyz"]
        self._n_entity_out = len(self._entity_names) // 3
        # written every step: the outputs that change (the constant ones once, in _write_outputs(full=True))
        const = World.CONSTANT_OUTPUTS
        self._real_out_names = ([name for i, name in enumerate(self._avatar_names) if i % len(AVATAR_FIELDS) not in const]
                                + self._perceived_names + [n for n in self._entity_names if not n.endswith(".z")]
                                + ["inconsistency_max", "inconsistency_rms"])
        self._int_out_names = ("desync_frames", "messages", "bytes", "handovers", "dropped_frames", "rejected_updates",
                               "online_nodes")
        self._in_get = itemgetter("latency_scale", *(n for names in self._in_names for n in names))
        self._last_in = None     # the inputs of the last step that bounced no avatar (see step_model)
        self._jolt = True        # the world's jolt may be non-zero
        self.values.update({f"avatar[{p}].{n}": 0.0 for p in range(G + 1, CAPACITY + 1) for n in AVATAR_FIELDS})
        self.values.update({f"perceived[{p}].{c}": 0.0 for p in range(G + 1, CAPACITY + 1) for c in "xy"})
        self.values.update({f"entity[{e}].{c}": 0.0 for e in range(E + 1, N_ENTITY_OUT + 1) for c in "xyz"})

    #: skip rewriting the outputs when everything they are computed from is unchanged (tests
    #: switch this off to compare against writing them every step)
    SKIP_UNCHANGED = True

    def step_model(self, t, h):
        v, m = self.values, self.model
        ins = self._in_get(v)     # latency_scale, then throttle, steer, active, nx, ny, depth per player
        if ins[0] < 0:
            raise ValueError(f"{self.instance_name}: input latency_scale = {ins[0]} must be >= 0 (t = {t:g} s)")
        m.latency_scale = ins[0]
        if self._jolt:            # (the jolt is zero unless a bounce set it)
            m.world.jolt[:] = 0.0
            self._jolt = False
        if ins != self._last_in:   # (unchanged inputs: set_input would return at once)
            for p in range(len(self._in_names)):
                j = 1 + 6 * p
                m.set_input(p, ins[j], ins[j + 1], t)
                if ins[j + 2]:
                    if ins[j + 5] < 0:
                        raise ValueError(f"{self.instance_name}: input contact[{p + 1}].depth = {ins[j + 5]} "
                                         f"must be >= 0 (t = {t:g} s)")
                    m.bounce(p, (ins[j + 3], ins[j + 4]), depth=ins[j + 5])
                    self._jolt = True
            self._last_in = ins if not self._jolt else None   # an active contact bounces every step
        m.step(h)
        if not self._jolt and m.world.jolt.any():   # an entity hit the avatar in the step
            self._jolt = True
        rest = m.at_rest()
        key = self._output_key(h) if rest else None
        if key is not None and key == self._key:   # at rest: every output would get its old value
            return OUTPUTS_UNCHANGED
        self._write_outputs(h, rest)
        self._key = key
        return None

    def _output_key(self, h):
        """Everything the outputs are computed from (world arrays, the perceived avatars'
        frame, the step's metrics), as bytes and numbers; equal keys give equal outputs (None
        when the shortcut is off). Only taken at rest (``at_rest`` True), where it may repeat."""
        if not self.SKIP_UNCHANGED:
            return None
        m = self.model
        w, s = m.world, m.metrics
        return (h, w.apos.tobytes(), w.yaw.tobytes(), w.speed.tobytes(), w.accel.tobytes(), w.yaw_rate.tobytes(),
                w.jolt.tobytes(), w.epos.tobytes(), m.perceived_key(self._slave),
                s.inconsistency_max, s.inconsistency_rms, s.desync_frames, s.frame_messages, s.frame_bytes,
                s.handovers, s.dropped_frames, s.rejected_updates, s.online_nodes)

    def _write_outputs(self, h=None, rest=None, full=False):
        """Write the outputs; ``full``: the constant ones too (avatars' z, f_z, w_x, w_y and the
        entities' z, set once at set-up: no step changes them)."""
        v, m = self.values, self.model
        w, s = m.world, m.metrics
        if full:
            v.update(zip(self._avatar_names, w.avatar_outputs(h)))
            v.update(zip(self._entity_names[2::3], w.ez[:self._n_entity_out].tolist()))
        out = w.avatar_outputs(h, constants=False)   # AVATAR_FIELDS per avatar, the constant ones left out
        out += m.perceived_list(self._slave)         # perceived x, y per avatar
        n = self._n_entity_out
        if n:   # x, y per entity
            out += w.epos[:n].ravel().tolist()
        out.append(float(s.inconsistency_max))
        out.append(float(s.inconsistency_rms))
        v.update(zip(self._real_out_names, out))
        self._out = out
        ints = (int(s.desync_frames), int(s.frame_messages), int(s.frame_bytes), int(s.handovers),
                int(s.dropped_frames), int(s.rejected_updates), int(s.online_nodes))
        if ints != self._ints:    # (steady traffic: the same counts step after step)
            v.update(zip(self._int_out_names, ints))
            self._ints = ints
        v["at_rest"] = bool(m.at_rest() if rest is None else rest)

    def _check_outputs(self, t):
        """The base class's output check on the Real outputs the step wrote (the list
        :meth:`_write_outputs` wrote; the others are the constants written at set-up, and
        the first check after set-up or a state restore reads them all): one sum, finite
        unless a term is not or it overflows; else the base class's search names the variable."""
        if self._check_all or not math.isfinite(sum(self._out)):
            super()._check_outputs(t)
            self._check_all = False

    def get_model_state(self):
        return self.model.get_state()

    def set_model_state(self, state):
        self.model.set_state(state)
        self._last_in, self._jolt = None, True   # the restored model's inputs and jolt
        self._key = None            # the restored outputs are in self.values; rewrite after the next step
        self._check_all = True
        self._ints = None
