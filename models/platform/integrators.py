"""Integration of the closed-loop platform over one macro step (33 ms), selectable by a config.

Methods (``IntegratorConfig.method``):

``rk4``
    classical explicit Runge-Kutta 4 with ``substeps`` equal substeps; the substep is one CasADi
    Function, compiled to C with the n-substep loop in C (:mod:`.codegen`), so one macro step is a
    single native call. The fast default.
``implicit``
    CasADi ``integrator('collocation')``: Radau IIA collocation of order 2*3-1 = 5 on ``substeps``
    finite elements, Newton on the collocation equations (A-stable, for stiff settings).
``cvode_bdf`` / ``cvode_adams``
    SUNDIALS CVODE through scikit-sundae, variable step and order with ``rtol``/``atol``; the
    right-hand side is a Python callback (the compiled CasADi right-hand side behind it).
``dop853``
    scipy ``solve_ivp`` DOP853, the tight-tolerance reference.

The right-hand side is any CasADi Function ``rhs(x, u, p, c) -> (xdot, F)`` with the inputs held
constant over the macro step (e.g. :func:`.control.prefiltered_loop`).
"""
from __future__ import annotations

import ctypes
import functools
import logging
from dataclasses import dataclass

import casadi as ca
import numpy as np

from .codegen import RK4_LOOP_C, FastFunction, compile_library

log = logging.getLogger(__name__)

METHODS = ("rk4", "implicit", "cvode_bdf", "cvode_adams", "dop853")


class IntegrationError(RuntimeError):
    """An integrator failed inside a macro step."""


@dataclass(frozen=True)
class IntegratorConfig:
    """Choice and settings of the macro-step integrator.

    Attributes
    ----------
    method : str
        One of :data:`METHODS`.
    substeps : int
        Substeps (rk4) or finite elements (implicit) per macro step.
    rtol, atol : float
        Tolerances of the adaptive methods (cvode_*, dop853).
    compiled : bool
        Compile the CasADi functions to C when a compiler is available.
    """

    method: str = "rk4"
    substeps: int = 2
    rtol: float = 1e-8
    atol: float = 1e-10
    compiled: bool = True

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"integrator {self.method!r} is not one of {', '.join(METHODS)}")
        if int(self.substeps) < 1:
            raise ValueError(f"substeps = {self.substeps} must be >= 1")
        if not (self.rtol > 0 and self.atol > 0):
            raise ValueError(f"tolerances rtol = {self.rtol}, atol = {self.atol} must be > 0")


def rk4_substep(rhs: ca.Function) -> ca.Function:
    """``sub(x, u, p, c, hs) -> x_next``: one classical RK4 step of length hs (MX calling ``rhs``)."""
    ins = [ca.MX.sym(rhs.name_in(i), rhs.sparsity_in(i)) for i in range(rhs.n_in())]
    hs = ca.MX.sym("hs")
    x, rest = ins[0], ins[1:]
    k1 = rhs(x, *rest)[0]
    k2 = rhs(x + 0.5 * hs * k1, *rest)[0]
    k3 = rhs(x + 0.5 * hs * k2, *rest)[0]
    k4 = rhs(x + hs * k3, *rest)[0]
    return ca.Function(f"{rhs.name()}_rk4", [*ins, hs], [x + hs / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)])


@functools.lru_cache(maxsize=None)
def _library(rhs: ca.Function):
    """Compiled library holding ``rhs``, its RK4 substep and the C substep loop (or None)."""
    sub = rk4_substep(rhs)
    loop = _loop_name(rhs)
    extra = RK4_LOOP_C.format(name=loop, sub=sub.name(), nx=rhs.nnz_in(0), sz_arg=max(sub.sz_arg(), 5),
                           sz_res=max(sub.sz_res(), 1))
    return compile_library(rhs.name(), [rhs, sub], extra), sub


def _loop_name(rhs: ca.Function) -> str:
    return f"{rhs.name()}_rk4_loop"


