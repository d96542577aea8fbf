"""One platform as a macro-step simulator: cueing -> workspace clamp -> prefilter -> controller ->
dynamics -> outputs. The FMU wrapper ``fmus/platform/platform_fmu.py`` only maps variables onto it.

With the default RK4 integrator a step is one native call (:mod:`.macrostep`: washout, workspace
check of the reference, N RK4 substeps, outputs); a reference outside the workspace (clamped by
bisection here), the other integrators and a machine without a C compiler take the composed
path (``pre``, :class:`.integrators.StepIntegrator`, ``post``) with the same arithmetic.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from . import macrostep as ms
from .control import CONTROLS, MODELS, ControlParams, prefiltered_loop
from .cueing import WashoutParams, washout_matrices
from .integrators import IntegratorConfig, StepIntegrator
from .kinematics import OutsideWorkspaceError, clamp_to_workspace
from .params import PlatformParams

log = logging.getLogger(__name__)


_X_FINITE, _STROKE_FINITE, _AT_REST = ms.OUT["x_finite"], ms.OUT["stroke_finite"], ms.OUT["at_rest"]
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
        return not self.packed().any()

    def packed(self) -> np.ndarray:
        """The packed input vector (19,) of :mod:`.macrostep`: f, omega, jolt, ref, force_cmd."""
        return np.concatenate([np.asarray(self.f, float).ravel(), np.asarray(self.omega, float).ravel(),
                               [float(self.jolt)], np.asarray(self.ref, float).ravel(),
                               np.asarray(self.force_cmd, float).ravel()])


def _view(key):
    return property(lambda self: self.packed[ms.OUT[key]], doc=f"{key} (view of the packed outputs)")


def _flag(key):
    i = ms.OUT[key]
    return property(lambda self: bool(self.packed[i]), doc=f"{key} flag")


class StepOutputs:
    """Outputs at the end of a macro step: pose (6, m and rad), vel (6), stroke (6, m), force (6, N,
    clipped to F_max), track_err (m) and the flags; all read from one packed vector (:data:`.macrostep.OUT`)
    that belongs to this object."""

    __slots__ = ("packed",)

    def __init__(self, packed: np.ndarray) -> None:
        self.packed = packed

    pose, vel, stroke, force = _view("pose"), _view("vel"), _view("stroke"), _view("force")
    saturated, near_singular = _flag("saturated"), _flag("near_singular")
    outside_workspace, at_rest = _flag("outside_workspace"), _flag("at_rest")

    @property
    def track_err(self) -> float:
        return float(self.packed[ms.OUT["track_err"]])


class PlatformSim:
    """Stateful platform simulation advanced in macro steps.

    The state (closed loop, washout filters, last inputs, references) is one packed vector
    (:data:`.macrostep.NSTATE`); a step that raises leaves it as it was before the step.
    """

    REST_TOL = ms.REST_TOL

    def __init__(self, cfg: SimConfig = SimConfig()) -> None:
        self.cfg = cfg
        self.p = cfg.params.vector()
        self.c = cfg.control.vector()
        ic = cfg.integrator
        # the compiled driver's Functions and library from the cache: no closed loop to build
        stored = ms.stored_library(cfg.control_mode, cfg.model) if ic.compiled and ic.method == "rk4" else None
        rhs = None if stored else prefiltered_loop(cfg.control_mode, cfg.model)
        self.macro = m = ms.MacroStep(rhs, compiled=ic.compiled, driver=ic.method == "rk4", library=stored)
        # the composed path's integrator; the driver integrates the step itself (with it the
        # composed path only runs to raise on a reference outside the workspace)
        self.integ = None if m.has_driver else StepIntegrator(rhs or prefiltered_loop(cfg.control_mode, cfg.model), ic)
        m.p[:], m.c[:] = self.p, self.c
        m.ctrl[:] = (cfg.cueing == "washout", 0.0, int(ic.substeps), cfg.cos_beta_min, cfg.on_workspace == "clamp")
        m.state[ms.REACH] = 1.0
        self._h = None
        self.skipped_steps = 0
        # home at rest is an equilibrium only under a controller (gravity compensated); with direct
        # actuator forces zero inputs let the platform fall, so no step may be skipped
        self._lazy = cfg.control_mode != "direct"
        m.next[:] = m.state
        m.run_post(False)
        self.out = StepOutputs(m.out.copy())
        self._rest = self.out.at_rest

    # -- state (views of the packed state) ----------------------------------------------
    x = property(lambda self: self.macro.state[ms.X], doc="closed-loop state (q, q', r, r') (24,)")
    u = property(lambda self: self.macro.state[ms.U], doc="inputs of the last step: clamped reference, force command (12,)")
    raw_ref = property(lambda self: self.macro.state[ms.RAW], doc="pose reference before clamping (6,)")
    clamped = property(lambda self: self.out.outside_workspace, doc="the last reference was clamped")

    def get_state(self):
        return {"state": self.macro.state.copy(), "out": self.out}

    def set_state(self, s) -> None:
        self.macro.state[:] = s["state"]
        self.out = s["out"]
        self._rest = self.out.at_rest

    def at_rest(self) -> bool:
        """Home pose, no motion, zero reference and force command, washout filters empty."""
        return self._rest

    # -- stepping -----------------------------------------------------------------------
    def step(self, inp: StepInputs, h: float, t: float = 0.0) -> StepOutputs:
        """Advance from t to t + h (s) with ``inp`` held; returns the outputs at t + h."""
        return self.step_packed(inp.packed(), h, t)

    def step_packed(self, s, h: float, t: float = 0.0) -> StepOutputs:
        """:meth:`step` with the packed inputs (19,) of :mod:`.macrostep` (any float sequence)."""
        m = self.macro
        m.s[:] = s
        if self._rest and self._lazy and not m.s.any():
            self.skipped_steps += 1  # lazy: nothing moves, outputs stay as they are
            return self.out
        if h != self._h:
            m.wm[:] = washout_matrices(self.cfg.washout, h)
            m.ctrl[1] = h
            self._h = h
        rc = m.run()
        if rc != 0:
            self._composed_step(rc, h, t)
        out = m.out
        if not out[_X_FINITE]:
            raise ArithmeticError(f"platform state became non-finite in the step ending at t = {t + h:g} s "
                                  f"(integrator {self.cfg.integrator.method}): a rod lost its slider (out of reach) "
                                  f"or the integration diverged")
        if not out[_STROKE_FINITE]:
            raise OutsideWorkspaceError(
                f"the platform left the rods' reach at t = {t + h:g} s: pose {np.array2string(m.next[:6], precision=4)}")
        m.state[:] = m.next
        self.out = StepOutputs(out.copy())
        self._rest = bool(out[_AT_REST])
        return self.out

    def _composed_step(self, rc: int, h: float, t: float) -> None:
        """The step in pieces: ``pre`` (unless the driver ran it), clamping, integrator, ``post``."""
        m = self.macro
        if rc < 0:
            m.run_pre()
        n = m.next
        clamped = False
        if not m.inside[0]:
            ref, clamped, n[ms.REACH] = self._limit(n[ms.RAW].copy(), t)
        else:
            ref = n[ms.RAW]
        n[ms.U] = np.concatenate([ref, m.s[13:19]])
        n[ms.X] = self.integ.step(m.state[ms.X], n[ms.U].copy(), self.p, self.c, h)
        m.run_post(clamped)

    def _inside(self, pose) -> tuple:
        """(inside, reach ratios) of one pose: the driver's workspace check (:func:`.macrostep.check_function`)."""
        inside, reach = self.macro.check(pose, self.p)
        return bool(inside[0]), reach

    def _limit(self, ref: np.ndarray, t: float):
        """(reference inside the workspace, clamped?, its reach ratios) of a reference found outside."""
        if self.cfg.on_workspace == "error":
            raise OutsideWorkspaceError(
                f"pose reference {np.array2string(ref, precision=4)} at t = {t:g} s is outside the workspace "
                f"(strokes {self.cfg.params.stroke_min:g}..{self.cfg.params.stroke_max:g} m, rod reach)")
        ref, clamped = clamp_to_workspace(ref, self.cfg.params, inside=lambda pose: self._inside(pose)[0])
        return ref, clamped, self._inside(ref)[1]
