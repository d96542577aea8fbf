"""FMI 2.0 co-simulation wrapper of the PSS 3-2-1 motion platform (thesis ch. 6).

The model is :class:`immersim.models.platform.simulator.PlatformSim`; this file maps FMU
variables onto it. Parameter variables are generated from the parameter dataclasses so the
defaults, units and descriptions have a single source.
"""
from dataclasses import fields
from operator import itemgetter

from immersim.fmus.common import TableSlave, Var, vector
from immersim.models.platform.control import ControlParams
from immersim.models.platform.cueing import WashoutParams
from immersim.models.platform.integrators import IntegratorConfig
from immersim.models.platform.params import PlatformParams
from immersim.models.platform.macrostep import OUT
from immersim.models.platform.simulator import PlatformSim, SimConfig

AXES = ("x", "y", "z", "gamma", "beta", "alpha")
POSE_UNITS = ("m", "m", "m", "rad", "rad", "rad")
#: input variables in the order of the simulator's packed step inputs (macrostep.NIN)
PACKED_INPUTS = (("cue.f_x", "cue.f_y", "cue.f_z", "cue.w_x", "cue.w_y", "cue.w_z", "jolt")
                 + tuple(f"ref.{a}" for a in AXES) + tuple(f"force_cmd[{i}]" for i in range(1, 7)))
#: Real outputs in the order of the simulator's packed outputs (macrostep.OUT), then the flags
PACKED_REAL_OUTPUTS = (tuple(f"pose.{a}" for a in AXES) + tuple(f"vel.{a}" for a in AXES)
                       + tuple(f"stroke[{i}]" for i in range(1, 7)) + tuple(f"force[{i}]" for i in range(1, 7))
                       + ("track_err",))
_packed_inputs = itemgetter(*PACKED_INPUTS)
FLAG_OUTPUTS = (("flag.saturated", OUT["saturated"]), ("flag.near_singular", OUT["near_singular"]),
                ("flag.outside_workspace", OUT["outside_workspace"]), ("at_rest", OUT["at_rest"]))


def _param_vars(cls, prefix):
    return tuple(Var(f"{prefix}{f.name}", "parameter", "Real", float(f.default), f.metadata["unit"],
                     f.metadata["doc"]) for f in fields(cls))


def _pose_vars(prefix, causality, what, rate=False):
    return tuple(Var(f"{prefix}.{ax}", causality, "Real", 0.0, u + ("/s" if rate else ""), f"{what} {ax}")
                 for ax, u in zip(AXES, POSE_UNITS))