class StepIntegrator:
    """Advance ``x' = rhs(x, u, p, c)[0]`` over a macro step with inputs held constant.

    One instance per simulation (it owns its buffers); the compiled code is shared per process.
    """

    def __init__(self, rhs: ca.Function, cfg: IntegratorConfig = IntegratorConfig()) -> None:
        self.cfg = cfg
        self.rhs_function = rhs
        self.nx = rhs.nnz_in(0)
        lib, sub = _library(rhs) if cfg.compiled else (None, rk4_substep(rhs))
        self._rhs = FastFunction(rhs, lib)
        self.compiled = self._rhs.compiled
        self.n_rhs = 0  # right-hand-side evaluations by Python callbacks (cvode, dop853)
        if cfg.method == "rk4":
            self._setup_rk4(lib, sub)
        elif cfg.method == "implicit":
            self._setup_implicit()
        elif cfg.method.startswith("cvode"):
            self._setup_cvode()

    # -- right-hand side ---------------------------------------------------------------
    def rhs(self, x, u, p, c):
        """(xdot, F) at state x for inputs u, plant parameters p, controller parameters c."""
        return self._rhs(x, u, p, c)

    # -- rk4 --------------------------------------------------------------------------------
    def _setup_rk4(self, lib, sub) -> None:
        self._sub = FastFunction(sub, lib)
        self._loop = None
        if lib is not None and self._sub.compiled:
            fn = getattr(lib, _loop_name(self.rhs_function))
            fn.restype = ctypes.c_int
            P = ctypes.c_void_p
            fn.argtypes = [P, P, P, P, ctypes.c_double, ctypes.c_longlong, P, P, P]
            self._loop = fn
            s = self._sub
            self._bufs = [b for b in s.in_bufs[:4]]
            self._xout = np.zeros(self.nx)
            self._ptrs = [b.ctypes.data for b in self._bufs]
            self._work = (self._xout.ctypes.data, s._iw.ctypes.data, s._w.ctypes.data)

    def _step_rk4(self, x, u, p, c, h):
        n = int(self.cfg.substeps)
        hs = h / n
        if self._loop is not None:
            b = self._bufs
            b[0][:] = x
            b[1][:] = u
            b[2][:] = p
            b[3][:] = c
            P = self._ptrs
            if self._loop(P[0], P[1], P[2], P[3], hs, n, *self._work):
                raise IntegrationError("compiled RK4 loop failed")
            return self._xout.copy()
        x = np.asarray(x, float)
        for _ in range(n):
            x = self._sub(x, u, p, c, hs)[0]
        return x

    # -- implicit collocation ------------------------------------------------------------
    def _setup_implicit(self) -> None:
        f = self.rhs_function
        x = ca.SX.sym("x", self.nx)
        par = [ca.SX.sym(f.name_in(i), f.sparsity_in(i)) for i in range(1, f.n_in())]
        h = ca.SX.sym("h")
        ode = h * f(x, *par)[0]  # time scaled to [0, 1]: h is a parameter
        self._sizes = [f.nnz_in(i) for i in range(1, f.n_in())]
        self._I = ca.integrator(f"{f.name()}_coll", "collocation",
                                {"x": x, "p": ca.vertcat(*par, h), "ode": ode}, 0.0, 1.0,
                                {"number_of_finite_elements": int(self.cfg.substeps), "interpolation_order": 3,
                                 "collocation_scheme": "radau",
                                 "rootfinder_options": {"abstol": 1e-13}})

    def _step_implicit(self, x, u, p, c, h):
        res = self._I(x0=x, p=np.concatenate([u, p, c, [h]]))
        return np.asarray(res["xf"]).ravel()

    # -- cvode ---------------------------------------------------------------------------
    def _setup_cvode(self) -> None:
        from sksundae.cvode import CVODE

        self._args = None

        def rhsfn(t, y, yp):
            self.n_rhs += 1
            yp[:] = self._rhs(y, *self._args)[0]

        method = "BDF" if self.cfg.method == "cvode_bdf" else "Adams"
        self._cvode = CVODE(rhsfn, method=method, rtol=self.cfg.rtol, atol=self.cfg.atol, max_num_steps=100000)

    def _step_cvode(self, x, u, p, c, h):
        self._args = (u, p, c)
        self._cvode.init_step(0.0, np.asarray(x, float))
        res = self._cvode.step(h)
        if not res.success:
            raise IntegrationError(f"CVODE ({self.cfg.method}) failed: {res.message}")
        return np.asarray(res.y, float).ravel().copy()

    # -- reference -----------------------------------------------------------------------
    def _step_dop853(self, x, u, p, c, h):
        from scipy.integrate import solve_ivp

        def f(t, y):
            self.n_rhs += 1
            return self._rhs(y, u, p, c)[0]

        sol = solve_ivp(f, (0.0, h), np.asarray(x, float), method="DOP853", rtol=self.cfg.rtol, atol=self.cfg.atol)
        if not sol.success:
            raise IntegrationError(f"DOP853 failed: {sol.message}")
        return sol.y[:, -1].copy()

    def step(self, x, u, p, c, h: float) -> np.ndarray:
        """State after a macro step of length h (s) from state x with constant inputs."""
        method = "cvode" if self.cfg.method.startswith("cvode") else self.cfg.method
        return getattr(self, f"_step_{method}")(x, u, p, c, h)
