"""The platform's whole 33 ms macro step as one native call.

Per macro step the simulator needs: the washout filter (:func:`.cueing.washout_sx`), the
workspace check of the resulting pose reference (IK eq. 6-14..6-19 and the limits of
:func:`.kinematics.within_limits`), the integration of the closed loop over the step, and the
outputs at the end (IK of the pose, actuator forces, saturation / near-singular / at-rest flags,
:func:`.kinematics.singular_flags`). Each of these is a CasADi expression, so they are three
CasADi Functions

``pre(w, s, ctrl, wm, p) -> (w_next, raw_ref, inside, reach_ref)``
    washout (or the pose input when ``ctrl[0] = 0``) and the workspace check of the reference;
``check(q, p) -> (inside, reach)``
    the workspace check of one pose, for clamping a reference found outside;
``sub(x, u, p, c, hs) -> x_next``
    one RK4 substep of the closed loop (:func:`.integrators.rk4_substep`);
``post(x, u, p, c, raw_ref, reach_ref, clamped, ctrl, w) -> out``
    the packed outputs (:data:`OUT`),

generated to C together with a small C driver that chains ``pre``, ``ctrl[2]`` substeps of
``sub`` and ``post`` over buffers that live for the whole simulation. A macro step is then a
single ``ctypes`` call with four pointer arguments and no numpy<->CasADi conversion. A reference
outside the workspace is clamped in the driver by the bisection of
:func:`.kinematics.clamp_to_workspace` (24 halvings of the segment from home, with ``check``);
with ``on_workspace = 'error'`` (``ctrl[4] = 0``) the driver stops after ``pre`` (return code 2)
and the caller raises. The library is compiled with the system C compiler and cached by the
hash of its source (:mod:`.codegen`); without a compiler, or for the other integrators, the
same ``pre``/``post`` Functions are called one by one (CasADi VM or compiled) around
:meth:`.integrators.StepIntegrator.step`, with the same arithmetic.

Packed layouts (all float64):

* step inputs ``s`` (:data:`NIN`): specific force (3), angular rate (3), jolt, pose reference (6),
  actuator force command (6);
* ``ctrl`` (:data:`NCTRL`): cueing is washout (1/0), macro step h (s), substeps, cos_beta_min,
  clamp a reference outside the workspace (1) or stop (0);
* state (:data:`NSTATE`): closed-loop state x (24), washout state (21), inputs u (12) of the last
  step, raw reference (6), reach ratios of the (clamped) reference (6);
* outputs (:data:`NOUT`): see :data:`OUT`.
"""
from __future__ import annotations

import ctypes
import functools
import hashlib
import logging
import pickle
from pathlib import Path
from typing import Optional

import casadi as ca
import numpy as np

from ..cachefiles import write_atomic
from .codegen import CFLAGS, RK4_LOOP_C, FastFunction, _work_sizes, cache_dir, compile_library
from .control import NC, prefiltered_loop
from .cueing import NWM, NWS, washout_sx
from .dynamics import NP, functions, param_dict
from .integrators import rk4_substep

log = logging.getLogger(__name__)

NX = 24
NU = 12
NIN = 19
NCTRL = 5
#: bisection steps when clamping a reference (as :func:`.kinematics.clamp_to_workspace`)
CLAMP_ITERS = 24
#: slices of the packed state
X, W, U, RAW, REACH = slice(0, 24), slice(24, 45), slice(45, 57), slice(57, 63), slice(63, 69)
NSTATE = 69
#: offsets of the packed outputs
OUT = dict(pose=slice(0, 6), vel=slice(6, 12), stroke=slice(12, 18), force=slice(18, 24), track_err=24,
           saturated=25, near_singular=26, outside_workspace=27, at_rest=28, x_finite=29, stroke_finite=30)
NOUT = 31
#: |x_i| below this (and zero inputs, empty washout filters) is "at rest"
REST_TOL = 1e-9
WASHOUT_REST_TOL = 1e-12
_BIG = float(np.finfo(float).max)


