"""FMI 2.0 co-simulation wrapper of the collision unit (thesis ch. 4-5).

Capacities fixed at build time (build options ``bodies`` and ``pairs``, 8 each by default):
dynamic bodies (inputs ``body[i].*``, the i-th dynamic body of the scene in scene order;
unused inputs are ignored) and monitored pairs (outputs ``pair[k].*``, the k-th pair of the
``pairs`` spec; unused outputs stay 0 / -1). The model is
:func:`immersim.models.collision.make_backend`; this file only maps variables.
"""
from operator import itemgetter

from immersim.fmus.common import OUTPUTS_UNCHANGED, BuildOption, TableSlave, Var, build_options
from immersim.models.collision import BACKENDS, BackendConfig, make_backend, parse_scene

#: capacities fixed at build time (``immersim build collision --option bodies=16``)
BUILD_OPTIONS = (
    BuildOption("bodies", 8, 1, 64, "dynamic bodies with pose inputs body[i].*"),
    BuildOption("pairs", 8, 1, 64, "monitored pairs with outputs pair[k].*"),
)
OPTIONS = build_options(*BUILD_OPTIONS)
BODY_CAPACITY = OPTIONS["bodies"]
PAIR_CAPACITY = OPTIONS["pairs"]
POSE = (("x", "m"), ("y", "m"), ("z", "m"), ("roll", "rad"), ("pitch", "rad"), ("yaw", "rad"))
PAIR_REALS = (
    ("distance", "m", "minimum distance (0 in contact; max_distance when farther; -1 when the pair has no member)"),
    ("depth", "m", "penetration depth (fcl: deepest contact; honeycomb: section overlap; basis_point: 0)"),
    ("px", "m", "contact point x (in contact) or closest point on the first body, world frame"),
    ("py", "m", "contact point y"),
    ("pz", "m", "contact point z"),
    ("nx", "1", "unit normal x from the partner (B) to the first body (A): A's separation direction (see README)"),
    ("ny", "1", "unit normal y"),
    ("nz", "1", "unit normal z"),
    ("toi", "s", "time of impact from the start of the step (fcl continuous collision), -1 when none"),
    ("closing_speed", "m/s", "relative speed along the normal from the pose change over the step (collision jolt)"),
)


def _variables():
    out = [
        Var("scene", "parameter", "String", "tank:tris=5.4k;missile:x=0,y=0,z=8",
            "", "scene: generator spec, JSON scene file or mesh file (see README)"),
        Var("backend", "parameter", "String", "fcl", "", "detector: fcl | basis_point | honeycomb"),
        Var("pairs", "parameter", "String", "", "",
            "monitored pairs, e.g. 'missile vs any tank; a vs b; avatar_1 vs scene' (empty: each dynamic body vs scene)"),
        Var("st", "parameter", "Real", 0.05, "1", "basis_point sampling threshold ST (eq. 5-8..5-11)"),
        Var("cells_n", "parameter", "Integer", 8, "", "honeycomb cells n (rows, §4.4)"),
        Var("cells_m", "parameter", "Integer", 8, "", "honeycomb cells m (columns, §4.4)"),
        Var("max_distance", "parameter", "Real", 2.0, "m",
            "pairs farther apart (AABB gap) skip the exact distance and report distance = max_distance"),
        Var("ccd", "parameter", "Boolean", True, "", "fcl: time of impact (conservative advancement) for moved bodies"),
        Var("chunk_faces", "parameter", "Integer", 32, "",
            "fcl: exact distances to meshes of >= 1024 triangles chunk by chunk, chunks of at most this many "
            "triangles (0: whole-mesh BVH queries, see README)"),
    ]
    for i in range(1, BODY_CAPACITY + 1):
        for axis, unit in POSE:
            out.append(Var(f"body[{i}].{axis}", "input", "Real", 0.0, unit,
                           f"pose {axis} of dynamic body {i} (world frame; R = Rz(yaw) Ry(pitch) Rx(roll), eq. 4-4)"))
    for k in range(1, PAIR_CAPACITY + 1):
        out.append(Var(f"pair[{k}].in_contact", "output", "Boolean", False, "", f"pair {k} in contact"))
        for name, unit, desc in PAIR_REALS:
            start = -1.0 if name in ("distance", "toi") else 0.0
            out.append(Var(f"pair[{k}].{name}", "output", "Real", start, unit, f"pair {k}: {desc}"))
    out += [
        Var("n_bodies", "output", "Integer", 0, "", "bodies in the scene"),
        Var("n_pairs", "output", "Integer", 0, "", "monitored pairs in use"),
        Var("n_candidates", "output", "Integer", 0, "", "broad-phase candidate pairs examined in the step"),
        Var("n_narrow", "output", "Integer", 0, "", "narrow-phase tests in the step"),
        Var("at_rest", "output", "Boolean", False, "", "no pose changed in the step (cached results, no test run)"),
    ]
    return tuple(out)


