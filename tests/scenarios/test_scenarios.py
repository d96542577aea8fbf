"""Reference scenarios: every file loads and passes the load-time checks, campus_drive's closed
loop (network -> collision -> network bounce, network -> platform jolt) really closes, and lazy
stepping on a mostly idle scene gives the same log as eager stepping."""
from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

from immersim.orchestrator.execution import Execution, run_scenario
from immersim.orchestrator.mcapio import read_series
from immersim.orchestrator.sweep import load_sweep

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]
SCEN = ROOT / "scenarios"
CAMPUS = SCEN / "campus_drive.toml"
MY_SWEEPS = ("campus_backends.toml", "campus_prediction.toml", "tank_field_n.toml")
RESTITUTION = 0.5  # network default (fmus/network/README.md)
MAX_DISTANCE = 2.0  # collision default (fmus/collision/README.md)
JOLT_GAIN = 0.03  # campus_drive: net.avatar[1].jolt_acc -> plat.jolt cue gain


def series(path: Path, name: str) -> np.ndarray:
    """Logged samples of ``unit.var`` (one per step, index k = time k*h)."""
    return read_series(path, [name.replace("[", "[[]")])[name][1]


@pytest.mark.parametrize("path", sorted(SCEN.glob("*.toml")), ids=lambda p: p.name)
def test_scenario_passes_load_time_checks(path):
    ex = Execution(path)  # resolves (builds) the FMUs and checks every connection, input, parameter
    assert ex.system.needed, f"{path.name}: nothing to simulate"
    assert not ex.system.skipped, f"{path.name}: units loaded for nothing: {ex.system.skipped}"


@pytest.mark.parametrize("name", MY_SWEEPS)
def test_sweep_file_loads(name):
    spec = load_sweep(SCEN / "sweeps" / name)  # checks every variant against its scenario
    assert len(spec.variants) >= 3


def test_campus_drive_short_run(tmp_path):
    out = tmp_path / "campus.mcap"
    res = run_scenario(CAMPUS, out, overrides={"simulation.stop": 2.0})
    assert res.status == "completed" and res.steps_done == res.steps_total == 61
    assert {"unit:net", "unit:coll", "unit:plat"} <= set(res.timing)
    d = series(out, "coll.pair[1].distance")
    x = series(out, "net.avatar[1].x")
    # avatar 1 drives towards tank_a, still farther than the collision unit's max_distance
    # (2 m, the FMU default): the pair reports exactly max_distance, never an exact distance
    assert x[-1] > x[0] + 1.0 and np.all(d == MAX_DISTANCE)
    # the avatar's acceleration reaches the platform through the washout (cue.f_* wired); with
    # Gauss-Seidel + linear (the defaults) the platform, stepped after the network, gets the
    # mid-step value of its source over each step (the first step: the value at its end)
    for axis, offset in (("x", 0.0), ("z", -9.81)):
        f, cue = series(out, f"net.avatar[1].f_{axis}"), series(out, f"plat.cue.f_{axis}")
        assert cue[1] == f[1] + offset
        np.testing.assert_allclose(cue[2:], 0.5 * (f[1:-1] + f[2:]) + offset, rtol=0, atol=1e-12)
    assert np.abs(series(out, "plat.stroke[1]")).max() > 1e-3
    # the scenario's washout gains keep the full-throttle launch inside the workspace
    assert not series(out, "plat.flag.outside_workspace").any()
    # the 3D view, derived from the units ([foxglove] units = true): every dynamic body of the
    # collision unit is a /tf frame posed by its inputs (R = Rz(yaw) Ry(pitch) Rx(roll)), the
    # platform's plate one posed by its pose; the meshes go once on /scene/meshes (the tanks
    # copies of one mesh placed in the world), and with nothing a primitive of it, no /scene
    import json

    from mcap.reader import make_reader

    from immersim.orchestrator.foxglove import read_transforms

    with open(out, "rb") as fh:   # /scene* is JSON; /tf is ROS 1 in this ros1 log
        msgs = {}
        for _, c, m in make_reader(fh).iter_messages(topics=["/scene", "/scene/meshes"]):
            msgs.setdefault(c.topic, []).append(json.loads(m.data)["entities"])
    tf = [transforms for _, transforms in read_transforms(out)]
    frames = {f"coll/{b}" for b in ("avatar_1", "avatar_2", "avatar_3", "missile", "entity_1", "entity_2",
                                     "entity_3", "entity_4")} | {"plat/plate"}
    assert len(tf) == 62 and all({x["child_frame_id"] for x in f} == frames for f in tf)
    assert "/scene" not in msgs and len(msgs["/scene/meshes"]) == 1
    static = {e["id"] for e in msgs["/scene/meshes"][0] if e["frame_id"] == "world"}
    assert static == {"coll/static", "plat/rails"}
    with open(out, "rb") as fh:   # [foxglove] rods = false: no per-step redraw of the platform's rods
        assert "/scene/plat" not in {c.topic for c in make_reader(fh).get_summary().channels.values()}
    a1 = [next(x for x in f if x["child_frame_id"] == "coll/avatar_1") for f in tf]
    np.testing.assert_array_equal([x_["translation"]["x"] for x_ in a1], series(out, "coll.body[1].x"))
    assert all(x_["translation"]["z"] == 2.5 for x_ in a1)
    yaw = series(out, "coll.body[1].yaw")
    np.testing.assert_allclose([x_["rotation"]["z"] for x_ in a1], np.sin(yaw / 2), rtol=0, atol=1e-15)