def _all(conds):
    out = conds[0]
    for cnd in conds[1:]:
        out = ca.logic_and(out, cnd)
    return out


def _any(conds):
    out = conds[0]
    for cnd in conds[1:]:
        out = ca.logic_or(out, cnd)
    return out


def inside_sx(dl, reach, P):
    """1 if strokes dl (6) and reach ratios (6) are inside the workspace (:func:`.kinematics.within_limits`).

    Written with comparisons only, so a NaN (rod out of reach) fails as in numpy.
    """
    return _all([cnd for i in range(6) for cnd in (reach[i] >= P["reach_margin"], dl[i] >= P["stroke_min"],
                                                    dl[i] <= P["stroke_max"])])


@functools.lru_cache(maxsize=None)
def pre_function(name: str = "platform_pre") -> ca.Function:
    """``pre(w[21], s[19], ctrl[4], wm[NWM], p[NP]) -> (w_next[21], raw_ref[6], inside, reach[6])``.

    Washout step (eq. of :mod:`.cueing`) when ``ctrl[0]`` is 1, else the pose input ``s[7:13]``
    (the washout state is kept); IK eq. 6-14..6-19 of that reference and the workspace check.
    """
    w, s, ctrl = ca.SX.sym("w", NWS), ca.SX.sym("s", NIN), ca.SX.sym("ctrl", NCTRL)
    wm, pv = ca.SX.sym("wm", NWM), ca.SX.sym("p", NP)
    w_wash, ref_wash = washout_sx(w, s[:7], wm)
    washout = ctrl[0] != 0
    raw = ca.vertcat(*[ca.if_else(washout, ref_wash[i], s[7 + i]) for i in range(6)])
    w_next = ca.vertcat(*[ca.if_else(washout, w_wash[i], w[i]) for i in range(NWS)])
    dl, reach = functions()["ik"](raw, pv)
    inside = inside_sx(dl, reach, param_dict(pv))
    return ca.Function(name, [w, s, ctrl, wm, pv], [w_next, raw, inside, reach],
                       ["w", "s", "ctrl", "wm", "p"], ["w_next", "raw_ref", "inside", "reach"])


@functools.lru_cache(maxsize=None)
def check_function(name: str = "platform_check") -> ca.Function:
    """``check(q[6], p[NP]) -> (inside, reach[6])``: workspace check of one pose (IK eq. 6-14..6-19)."""
    q, pv = ca.SX.sym("q", 6), ca.SX.sym("p", NP)
    dl, reach = functions()["ik"](q, pv)
    return ca.Function(name, [q, pv], [inside_sx(dl, reach, param_dict(pv)), reach], ["q", "p"], ["inside", "reach"])


