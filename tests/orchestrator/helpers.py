"""Write small scenario files for the orchestrator tests."""
from __future__ import annotations

from pathlib import Path


def oscillator_scenario(tmp: Path, fmu: Path, *, step: float = 0.01, stop: float = 5.0,
                        algorithm: str = "jacobi", extrapolation: str = "zoh", extra: str = "",
                        name: str = "osc.toml") -> Path:
    """Two coupled oscillators m1 (x0 = 1) and m2 (x0 = 0), k = kc = m = 1."""
    text = f'''
[simulation]
stop = {stop}
step = {step}
algorithm = "{algorithm}"
extrapolation = "{extrapolation}"

[[units]]
name = "m1"
fmu = "{fmu}"
parameters = {{ x0 = 1.0 }}

[[units]]
name = "m2"
fmu = "{fmu}"

[[connections]]
from = "m1.x"
to = "m2.x_other"

[[connections]]
from = "m2.x"
to = "m1.x_other"
{extra}
'''
    path = tmp / name
    path.write_text(text)
    return path


#: a 3D-view body following the oscillators (m1.x its position, m2.x its yaw), for the
#: ``extra`` of :func:`oscillator_scenario`
MASS_BODY = '''
[[foxglove.bodies]]
name = "mass1"
position = ["m1.x", 0.0, 0.5]
euler = [0.0, 0.0, "m2.x"]
order = "zyx"
size = [0.2, 0.2, 0.2]
'''
