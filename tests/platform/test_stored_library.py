"""The platform's compiled macro step read back from the codegen cache
(:func:`macrostep.stored_library`: its CasADi Functions serialized, the library by path) is the
one built from the closed loop: the same outputs bit for bit; a run that finds the entry builds
no closed loop; a damaged entry is made again."""
import json
import os
import subprocess
import sys

import pytest

CODE = r"""
import json, sys
import numpy as np
import immersim.models.platform.control as control
import immersim.models.platform.macrostep as ms
from immersim.models.platform.simulator import PlatformSim, SimConfig, StepInputs
if sys.argv[1] == "built":
    ms.stored_library = lambda control, model: None   # (the closed loop built and generated here)
sim = PlatformSim(SimConfig())
out = []
for k in range(120):   # a washout cue with a jolt, then a rest
    t = 0.033 * k
    inp = StepInputs(f=[2.0 * np.sin(3.0 * t), 1.0 * np.cos(2.0 * t), 0.3], omega=[0.0, 0.1, 0.4 * np.sin(t)],
                     jolt=5.0 if k == 40 else 0.0)
    out.append(sim.step(inp, 0.033, t).packed.tolist())
print(json.dumps({"out": out, "built": control.prefiltered_loop.cache_info().currsize}))
"""


def _run(how: str, cache) -> dict:
    env = {**os.environ, "IMMERSIM_CACHE_DIR": str(cache)}
    done = subprocess.run([sys.executable, "-c", CODE, how], capture_output=True, text=True, env=env, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("codegen")


def test_a_stored_library_gives_the_built_librarys_outputs_and_builds_nothing(cache):
    built = _run("built", cache)
    first, again = _run("stored", cache), _run("stored", cache)
    if not list(cache.glob("macro_*.pickle")):
        pytest.skip("no C compiler: nothing is stored")
    assert built["built"] == 1 and first["built"] == 1 and again["built"] == 0
    assert first["out"] == built["out"] and again["out"] == built["out"]
    assert any(abs(v) > 1e-3 for row in built["out"] for v in row[:6])   # the platform moved


def test_a_damaged_entry_is_made_again(cache):
    for entry in cache.glob("macro_*.pickle"):
        entry.write_bytes(entry.read_bytes()[:1000])
    assert _run("stored", cache)["built"] == 1
    assert _run("stored", cache)["built"] == 0