@functools.lru_cache(maxsize=None)
def post_function(rhs: ca.Function) -> ca.Function:
    """``post(x, u, p, c, raw_ref, reach_ref, clamped, ctrl, w) -> out[NOUT]``: outputs at the end of a step.

    Pose and rates; strokes eq. 6-14..6-19; actuator force demand of the closed loop ``rhs`` clipped
    to +-F_max and its saturation flag; |C - r| (tracking error against the prefiltered
    reference); near-singular flag of :func:`.kinematics.singular_flags` on the pose, the clamped
    reference (beta and rods) and the raw reference (beta); at-rest flag; finiteness flags of the
    state and of the strokes (the caller raises on them).
    """
    x, u = ca.SX.sym("x", NX), ca.SX.sym("u", NU)
    pv, cv = ca.SX.sym("p", NP), ca.SX.sym("c", NC)
    raw, reach_ref, clamped = ca.SX.sym("raw_ref", 6), ca.SX.sym("reach_ref", 6), ca.SX.sym("clamped")
    ctrl, w = ca.SX.sym("ctrl", NCTRL), ca.SX.sym("w", NWS)
    P = param_dict(pv)
    q = x[:6]
    dl, reach = functions()["ik"](q, pv)
    F = rhs(x, u, pv, cv)[1]
    Fmax = cv[2]
    rmin, cbm = 2.0 * P["reach_margin"], ctrl[3]
    sat = _any([ca.fabs(F[i]) > Fmax for i in range(6)])
    sing = _any([ca.fabs(ca.cos(b)) < cbm for b in (q[4], u[4], raw[4])]
                + [ca.logic_not(r[i] >= rmin) for r in (reach, reach_ref) for i in range(6)]
                + [ca.logic_not(1.0 >= rmin)])
    d = q[:3] - x[12:15]
    rest = _all([ca.fabs(x[i]) < REST_TOL for i in range(NX)] + [u[i] == 0 for i in range(NU)]
                + [ca.fabs(w[i]) < WASHOUT_REST_TOL for i in range(NWS)])
    x_ok = _all([ca.fabs(x[i]) <= _BIG for i in range(NX)])
    dl_ok = _all([ca.fabs(dl[i]) <= _BIG for i in range(6)])
    out = ca.vertcat(q, x[6:12], dl, ca.fmin(ca.fmax(F, -Fmax), Fmax), ca.sqrt(ca.sumsqr(d)),
                     sat, sing, clamped, rest, x_ok, dl_ok)
    assert out.numel() == NOUT
    return ca.Function(f"{rhs.name()}_post", [x, u, pv, cv, raw, reach_ref, clamped, ctrl, w], [out],
                       ["x", "u", "p", "c", "raw_ref", "reach_ref", "clamped", "ctrl", "w"], ["out"])


DRIVER_C = r"""
/* one platform macro step: pre, n RK4 substeps (the RK4 loop above), post (see macrostep.py) */
CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w) {{
  const casadi_real *st = arg[0], *s = arg[1], *ctrl = arg[2], *wm = arg[3], *p = arg[4], *c = arg[5];
  casadi_real *nx = res[0], *out = res[1], *inside = res[2];
  casadi_real xin[{nx}], u[{nu}], hs, clamped = 0, lo, hi, mid, ok;
  const casadi_real* a[{sz_arg}];
  casadi_real* r[{sz_res}];
  casadi_int i, k, n = (casadi_int) ctrl[2];
  a[0] = st + {ow}; a[1] = s; a[2] = ctrl; a[3] = wm; a[4] = p;
  r[0] = nx + {ow}; r[1] = nx + {oraw}; r[2] = inside; r[3] = nx + {oreach};
  if ({pre}(a, r, iw, w, 0)) return 1;
  for (i = 0; i < 6; ++i) {{ u[i] = nx[{oraw} + i]; u[6 + i] = s[13 + i]; }}
  if (inside[0] == 0) {{
    if (ctrl[4] == 0) return 2;
    /* bisection on the segment from home to the reference (kinematics.clamp_to_workspace) */
    lo = 0; hi = 1;
    a[0] = xin; a[1] = p; r[0] = &ok; r[1] = nx + {oreach};
    for (k = 0; k < {iters}; ++k) {{
      mid = 0.5 * (lo + hi);
      for (i = 0; i < 6; ++i) xin[i] = 0.0 + mid * nx[{oraw} + i];
      if ({check}(a, r, iw, w, 0)) return 1;
      if (ok != 0) lo = mid; else hi = mid;
    }}
    for (i = 0; i < 6; ++i) u[i] = xin[i] = 0.0 + lo * nx[{oraw} + i];
    if ({check}(a, r, iw, w, 0)) return 1;
    clamped = 1;
  }}
  for (i = 0; i < {nu}; ++i) nx[{ou} + i] = u[i];
  hs = ctrl[1] / n;
  if ({loop}(st, u, p, c, hs, n, nx, iw, w)) return 1;  /* codegen.RK4_LOOP_C */
  a[0] = nx; a[1] = u; a[2] = p; a[3] = c; a[4] = nx + {oraw}; a[5] = nx + {oreach}; a[6] = &clamped;
  a[7] = ctrl; a[8] = nx + {ow};
  r[0] = out;
  if ({post}(a, r, iw, w, 0)) return 1;
  return 0;
}}
"""