class platform(TableSlave):
    modelName = "platform"
    description = "PSS 3-2-1 6-DOF motion platform: washout cueing, computed-torque control, Lagrangian dynamics, IK"
    CAN_HANDLE_STATE = True
    VARIABLES = (
        # -- inputs
        Var("cue.f_x", "input", "Real", 0.0, "m/s2", "avatar specific force minus 1 g, body x (surge)"),
        Var("cue.f_y", "input", "Real", 0.0, "m/s2", "avatar specific force minus 1 g, body y (sway)"),
        Var("cue.f_z", "input", "Real", 0.0, "m/s2", "avatar specific force minus 1 g, body z (heave)"),
        Var("cue.w_x", "input", "Real", 0.0, "rad/s", "avatar angular rate, body x (roll)"),
        Var("cue.w_y", "input", "Real", 0.0, "rad/s", "avatar angular rate, body y (pitch)"),
        Var("cue.w_z", "input", "Real", 0.0, "rad/s", "avatar angular rate, body z (yaw)"),
        Var("jolt", "input", "Real", 0.0, "m/s2",
            "collision jolt: acceleration pulse held for the step, added to surge (and jolt_heave x to heave)"),
    ) + _pose_vars("ref", "input", "pose reference (cueing = 'pose')") + vector(
        "force_cmd", 6, "input", "N", "actuator force command (control = 'direct')") + (
        # -- outputs
    ) + _pose_vars("pose", "output", "platform pose, eq. 6-48") + _pose_vars(
        "vel", "output", "platform generalized velocity", rate=True) + vector(
        "stroke", 6, "output", "m", "actuator stroke dl_i, eq. 6-14..6-19") + vector(
        "force", 6, "output", "N", "actuator force F_i (clipped to F_max)") + (
        Var("track_err", "output", "Real", 0.0, "m", "distance of C from the prefiltered reference position"),
        Var("flag.saturated", "output", "Boolean", False, "", "some actuator force demand exceeds F_max"),
        Var("flag.near_singular", "output", "Boolean", False, "",
            "|cos beta| < cos_beta_min or a rod within 2 reach_margin of perpendicular to its slider"),
        Var("flag.outside_workspace", "output", "Boolean", False, "",
            "the pose reference was outside the workspace and has been clamped"),
        Var("at_rest", "output", "Boolean", True, "",
            "home pose, at rest, zero inputs, empty filters (the step is skipped)"),
        # -- parameters
    ) + _param_vars(PlatformParams, "") + _param_vars(ControlParams, "") + _param_vars(WashoutParams, "washout.") + (
        Var("cos_beta_min", "parameter", "Real", 0.17, "1", "near-singular flag threshold on |cos beta|"),
        Var("cueing", "parameter", "String", "washout", "", "'washout' (cue.* inputs) or 'pose' (ref.* inputs)"),
        Var("control", "parameter", "String", "computed_torque", "", "'computed_torque', 'pd' or 'direct'"),
        Var("model", "parameter", "String", "full", "", "plant: 'full' Lagrangian or 'planar' eq. 6-72..6-74"),
        Var("integrator", "parameter", "String", "rk4", "", "'rk4', 'implicit', 'cvode_bdf', 'cvode_adams', 'dop853'"),
        Var("substeps", "parameter", "Integer", 2, "", "RK4 substeps / collocation elements per step"),
        Var("rtol", "parameter", "Real", 1e-8, "1", "relative tolerance (cvode_*, dop853)"),
        Var("atol", "parameter", "Real", 1e-10, "1", "absolute tolerance (cvode_*, dop853)"),
        Var("on_workspace", "parameter", "String", "clamp", "",
            "reference outside the workspace: 'clamp' (and flag) or 'error'"),
    )

    def _config(self) -> SimConfig:
        v = self.values

        def take(cls, prefix):
            return cls(**{f.name: float(v[prefix + f.name]) for f in fields(cls)})

        try:
            return SimConfig(params=take(PlatformParams, ""), control=take(ControlParams, ""),
                             washout=take(WashoutParams, "washout."),
                             integrator=IntegratorConfig(v["integrator"], int(v["substeps"]), v["rtol"], v["atol"]),
                             control_mode=v["control"], model=v["model"], cueing=v["cueing"],
                             on_workspace=v["on_workspace"], cos_beta_min=v["cos_beta_min"])
        except ValueError as exc:
            raise ValueError(f"{self.instance_name}: bad parameter: {exc}") from exc

    def setup_model(self):
        self.sim = PlatformSim(self._config())
        self._write(self.sim.out)

    def step_model(self, t, h):
        try:
            out = self.sim.step_packed(_packed_inputs(self.values), h, t)
        except (ValueError, ArithmeticError, RuntimeError) as exc:
            raise type(exc)(f"{self.instance_name}: {exc}") from exc
        self._write(out)

    def _write(self, out):
        v = self.values
        packed = out.packed.tolist()
        v.update(zip(PACKED_REAL_OUTPUTS, packed))
        for name, i in FLAG_OUTPUTS:
            v[name] = packed[i] != 0.0

    def get_model_state(self):
        return self.sim.get_state()

    def set_model_state(self, state):
        self.sim.set_state(state)