def _campus_variant(tmp_path: Path, name: str, drop_jolt: bool) -> Path:
    """campus_drive with tank_a 6.5 m ahead of avatar 1 (contact within 2 s), optionally
    without the net.avatar[1].jolt_acc -> plat.jolt connection (of the included file)."""
    text = CAMPUS.read_text()
    text, n = re.subn(r'(name = "tank_a", tris = "5\.4k"), x = [0-9.]+, y = [0-9.]+', r"\1, x = 48.123, y = 53.310", text)
    assert n == 1
    common = (SCEN / "campus_common.toml").read_text()
    if drop_jolt:
        common, n = re.subn(r"\[\[connections\]\][^\n]*\nfrom = \"net\.avatar\[1\]\.jolt_acc\"\n"
                            r"to = \"plat\.jolt\"\ngain = [0-9.]+\nextrapolation = \"zoh\"\n", "", common)
        assert n == 1
    (tmp_path / f"common_{name}").write_text(common)
    path = tmp_path / name
    path.write_text(text.replace('include = ["campus_common.toml"]', f'include = ["common_{name}"]'))
    return path


def test_campus_closed_loop_collision_bounce_and_jolt(tmp_path):
    ov = {"simulation.stop": 2.0}
    a, b = tmp_path / "loop.mcap", tmp_path / "nojolt.mcap"
    run_scenario(_campus_variant(tmp_path, "loop.toml", False), a, overrides=ov)
    run_scenario(_campus_variant(tmp_path, "nojolt.toml", True), b, overrides=ov)
    contact = series(a, "coll.pair[1].in_contact") > 0
    assert contact.any(), "no collision of avatar 1 within 2 s"
    k = int(np.flatnonzero(contact)[0])
    assert 5 < k < 60
    # approaching: max_distance while far, then exact distances falling to contact
    d = series(a, "coll.pair[1].distance")
    near = np.flatnonzero(d[:k] < MAX_DISTANCE)
    assert d[0] == MAX_DISTANCE and near.size >= 2 and near[-1] == k - 1
    assert np.all(np.diff(d[near[0]:k]) < 0) and d[k] == 0.0
    active = series(a, "net.contact[1].active") > 0
    nx, ny = series(a, "coll.pair[1].nx"), series(a, "coll.pair[1].ny")
    # collision -> network: the contact reaches the network input in the same step (the
    # collision unit steps first, on the network's last poses; the network reads it fresh)
    assert not active[:k].any() and active[k]
    assert series(a, "net.contact[1].nx")[k] == nx[k] and series(a, "net.contact[1].ny")[k] == ny[k]
    # the normal points from tank_a (partner) to the avatar (first body), against its velocity: the network bounces it
    vx, vy = series(a, "net.avatar[1].vx"), series(a, "net.avatar[1].vy")
    n = np.array([nx[k], ny[k]]) / np.hypot(nx[k], ny[k])
    vn_before = vx[k - 1] * n[0] + vy[k - 1] * n[1]
    vn_after = vx[k] * n[0] + vy[k] * n[1]
    assert vn_before < -1.0 and vn_after > 0.0
    jolt = series(a, "net.avatar[1].jolt")
    assert not jolt[:k].any()
    # |dv| = (1 + e)|v.n| (the throttle adds a little over the step)
    assert jolt[k] == pytest.approx((1 + RESTITUTION) * -vn_before, rel=0.05)
    # network -> platform: the jolt arrives in the same step (Gauss-Seidel, platform after network)
    # wired as jolt_acc = jolt / h (m/s2) with the cue gain of the connection
    acc = series(a, "net.avatar[1].jolt_acc")
    assert acc[k] == pytest.approx(jolt[k] / 0.033, rel=1e-12)
    pj = series(a, "plat.jolt")
    assert pj[k] == pytest.approx(JOLT_GAIN * acc[k], rel=1e-15) and not pj[:k].any()
    # and the platform responds: strokes equal to the no-jolt run until the jolt, then differ
    s = np.array([series(a, f"plat.stroke[{i}]") for i in range(1, 7)])
    s0 = np.array([series(b, f"plat.stroke[{i}]") for i in range(1, 7)])
    assert np.array_equal(s[:, :k], s0[:, :k])
    assert np.abs(s - s0)[:, k:].max() > 2e-3