@functools.lru_cache(maxsize=None)
def _library(rhs: ca.Function):
    """(library or None, (pre, check, sub, post), (driver name, its sz_arg, sz_res)) for the closed loop
    ``rhs``, compiled once per process."""
    fns, driver, extra_c = macro_parts(rhs)
    return compile_library(driver[0], list(fns), extra_c), fns, driver


@functools.lru_cache(maxsize=None)
def stored_library(control: str, model: str) -> Optional[tuple]:
    """:func:`_library` of ``prefiltered_loop(control, model)`` without building it again: the
    Functions (CasADi's serialization) and the compiled library's path are kept in the codegen
    cache (:func:`.codegen.cache_dir`), keyed by ``control``, ``model``, CasADi's version, the C
    flags and the sources of this package, which are all the generated code depends on. A missing
    or damaged entry is made again (building the closed loop and generating its C, ~0.1 s). None
    without a C compiler."""
    here = Path(__file__).parent
    h = hashlib.sha256(f"{control}\n{model}\n{ca.__version__}\n{' '.join(CFLAGS)}".encode())
    for src in sorted(here.glob("*.py")):
        h.update(src.name.encode() + b"\0" + src.read_bytes())
    entry = cache_dir() / f"macro_{h.hexdigest()[:24]}.pickle"
    try:
        rec = pickle.loads(entry.read_bytes())
        fns = tuple(ca.Function.deserialize(s) for s in rec["functions"])
        return ctypes.CDLL(rec["library"]), fns, tuple(rec["driver"])
    except (OSError, KeyError, TypeError, ValueError, RuntimeError, EOFError, pickle.UnpicklingError):
        pass   # (absent, cut or damaged; a library removed from the cache)
    lib, fns, driver = _library(prefiltered_loop(control, model))
    if lib is None:
        return None
    rec = {"functions": [f.serialize() for f in fns], "library": lib._name, "driver": list(driver)}
    try:
        write_atomic(entry, lambda f: f.write(pickle.dumps(rec)))
    except OSError:   # a read-only or full cache: the next run builds it again
        pass
    return lib, fns, driver


def macro_parts(rhs: ca.Function):
    """((pre, check, sub, post), (driver name, its sz_arg, sz_res), C of the RK4 loop and the driver)
    for the closed loop ``rhs``; :func:`.codegen.library_source` of these is the library's whole C."""
    pre = pre_function(f"{rhs.name()}_pre")
    check = check_function(f"{rhs.name()}_check")
    sub = rk4_substep(rhs)
    post = post_function(rhs)
    name = f"{rhs.name()}_macro"
    fns = (pre, check, sub, post)
    sz_arg, sz_res = max(max(f.sz_arg() for f in fns), 9), max(max(f.sz_res() for f in fns), 4)
    loop = f"{name}_rk4_loop"
    c_src = RK4_LOOP_C.format(name=loop, sub=sub.name(), nx=NX, sz_arg=sz_arg, sz_res=sz_res)
    c_src += DRIVER_C.format(name=name, pre=pre.name(), check=check.name(), loop=loop, post=post.name(),
                             nx=NX, nu=NU, iters=CLAMP_ITERS, sz_arg=sz_arg, sz_res=sz_res,
                             ow=W.start, ou=U.start, oraw=RAW.start, oreach=REACH.start)
    return fns, (name, sz_arg, sz_res), c_src


