"""One platform as a macro-step simulator: cueing -> workspace clamp -> prefilter -> controller ->
dynamics -> outputs. The FMU wrapper ``fmus/platform/platform_fmu.py`` only maps variables onto it.
"""
from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field

import numpy as np

from .control import CONTROLS, MODELS, ControlParams, prefiltered_loop
from .codegen import FastFunction, compile_library
from .cueing import Washout, WashoutParams
from .dynamics import functions
from .integrators import IntegratorConfig, StepIntegrator
from .kinematics import OutsideWorkspaceError, clamp_to_workspace, singular_flags, within_limits
from .params import PlatformParams

log = logging.getLogger(__name__)


@functools.lru_cache(maxsize=None)
def _ik_library():
    return compile_library("platform_ik", [functions()["ik"]])

CUEING = ("washout", "pose")
ON_WORKSPACE = ("clamp", "error")


@dataclass(frozen=True)
class SimConfig:
    """Everything that configures a platform simulation (see the unit README for defaults)."""

    params: PlatformParams = field(default_factory=PlatformParams)
    control: ControlParams = field(default_factory=ControlParams)
    washout: WashoutParams = field(default_factory=WashoutParams)
    integrator: IntegratorConfig = field(default_factory=IntegratorConfig)
    control_mode: str = "computed_torque"
    model: str = "full"
    cueing: str = "washout"
    on_workspace: str = "clamp"
    cos_beta_min: float = 0.17

    def __post_init__(self) -> None:
        for name, allowed in (("control_mode", CONTROLS), ("model", MODELS), ("cueing", CUEING),
                              ("on_workspace", ON_WORKSPACE)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} = {getattr(self, name)!r} is not one of {', '.join(allowed)}")


@dataclass
class StepInputs:
    """Inputs held over one macro step."""

    f: np.ndarray = field(default_factory=lambda: np.zeros(3))      # avatar specific force - 1 g, m/s^2
    omega: np.ndarray = field(default_factory=lambda: np.zeros(3))  # avatar angular rate, rad/s
    jolt: float = 0.0                                                # collision jolt, m/s^2
    ref: np.ndarray = field(default_factory=lambda: np.zeros(6))    # pose reference (cueing = pose)
    force_cmd: np.ndarray = field(default_factory=lambda: np.zeros(6))  # N (control = direct)

    def is_zero(self) -> bool:
        return not (self.jolt or self.f.any() or self.omega.any() or self.ref.any() or self.force_cmd.any())


@dataclass
class StepOutputs:
    pose: np.ndarray
    vel: np.ndarray
    stroke: np.ndarray
    force: np.ndarray
    track_err: float
    saturated: bool
    near_singular: bool
    outside_workspace: bool
    at_rest: bool