def test_lazy_stepping_matches_eager_on_idle_scene(tmp_path):
    ov = {"simulation.stop": 8.0}
    lazy_log, eager_log = tmp_path / "lazy.mcap", tmp_path / "eager.mcap"
    ex = Execution(SCEN / "campus_idle.toml", lazy_log, overrides={**ov, "simulation.lazy": True})
    ex.run()
    skipped = {n: s.skipped_steps for n, s in ex.master.slots.items()}
    assert min(skipped.values()) > 150, skipped  # idle for 7 s of 8: most steps skipped
    run_scenario(SCEN / "campus_idle.toml", eager_log, overrides={**ov, "simulation.lazy": False})
    a, b = read_series(lazy_log, ["*"]), read_series(eager_log, ["*"])
    assert a.keys() == b.keys() and len(a) > 300
    # every signal, the network's per-frame traffic counters included (heartbeats are not part of
    # them, so a scene at rest has the same traffic every frame)
    differ = sorted(k for k in a if not np.array_equal(a[k][1], b[k][1], equal_nan=True))
    assert not differ, differ
    # the drive after 7 s really happened in both (the lazy units woke up and caught up)
    assert series(lazy_log, "net.avatar[1].x")[-1] > series(lazy_log, "net.avatar[1].x")[0] + 0.5
    assert np.abs(series(lazy_log, "plat.stroke[1]")).max() > 1e-3


def test_lazy_stepping_matches_eager_for_a_control_packet_at_standstill(tmp_path):
    """A steer change at zero speed moves nothing but sends a ControllerPacket: the network must
    not claim at_rest while that changes a frame's traffic (lazy stepping would repeat it)."""
    scn = tmp_path / "standstill.toml"
    scn.write_text('[simulation]\nstop = 3.0\n[[units]]\nname = "net"\nfmu = "network"\n'
                   '[units.parameters]\nplayers = 2\nrender_nodes = 2\nentities = 0\ntopology = "full_mesh"\n'
                   '[[inputs]]\ntarget = "net.avatar[1].steer"\nkind = "step"\nat = 1.0\nvalue = 0.3\n')
    lazy_log, eager_log = tmp_path / "lazy.mcap", tmp_path / "eager.mcap"
    ex = Execution(scn, lazy_log, overrides={"simulation.lazy": True})
    ex.run()
    assert ex.master.slots["net"].skipped_steps > 60
    run_scenario(scn, eager_log, overrides={"simulation.lazy": False})
    a, b = read_series(lazy_log, ["*"]), read_series(eager_log, ["*"])
    assert len(np.unique(b["net.messages"][1])) > 1  # the packet shows in the traffic
    differ = sorted(k for k in a if not np.array_equal(a[k][1], b[k][1], equal_nan=True))
    assert not differ, differ


def test_two_runs_in_one_process_each_load_the_fmu_code_they_need(tmp_path):
    """The same FMU in two runs of one process (a sweep worker, a benchmark): the first run's
    extraction is gone when the second starts, and the second needs a module the first never
    imported (another backend). No module of a removed extraction may stay importable."""
    import sys

    for backend in ("fcl", "basis_point"):
        res = run_scenario(SCEN / "tank_field.toml", tmp_path / f"{backend}.mcap",
                           overrides={"simulation.stop": 0.33, "coll.backend": backend})
        assert res.status == "completed" and res.steps_done == 10
        stale = [n for n, m in sys.modules.items()
                 if getattr(m, "__file__", None) and "immersim_run_" in m.__file__
                 and not Path(m.__file__).exists()]
        assert not stale, stale[:5]