class MacroStep:
    """Buffers and compiled code of one platform's macro step.

    Parameters
    ----------
    rhs : casadi.Function
        Closed loop ``rhs(x[24], u[12], p, c) -> (xdot, F)`` (:func:`.control.prefiltered_loop`).
    compiled : bool
        Use the C compiler when there is one.
    driver : bool
        Bind the one-call C driver (the RK4 integrator); otherwise :meth:`run` returns -1 and the
        caller composes :attr:`pre`, its integrator and :attr:`post`.

    Attributes
    ----------
    state, next : ndarray (NSTATE,)
        Packed state before the step and as computed by it (committed by the caller).
    s, ctrl, wm, p, c : ndarray
        Inputs of the step, see the module docstring.
    pre, check, post : FastFunction
        The CasADi Functions of the module docstring, for the composed path.
    out : ndarray (NOUT,)
        Packed outputs of the last computed step.
    inside : ndarray (1,)
        Whether the raw reference of the step is inside the workspace.
    """

    def __init__(self, rhs: Optional[ca.Function], compiled: bool = True, driver: bool = True,
                 library: Optional[tuple] = None) -> None:
        if library is not None:
            lib, fns, driver_c = library
        elif compiled:
            lib, fns, driver_c = _library(rhs)
        else:
            lib, fns, driver_c = None, (pre_function(f"{rhs.name()}_pre"), check_function(f"{rhs.name()}_check"),
                                        None, post_function(rhs)), None
        pre, check, post = fns[0], fns[1], fns[3]
        self.pre = FastFunction(pre, lib)
        self.check = FastFunction(check, lib)
        self.post = FastFunction(post, lib)
        self.compiled = self.pre.compiled and self.post.compiled
        self.state, self.next = np.zeros(NSTATE), np.zeros(NSTATE)
        self.s, self.ctrl = np.zeros(NIN), np.zeros(NCTRL)
        self.wm, self.p, self.c = np.zeros(NWM), np.zeros(NP), np.zeros(NC)
        self.out, self.inside = np.zeros(NOUT), np.zeros(1)
        self._call: Optional[tuple] = None
        sizes = [_work_sizes(lib, f) for f in fns] if lib is not None else []
        if sizes and any(sz[0] > driver_c[1] or sz[1] > driver_c[2] for sz in sizes):
            log.warning("generated code of %s needs larger argument arrays than its driver: composed path",
                        driver_c[0])
            driver = False
        if lib is not None and driver and self.compiled:
            fn = getattr(lib, driver_c[0])
            fn.restype = ctypes.c_int
            fn.argtypes = [ctypes.c_void_p] * 4
            self._iw = np.zeros(max(max(s[2] for s in sizes), 1), np.int64)
            self._w = np.zeros(max(max(s[3] for s in sizes), 1))
            P = ctypes.c_void_p
            self._arg = (P * 6)(*[b.ctypes.data for b in (self.state, self.s, self.ctrl, self.wm, self.p, self.c)])
            self._res = (P * 3)(*[b.ctypes.data for b in (self.next, self.out, self.inside)])
            self._call = (fn, self._arg, self._res, self._iw.ctypes.data, self._w.ctypes.data)

    @property
    def has_driver(self) -> bool:
        return self._call is not None

    def run(self) -> int:
        """One macro step in native code: 0 done (``next``, ``out`` filled), 2 reference outside the
        workspace and ``ctrl[4] = 0`` (only the ``pre`` outputs in ``next`` are valid), -1 no driver."""
        if self._call is None:
            return -1
        fn, arg, res, iw, w = self._call
        rc = fn(arg, res, iw, w)
        if rc == 1:
            raise ArithmeticError("compiled platform macro step returned an error")
        return rc

    def run_pre(self) -> None:
        """``pre`` alone (into ``next``, ``inside``), for the composed path."""
        w_next, raw, inside, reach = self.pre(self.state[W], self.s, self.ctrl, self.wm, self.p)
        self.next[W], self.next[RAW], self.next[REACH] = w_next, raw, reach
        self.inside[0] = inside[0]

    def run_post(self, clamped: bool) -> None:
        """``post`` on ``next`` (state after the integration) into ``out``."""
        n = self.next
        self.out[:] = self.post(n[X], n[U], self.p, self.c, n[RAW], n[REACH], float(clamped), self.ctrl, n[W])[0]
