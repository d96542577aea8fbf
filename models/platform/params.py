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

from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np


@dataclass(frozen=True)
class PlatformParams:
    """Geometry, mass and hinge parameters of the platform (SI units, see module table)."""

    a: float = field(default=0.38, metadata={"unit": "m", "doc": "ball joint B1 at (-a, 0, 0), eq. 6-5"})
    b: float = field(default=0.35, metadata={"unit": "m", "doc": "B2, B3 at (-e, -b, 0), (e, -b, 0), eq. 6-5"})
    e: float = field(default=0.318, metadata={"unit": "m", "doc": "x offset of B2, B3, eq. 6-5"})
    d: float = field(default=0.318, metadata={"unit": "m", "doc": "B4, B5 at (d, m, -h), (-d, m, -h), eq. 6-5"})
    c: float = field(default=0.30, metadata={"unit": "m", "doc": "rod length B_iC_i"})
    h: float = field(default=0.02, metadata={"unit": "m", "doc": "depth of B4..B6 below the centre plane"})
    m: float = field(default=0.129, metadata={"unit": "m", "doc": "y offset of B4, B5, eq. 6-5"})
    n: float = field(default=0.241, metadata={"unit": "m", "doc": "B6 at (0, -n, -h), eq. 6-5"})
    M: float = field(default=240.0, metadata={"unit": "kg", "doc": "platform mass"})
    size_x: float = field(default=0.76, metadata={"unit": "m", "doc": "platform length (cuboid inertia)"})
    size_y: float = field(default=0.70, metadata={"unit": "m", "doc": "platform width (cuboid inertia)"})
    size_z: float = field(default=0.04, metadata={"unit": "m", "doc": "platform height (cuboid inertia)"})
    payload_mass: float = field(default=0.0, metadata={"unit": "kg", "doc": "point payload (seated person)"})
    payload_z: float = field(default=0.5, metadata={"unit": "m", "doc": "payload height above C in the platform frame"})
    k_C: float = field(default=5.0, metadata={"unit": "N.m/rad", "doc": "hinge stiffness at the universal joints C_i, eq. 6-54"})
    p_C: float = field(default=0.5, metadata={"unit": "N.m.s/rad", "doc": "hinge damping at C_i, eq. 6-54"})
    p_B: float = field(default=0.2, metadata={"unit": "N.m.s/rad", "doc": "ball-joint damping on the relative rate, eq. 6-54"})
    stroke_min: float = field(default=-0.12, metadata={"unit": "m", "doc": "lower stroke limit of every actuator"})
    stroke_max: float = field(default=0.12, metadata={"unit": "m", "doc": "upper stroke limit of every actuator"})
    reach_margin: float = field(default=0.02, metadata={"unit": "1", "doc": "minimum (rod . slider axis)/c inside the workspace"})
    g: float = field(default=9.81, metadata={"unit": "m/s2", "doc": "gravity"})

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
