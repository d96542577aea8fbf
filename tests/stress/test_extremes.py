"""Extreme but valid parameters (fast cases; 1000 s runs and 200k-triangle meshes are in
benchmarks/bench_stress.py): the run completes with finite values in the log, or fails with
a clear message naming the unit and the time -- never NaN/inf in the log, never a raw error.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from stresslib import (BIPYRAMID_OBJ, assert_sound, collision_scenario, network_scenario, platform_scenario,
                       run_checked, write_scenario)

CUES = {"cue.f_x": 8.0, "cue.f_y": -6.0, "cue.w_z": 1.0, "jolt": 30.0}


@pytest.mark.parametrize("params, completes", [
    # hinge friction/stiffness 1e6: the explicit default (rk4) diverges at the first moving step and
    # must say so; the implicit integrators must run it through
    ({"k_C": 1e6, "p_C": 1e6, "p_B": 1e6}, None),
    ({"k_C": 1e6, "p_C": 1e6, "p_B": 1e6, "integrator": "implicit"}, True),
    ({"M": 0.01, "size_z": 0.001}, True),                            # a very light platform
    ({"M": 500.0, "payload_mass": 150.0, "payload_z": 1.0}, True),   # heavy with a high payload
    # 100 N cannot hold 240 kg: the platform drops out of the rods' reach -> a clean failure
    ({"omega_c": 100.0, "zeta_c": 0.1, "F_max": 100.0}, False),
], ids=["friction_1e6_rk4", "friction_1e6_implicit", "mass_0.01kg", "heavy_payload", "too_weak_actuators"])
def test_platform_extreme_parameters(params, completes, tmp_path):
    sc = write_scenario(platform_scenario(params, CUES, stop=1.0), tmp_path / "p.toml")
    out = run_checked(sc, tmp_path / "p.mcap")
    assert_sound(out, ["p"])
    if completes is not None:
        assert out.completed == completes, out.message


@pytest.mark.parametrize("params", [
    {"players": 4, "render_nodes": 6, "latency_ms": 2000.0, "jitter_ms": 500.0, "loss": 0.5},
    {"players": 4, "latency_ms": 0.0, "jitter_ms": 0.0, "loss": 0.0, "bandwidth_mbps": 0.0},
    {"players": 3, "topology": "full_mesh", "loss": 0.5, "bandwidth_mbps": 0.01, "prediction_order": 2},
], ids=["latency_2s_loss_50", "ideal_links", "full_mesh_starved"])
def test_network_extreme_links(params, tmp_path):
    n = params["players"]
    sc = network_scenario(params, [1.0, -1.0, 0.5, 1.0][:n], [1.0, -1.0, 0.0, 0.5][:n], stop=1.0, latency_burst=10.0)
    out = run_checked(write_scenario(sc, tmp_path / "n.toml"), tmp_path / "n.mcap")
    assert_sound(out, ["net"])
    assert out.completed, out.message


def test_collision_ten_triangle_mesh_through_a_tank(tmp_path):
    mesh = tmp_path / "bipyramid.obj"
    mesh.write_text(BIPYRAMID_OBJ)
    scene = f"tank:name=tank_1,tris=400;mesh:name=probe,file={mesh},dynamic=1,z=1"
    motion = {"body[1].x": {"slope": 40.0, "initial": -10.0}}  # crosses the tank in the run
    sc = collision_scenario(scene, "probe vs tank_1", motion, stop=0.5)
    out = run_checked(write_scenario(sc, tmp_path / "c.toml"), tmp_path / "c.mcap")
    assert_sound(out, ["coll"])
    assert out.completed, out.message