class collision(TableSlave):
    modelName = "collision"
    description = "contacts, distances, penetration and time of impact of a mesh scene: FCL or the thesis's detectors"
    CAN_HANDLE_STATE = True
    VARIABLES = _variables()

    def setup_model(self):
        val, who = self.values, self.instance_name
        backend = val["backend"].strip()
        if backend not in BACKENDS:
            raise ValueError(f"{who}: parameter backend = {backend!r} must be one of {', '.join(BACKENDS)}")
        try:
            scene = parse_scene(val["scene"])
        except (ValueError, OSError) as exc:
            raise type(exc)(f"{who}: parameter scene: {exc}") from exc
        n_dyn = len(scene.dynamic)
        if n_dyn > BODY_CAPACITY:
            raise ValueError(f"{who}: parameter scene has {n_dyn} dynamic bodies; the FMU takes at most {BODY_CAPACITY} "
                             "(build option bodies)")
        try:
            config = BackendConfig(max_distance=val["max_distance"], ccd=bool(val["ccd"]), st=val["st"],
                                   cells_n=int(val["cells_n"]), cells_m=int(val["cells_m"]),
                                   chunk_faces=int(val["chunk_faces"]))
        except ValueError as exc:
            raise ValueError(f"{who}: parameters: {exc}") from exc
        try:
            self.model = make_backend(backend, scene, val["pairs"], config)
        except ValueError as exc:
            raise ValueError(f"{who}: parameter pairs: {exc}") from exc
        if len(self.model.pairs) > PAIR_CAPACITY:
            raise ValueError(f"{who}: parameter pairs lists {len(self.model.pairs)} pairs; the FMU reports at most "
                             f"{PAIR_CAPACITY} (build option pairs)")
        self._pose_names = [[f"body[{i + 1}].{axis}" for axis, _ in POSE] for i in range(n_dyn)]
        flat = [n for names in self._pose_names for n in names]
        self._inputs = itemgetter(*flat) if len(flat) > 1 else (lambda v, _n=flat: tuple(v[n] for n in _n))
        self._pair_names = [[f"pair[{k}].{name}" for name in ("in_contact",) + tuple(r[0] for r in PAIR_REALS)]
                            for k in range(1, len(self.model.pairs) + 1)]
        self._rest_values = [(f"pair[{k}].{name}", value) for k in range(1, len(self.model.pairs) + 1)
                             for name, value in (("toi", -1.0), ("closing_speed", 0.0))]
        self._rest_values += [("n_candidates", 0), ("n_narrow", 0), ("at_rest", True)]
        self._shown = [None] * len(self.model.pairs)  # the result object last written per pair
        self._counters = None  # (n_candidates, n_narrow, at_rest) last written
        val["n_bodies"], val["n_pairs"] = len(scene.bodies), len(self.model.pairs)  # fixed by the parameters
        # the base class has checked every input (finite) before initialization and each step
        self._last_inputs = self._inputs(val)
        self._publish(self.model.query(self._last_inputs, 0.033))
        self._rested = True
        val["at_rest"] = True
        self._counters = (val["n_candidates"], val["n_narrow"], True)

    def _publish(self, res) -> bool:
        """Write the outputs of a query result; True when any value was written (False: every
        output holds its value of the last step)."""
        val, shown = self.values, self._shown
        wrote = False
        for k, (names, r) in enumerate(zip(self._pair_names, res.pairs)):
            # the model never modifies a result it has handed out: the same object again (a
            # cached pair) holds the values already written (the rest path only writes the
            # toi = -1 and closing_speed = 0 such a result has)
            if r is shown[k]:
                continue
            shown[k] = r
            wrote = True
            val.update(zip(names, (bool(r.in_contact), float(r.distance), float(r.depth),
                                   *r.point.tolist(), *r.normal.tolist(), float(r.toi), float(r.closing_speed))))
        counters = (int(res.n_candidates), int(res.n_narrow), bool(res.at_rest))
        if counters != self._counters:
            self._counters = counters
            val["n_candidates"], val["n_narrow"], val["at_rest"] = counters
            wrote = True
        return wrote

    def step_model(self, t, h):
        inputs = self._inputs(self.values)
        if inputs == self._last_inputs:
            # nothing moved (the base class has rejected non-finite inputs): the model's cached
            # answer holds; only the per-step outputs change, once (README "Skip rules")
            if self._rested:
                return OUTPUTS_UNCHANGED
            val = self.values
            for name, value in self._rest_values:
                val[name] = value
            self._counters = (0, 0, True)
            self._rested = True
            return None
        # poses (n_dynamic x 6, flat in scene order): the model reshapes them; a step whose
        # results are all the objects already written (far pairs, pairs at rest) and whose
        # counters repeat changes no output (the base class then skips its output check)
        wrote = self._publish(self.model.query(inputs, h))
        self._last_inputs = inputs
        self._rested = False
        return None if wrote else OUTPUTS_UNCHANGED

    def get_model_state(self):
        return {"model": self.model.get_state(), "inputs": self._last_inputs, "rested": self._rested}

    def set_model_state(self, state):
        self.model.set_state(state["model"])
        self._shown = [None] * len(self.model.pairs)
        self._counters = None
        self._last_inputs, self._rested = state["inputs"], state["rested"]
