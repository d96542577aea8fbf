"""Parameters of the PSS 3-2-1 orthogonal parallel platform (thesis ch. 6, fig. 6-2, eq. 6-5/6-6).

Defaults follow SPEC.md (unit ``platform``): the seed lists ``a = 0.318 ... a = 0.38`` (line ~2498);
0.38 m is read as ``a`` (half the 0.76 m platform length) and 0.318 m as ``e``; ``d`` is not given
and is taken equal to ``e``. The machine mass M = 240 kg is used (the thesis simulation used 4 kg).

| symbol | default | unit | meaning |
|---|---|---|---|
| a | 0.38 | m | ball joint B1 at (-a, 0, 0) |
| b | 0.35 | m | B2, B3 at (-e, -b, 0), (e, -b, 0) |
| e | 0.318 | m | see b |
| d | 0.318 | m | B4, B5 at (d, m, -h), (-d, m, -h) |
| c | 0.30 | m | rod length B_iC_i |
| h | 0.02 | m | depth of B4..B6 under the centre plane |
| m | 0.129 | m | see d |
| n | 0.241 | m | B6 at (0, -n, -h) |
| M | 240 | kg | platform mass |
| size | 0.76 x 0.70 x 0.04 | m | cuboid whose principal inertias J_x, J_y, J_z are used |
| payload_mass | 0 | kg | point payload (seated person) rigidly fixed to the platform |
| payload_z | 0.5 | m | height of the payload above C in the platform frame |
| k_C | 5 | N m/rad | hinge stiffness at the universal joints C_i (eq. 6-54) |
| p_C | 0.5 | N m s/rad | hinge damping at C_i (eq. 6-54) |
| p_B | 0.2 | N m s/rad | damping of the ball joints B_i on the relative rate (eq. 6-54) |
| stroke_min, stroke_max | -0.12, 0.12 | m | actuator stroke limits of Δl_i |
| reach_margin | 0.02 | - | minimum of (rod · slider axis) / c, i.e. rod at most ~89° off its axis |
| g | 9.81 | m/s^2 | gravity, along -Z |
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

import numpy as np


@dataclass(frozen=True)
class PlatformParams:
    """Geometry, mass and hinge parameters of the platform (SI units, see module table)."""

    a: float = 0.38
    b: float = 0.35
    e: float = 0.318
    d: float = 0.318
    c: float = 0.30
    h: float = 0.02
    m: float = 0.129
    n: float = 0.241
    M: float = 240.0
    size_x: float = 0.76
    size_y: float = 0.70
    size_z: float = 0.04
    payload_mass: float = 0.0
    payload_z: float = 0.5
    k_C: float = 5.0
    p_C: float = 0.5
    p_B: float = 0.2
    stroke_min: float = -0.12
    stroke_max: float = 0.12
    reach_margin: float = 0.02
    g: float = 9.81

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not np.isfinite(v):
                raise ValueError(f"PlatformParams.{f.name} = {v} is not finite")
        for name in ("a", "b", "e", "c", "M", "size_x", "size_y", "size_z"):
            if getattr(self, name) <= 0:
                raise ValueError(f"PlatformParams.{name} = {getattr(self, name)} must be > 0")
        if self.payload_mass < 0:
            raise ValueError(f"PlatformParams.payload_mass = {self.payload_mass} must be >= 0")
        if not self.stroke_min < 0 < self.stroke_max:
            raise ValueError(f"stroke limits [{self.stroke_min}, {self.stroke_max}] m must bracket 0")

    @property
    def inertia(self) -> np.ndarray:
        """Principal inertias (J_x, J_y, J_z) of the cuboid of mass M, kg m^2, shape (3,)."""
        x, y, z = self.size_x, self.size_y, self.size_z
        return self.M / 12.0 * np.array([y * y + z * z, x * x + z * z, x * x + y * y])

    @property
    def joints(self) -> np.ndarray:
        """Ball joints B_i in the platform frame Cxyz, eq. 6-5, shape (6, 3), m."""
        a, b, e, d, h, m, n = self.a, self.b, self.e, self.d, self.h, self.m, self.n
        return np.array([[-a, 0, 0], [-e, -b, 0], [e, -b, 0], [d, m, -h], [-d, m, -h], [0, -n, -h]], float)

    @property
    def axes(self) -> np.ndarray:
        """Unit slider axes e_i in OXYZ (C1 along X, C2/C3 along Y, C4..C6 along Z), shape (6, 3)."""
        return np.array([[1, 0, 0], [0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 0, 1]], float)

    @property
    def sliders_home(self) -> np.ndarray:
        """Slider points C_i at zero stroke, eq. 6-6: ``B_i - c e_i``, shape (6, 3), m."""
        return self.joints - self.c * self.axes

    def vector(self) -> np.ndarray:
        """All fields as a float vector in declaration order (the CasADi parameter vector)."""
        return np.array([getattr(self, f.name) for f in fields(self)], float)

    @classmethod
    def names(cls) -> tuple:
        return tuple(f.name for f in fields(cls))

    def replace(self, **changes) -> "PlatformParams":
        return replace(self, **changes)

    def as_dict(self) -> dict:
        return asdict(self)