class PlatformSim:
    """Stateful platform simulation advanced in macro steps."""

    REST_TOL = 1e-9

    def __init__(self, cfg: SimConfig = SimConfig()) -> None:
        self.cfg = cfg
        self.p = cfg.params.vector()
        self.c = cfg.control.vector()
        self.integ = StepIntegrator(prefiltered_loop(cfg.control_mode, cfg.model), cfg.integrator)
        self.washout = Washout(cfg.washout)
        self._ik = FastFunction(functions()["ik"], _ik_library())
        self.raw_ref = np.zeros(6)
        self._ref_reach = np.ones(6)
        self.x = np.zeros(24)
        self.u = np.zeros(12)
        self.clamped = False
        self.skipped_steps = 0
        self.out = self._outputs()

    # -- state --------------------------------------------------------------------------
    def get_state(self):
        return {"x": self.x.copy(), "u": self.u.copy(), "washout": self.washout.state(), "clamped": self.clamped,
                "raw_ref": self.raw_ref.copy(), "ref_reach": self._ref_reach.copy(), "out": self.out}

    def set_state(self, s) -> None:
        self.x, self.u = s["x"].copy(), s["u"].copy()
        self.washout.set_state(s["washout"])
        self.clamped = s["clamped"]
        self.raw_ref = s["raw_ref"].copy()
        self._ref_reach = s["ref_reach"].copy()
        self.out = s["out"]

    def at_rest(self) -> bool:
        """Home pose, no motion, zero reference and force command, washout filters empty."""
        return bool(np.all(np.abs(self.x) < self.REST_TOL) and not np.any(self.u) and self.washout.at_rest())

    # -- stepping -----------------------------------------------------------------------
    def step(self, inp: StepInputs, h: float, t: float = 0.0) -> StepOutputs:
        """Advance from t to t + h (s) with ``inp`` held; returns the outputs at t + h."""
        if inp.is_zero() and self.at_rest():
            self.skipped_steps += 1  # lazy: nothing moves, outputs stay as they are
            return self.out
        cfg = self.cfg
        if cfg.cueing == "washout":
            ref = self.washout.step(inp.f, inp.omega, inp.jolt, h)
        else:
            ref = np.asarray(inp.ref, float)
        self.raw_ref = ref
        ref, self.clamped, self._ref_reach = self._limit(ref, t)
        self.u = np.concatenate([ref, inp.force_cmd])
        x = self.integ.step(self.x, self.u, self.p, self.c, h)
        if not np.isfinite(x).all():
            raise ArithmeticError(f"platform state became non-finite in the step ending at t = {t + h:g} s "
                                  f"(integrator {cfg.integrator.method}): a rod lost its slider (out of reach) "
                                  f"or the integration diverged")
        self.x = x
        self.out = self._outputs()
        if not np.isfinite(self.out.stroke).all():
            raise OutsideWorkspaceError(
                f"the platform left the rods' reach at t = {t + h:g} s: pose {np.array2string(x[:6], precision=4)}")
        return self.out

    def _inside(self, pose) -> tuple:
        """(inside, strokes, reach) of one pose with the compiled IK."""
        dl, reach = self._ik(pose, self.p)
        reach_ok, stroke_ok = within_limits(dl, reach, self.cfg.params)
        return bool(reach_ok and stroke_ok), dl, reach

    def _limit(self, ref: np.ndarray, t: float):
        """(reference inside the workspace, clamped?, its reach ratios)."""
        inside, _, reach = self._inside(ref)
        if inside:
            return ref, False, reach
        if self.cfg.on_workspace == "error":
            raise OutsideWorkspaceError(
                f"pose reference {np.array2string(ref, precision=4)} at t = {t:g} s is outside the workspace "
                f"(strokes {self.cfg.params.stroke_min:g}..{self.cfg.params.stroke_max:g} m, rod reach)")
        ref = clamp_to_workspace(ref, self.cfg.params, inside=lambda pose: self._inside(pose)[0])[0]
        return ref, True, self._inside(ref)[2]

    def _outputs(self) -> StepOutputs:
        q, dq, r = self.x[:6], self.x[6:12], self.x[12:18]
        _, dl, reach = self._inside(q)
        reach_ref = self._ref_reach
        _, F = self.integ.rhs(self.x, self.u, self.p, self.c)
        Fmax = self.cfg.control.F_max
        sat = bool(np.abs(F).max() > Fmax)
        # the pose and the clamped reference (beta and rods), the raw reference (beta only)
        sing = bool(singular_flags(np.array([q[4], self.u[4], self.raw_ref[4]]),
                                   np.array([reach, reach_ref, np.ones(6)]), self.cfg.params,
                                   self.cfg.cos_beta_min).any())
        return StepOutputs(pose=q.copy(), vel=dq.copy(), stroke=dl,
                           force=np.minimum(np.maximum(F, -Fmax), Fmax),
                           track_err=math.dist(q[:3], r[:3]), saturated=sat, near_singular=sing,
                           outside_workspace=self.clamped, at_rest=self.at_rest())
