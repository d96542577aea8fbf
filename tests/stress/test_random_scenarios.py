"""Hypothesis-driven random scenarios with parameters inside the documented ranges
(fmus/*/README.md): no NaN or inf ever reaches the log; a run either completes or fails with
a clear message naming the unit and the time, and its log holds every completed step.

Kept small for ``make test`` (derandomized, a few examples of 0.5..1 s each); the long
version is ``benchmarks/bench_stress.py``.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stresslib import (assert_sound, collision_scenario, network_scenario, platform_scenario, run_checked,
                       write_scenario)

FAST = settings(max_examples=5, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])

platform_params = st.fixed_dictionaries({
    "M": st.floats(1.0, 500.0),
    "payload_mass": st.floats(0.0, 150.0),
    "payload_z": st.floats(0.0, 1.0),
    "k_C": st.floats(0.0, 1e3),
    "p_C": st.floats(0.0, 1e3),
    "p_B": st.floats(0.0, 1e3),
    "omega_c": st.floats(2.0, 60.0),
    "zeta_c": st.floats(0.3, 2.0),
    "omega_f": st.floats(2.0, 40.0),
    "washout.k_t": st.floats(0.0, 2.0),
    "washout.omega_t": st.floats(0.5, 10.0),
    "washout.k_r": st.floats(0.0, 2.0),
    "control": st.sampled_from(["computed_torque", "pd"]),
    "integrator": st.sampled_from(["rk4", "implicit"]),
    "substeps": st.integers(1, 8),
})
cue_amplitudes = st.fixed_dictionaries({
    "cue.f_x": st.floats(-15.0, 15.0), "cue.f_y": st.floats(-15.0, 15.0), "cue.f_z": st.floats(-5.0, 5.0),
    "cue.w_x": st.floats(-2.0, 2.0), "cue.w_y": st.floats(-2.0, 2.0), "cue.w_z": st.floats(-2.0, 2.0),
    "jolt": st.floats(0.0, 50.0)})


@FAST
@given(params=platform_params, cues=cue_amplitudes, step=st.sampled_from([0.033, 0.0165, 0.05]))
def test_platform_random_washout(params, cues, step):
    with tempfile.TemporaryDirectory() as d:
        sc = write_scenario(platform_scenario(params, cues, stop=0.5, step=step), Path(d) / "p.toml")
        out = run_checked(sc, Path(d) / "p.mcap")
        assert_sound(out, ["p"])


network_params = st.fixed_dictionaries({
    "players": st.integers(1, 4),
    "render_nodes": st.integers(1, 6),
    "entities": st.integers(0, 16),
    "seed": st.integers(0, 2**31 - 1),
    "topology": st.sampled_from(["hybrid_p2p", "client_server", "full_mesh"]),
    "prediction_order": st.integers(0, 2),
    "ownership": st.sampled_from(["mahalanobis", "euclidean", "none"]),
    "grid": st.booleans(),
    "latency_ms": st.floats(0.0, 2000.0),
    "jitter_ms": st.floats(0.0, 200.0),
    "loss": st.floats(0.0, 0.5),
    "bandwidth_mbps": st.floats(0.0, 1000.0),
    "dis_threshold": st.floats(0.0, 2.0),
})


@FAST
@given(params=network_params, drive=st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1)), min_size=4, max_size=4),
       burst=st.floats(0.0, 20.0))
def test_network_random(params, drive, burst):
    with tempfile.TemporaryDirectory() as d:
        sc = network_scenario(params, [a for a, _ in drive][:params["players"]],
                              [b for _, b in drive][:params["players"]], stop=1.0, latency_burst=burst)
        out = run_checked(write_scenario(sc, Path(d) / "n.toml"), Path(d) / "n.mcap")
        assert_sound(out, ["net"])


@FAST
@given(kind=st.sampled_from(["box:sx=2,sy=1,sz=1", "sphere:r=0.7,subdiv=1", "cylinder:r=0.4,h=2", "missile:"]),
       n_tanks=st.integers(1, 9), backend=st.sampled_from(["fcl", "basis_point", "honeycomb"]),
       vx=st.floats(-30.0, 30.0), vy=st.floats(-30.0, 30.0), wz=st.floats(-3.0, 3.0),
       x0=st.floats(-15.0, 15.0), spacing=st.floats(6.0, 20.0))
def test_collision_random(kind, n_tanks, backend, vx, vy, wz, x0, spacing):
    k, _, rest = kind.partition(":")
    body = f"{k}:name=mover,dynamic=1,z=1" + (f",{rest}" if rest else "")
    scene = f"tanks:n={n_tanks},tris=400,spacing={spacing:.3f};{body}"
    motion = {"body[1].x": {"slope": vx, "initial": x0}, "body[1].y": {"slope": vy, "initial": -x0},
              "body[1].yaw": {"slope": wz}}
    with tempfile.TemporaryDirectory() as d:
        sc = collision_scenario(scene, "mover vs any tank", motion, stop=0.5, params={"backend": backend})
        out = run_checked(write_scenario(sc, Path(d) / "c.toml"), Path(d) / "c.mcap")
        assert_sound(out, ["coll"])
