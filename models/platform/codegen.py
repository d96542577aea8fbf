"""Compile CasADi Functions to C with gcc and call them through ctypes (no Python per-call cost).

A CasADi ``Function`` called from Python costs tens of microseconds of argument conversion; the
generated C code of the same function, called through ``ctypes`` with preallocated buffers, costs
about a microsecond plus the arithmetic. Libraries are cached on disk by the sha256 of their C
source (``$IMMERSIM_CACHE_DIR``, else ``~/.cache/immersim/casadi``, else the temp dir). When no C
compiler is available everything falls back to the CasADi virtual machine (same results).
"""
from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import List, Optional, Sequence

import casadi as ca
import numpy as np

log = logging.getLogger(__name__)

CFLAGS = ["-O2", "-shared", "-fPIC", "-fno-math-errno"]

RK4_LOOP_C = r"""
/* fixed-step driver: n substeps of {sub}(x, u, p, c, hs) -> x */
CASADI_SYMBOL_EXPORT int {name}(const casadi_real* x0, const casadi_real* u, const casadi_real* p,
                                const casadi_real* c, casadi_real hs, casadi_int n, casadi_real* x,
                                casadi_int* iw, casadi_real* w) {{
  casadi_real xin[{nx}];
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int i, k;
  for (i = 0; i < {nx}; ++i) x[i] = x0[i];
  for (k = 0; k < n; ++k) {{
    for (i = 0; i < {nx}; ++i) xin[i] = x[i];
    arg[0] = xin; arg[1] = u; arg[2] = p; arg[3] = c; arg[4] = &hs;
    res[0] = x;
    if ({sub}(arg, res, iw, w, 0)) return 1;
  }}
  return 0;
}}
"""


def cache_dir() -> Path:
    env = os.environ.get("IMMERSIM_CACHE_DIR")
    candidates = [Path(env)] if env else []
    candidates += [Path.home() / ".cache" / "immersim" / "casadi", Path(tempfile.gettempdir()) / "immersim_casadi"]
    for c in candidates:
        try:
            c.mkdir(parents=True, exist_ok=True)
            if os.access(c, os.W_OK):
                return c
        except OSError:
            continue
    raise OSError("no writable cache directory for compiled CasADi functions")


def compiler() -> Optional[str]:
    """Path of the C compiler (``$CC``, gcc, cc) or None."""
    for cand in (os.environ.get("CC"), "gcc", "cc"):
        if cand and shutil.which(cand):
            return shutil.which(cand)
    return None


def library_source(name: str, functions: Sequence[ca.Function], extra_c: str = "") -> str:
    """The C source of a library: CasADi's generated code of ``functions``, then ``extra_c``."""
    cg = ca.CodeGenerator(f"{name}.c", {"with_header": False, "casadi_real": "double", "casadi_int": "long long int"})
    for f in functions:
        cg.add(f)
    return cg.dump() + extra_c


def compile_library(name: str, functions: Sequence[ca.Function], extra_c: str = "") -> Optional[ctypes.CDLL]:
    """Generate C for ``functions`` (plus ``extra_c``), compile (cached) and load; None without a compiler."""
    cc = compiler()
    if cc is None:
        log.info("no C compiler: %s runs in the CasADi virtual machine", name)
        return None
    source = library_source(name, functions, extra_c)
    digest = hashlib.sha256((source + " ".join(CFLAGS) + ca.__version__).encode()).hexdigest()[:20]
    lib = cache_dir() / f"{name}_{digest}.so"
    if not lib.exists():
        # compiled next to the cache: os.replace cannot move a file across file systems
        # (a tmpfs /tmp and a cache folder on disk)
        with tempfile.TemporaryDirectory(prefix="immersim_cg_", dir=lib.parent) as tmp:
            src = Path(tmp) / f"{name}.c"
            src.write_text(source)
            out = Path(tmp) / lib.name
            proc = subprocess.run([cc, *CFLAGS, str(src), "-o", str(out), "-lm"], capture_output=True, text=True)
            if proc.returncode != 0:
                log.warning("compiling %s failed, using the CasADi VM: %s", name, proc.stderr[-2000:])
                return None
            os.replace(out, lib)  # atomic: concurrent builders write the same content
        log.info("compiled %s -> %s", name, lib)
    return ctypes.CDLL(str(lib))


def _work_sizes(lib: ctypes.CDLL, f: ca.Function) -> tuple:
    """(sz_arg, sz_res, sz_iw, sz_w): the larger of the generated code's ``<name>_work`` and the
    Function's own sizes, so the buffers handed to C can never be too small."""
    sizes = [f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w()]
    work = getattr(lib, f"{f.name()}_work", None)
    if work is not None:
        got = [ctypes.c_longlong() for _ in range(4)]
        work.argtypes = [ctypes.POINTER(ctypes.c_longlong)] * 4
        if work(*[ctypes.byref(g) for g in got]) == 0:
            sizes = [max(s, g.value) for s, g in zip(sizes, got)]
    return tuple(sizes)


class FastFunction:
    """Call a CasADi Function with dense vector inputs/outputs from numpy, compiled when possible.

    Parameters
    ----------
    f : casadi.Function
        Every input and output a dense column vector.
    lib : ctypes.CDLL, optional
        A library holding ``f`` (from :func:`compile_library`); None uses the CasADi VM.
    """

    def __init__(self, f: ca.Function, lib: Optional[ctypes.CDLL] = None) -> None:
        self.f = f
        self.n_in, self.n_out = f.n_in(), f.n_out()
        self.in_bufs = [np.zeros(f.nnz_in(i)) for i in range(self.n_in)]
        self.out_bufs = [np.zeros(f.nnz_out(i)) for i in range(self.n_out)]
        self.compiled = False
        if lib is not None:
            try:
                self._c = getattr(lib, f.name())
            except AttributeError:
                self._c = None
            if self._c is not None:
                self._c.restype = ctypes.c_int
                sz = _work_sizes(lib, f)
                self._iw = np.zeros(max(sz[2], 1), np.int64)
                self._w = np.zeros(max(sz[3], 1))
                arg = (ctypes.c_void_p * max(sz[0], 1))()
                res = (ctypes.c_void_p * max(sz[1], 1))()
                for i, b in enumerate(self.in_bufs):
                    arg[i] = b.ctypes.data
                for i, b in enumerate(self.out_bufs):
                    res[i] = b.ctypes.data
                self._args = (arg, res, self._iw.ctypes.data_as(ctypes.c_void_p),
                              self._w.ctypes.data_as(ctypes.c_void_p), ctypes.c_int(0))
                self.compiled = True

    def __call__(self, *inputs) -> List[np.ndarray]:
        """Evaluate; returns a list of output arrays (copies)."""
        if self.compiled:
            for buf, x in zip(self.in_bufs, inputs):
                buf[:] = x
            if self._c(*self._args):
                raise ArithmeticError(f"compiled CasADi function {self.f.name()} returned an error")
            return [b.copy() for b in self.out_bufs]
        out = self.f(*inputs)
        out = out if isinstance(out, tuple) else (out,)
        return [np.asarray(o, float).ravel() for o in out]
