"""campus_drive8: eight players on sized builds (network players = 8, collision 16 bodies and
16 pairs) close campus_drive's loop for every player: each avatar moves, its contacts reach
the network in the step the collision unit reports them and bounce it, and the platform cues
player 1 as in campus_drive."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.mcapio import read_series

CAMPUS8 = Path(__file__).resolve().parents[2] / "scenarios" / "campus_drive8.toml"
STOP = 5.5   # s: every avatar has met a tank by then (the last, avatar 6, at ~5.2 s)
RESTITUTION = 0.5  # network default (fmus/network/README.md)
JOLT_GAIN = 0.03   # net.avatar[1].jolt_acc -> plat.jolt cue gain


@pytest.fixture(scope="module")
def mcap(tmp_path_factory):
    out = tmp_path_factory.mktemp("campus8") / "campus8.mcap"
    res = run_scenario(CAMPUS8, out, overrides={"simulation.stop": STOP})
    assert res.status == "completed" and res.steps_done == res.steps_total == round(STOP / 0.033)
    assert {"unit:net", "unit:coll", "unit:plat"} <= set(res.timing)
    return out


@pytest.fixture(scope="module")
def log(mcap):
    return {name: values for name, (_, values, _) in read_series(mcap, ["*"]).items()}


def test_the_units_are_the_sized_builds(log):
    assert "net.avatar[8].x" in log and "net.avatar[9].x" not in log
    assert "coll.pair[16].in_contact" in log and "coll.body[16].x" in log and "coll.body[17].x" not in log
    assert log["coll.n_pairs"][0] == 10 and log["coll.n_bodies"][0] == 13 + 7 + 4   # dynamic + tanks + field


def test_no_signal_is_nan(log):
    bad = [name for name, v in log.items() if v.dtype.kind == "f" and not np.isfinite(v).all()]
    assert not bad


@pytest.mark.parametrize("p", range(1, 9))
def test_every_player_drives_and_bounces_off_a_tank(log, p):
    x, y = log[f"net.avatar[{p}].x"], log[f"net.avatar[{p}].y"]
    assert np.hypot(x - x[0], y - y[0]).max() > 5.0
    contact = log[f"coll.pair[{p}].in_contact"] > 0
    active = log[f"net.contact[{p}].active"] > 0
    # collision -> network: every step's contact reaches the network in that step (fresh read)
    assert np.array_equal(contact, active) and contact.any()
    k = int(np.flatnonzero(contact)[0])
    assert k > 10   # no avatar starts in a tank
    for c in ("nx", "ny", "depth"):
        np.testing.assert_array_equal(log[f"net.contact[{p}].{c}"][contact], log[f"coll.pair[{p}].{c}"][contact])
    # the normal points from the tank to the avatar, against its velocity: the network bounces it
    nx, ny = log[f"coll.pair[{p}].nx"][k], log[f"coll.pair[{p}].ny"][k]
    n = np.array([nx, ny]) / np.hypot(nx, ny)
    vx, vy = log[f"net.avatar[{p}].vx"], log[f"net.avatar[{p}].vy"]
    vn_before, vn_after = vx[k - 1] * n[0] + vy[k - 1] * n[1], vx[k] * n[0] + vy[k] * n[1]
    assert vn_before < -0.5 and vn_after > 0.0
    jolt = log[f"net.avatar[{p}].jolt"]
    # |dv| = (1 + e)|v.n| (the throttle adds a little over the step)
    assert not jolt[:k].any() and jolt[k] == pytest.approx((1 + RESTITUTION) * -vn_before, rel=0.05)


def test_the_platform_cues_player_1(log):
    # Gauss-Seidel + linear: the platform, stepped after the network, gets the mid-step value
    for axis, offset in (("x", 0.0), ("y", 0.0), ("z", -9.81)):
        f, cue = log[f"net.avatar[1].f_{axis}"], log[f"plat.cue.f_{axis}"]
        assert cue[1] == f[1] + offset
        np.testing.assert_allclose(cue[2:], 0.5 * (f[1:-1] + f[2:]) + offset, rtol=0, atol=1e-12)
    # player 1's bounce reaches the platform as a one-step jolt in the same step (zoh)
    acc, pj = log["net.avatar[1].jolt_acc"], log["plat.jolt"]
    k = int(np.flatnonzero(log["coll.pair[1].in_contact"] > 0)[0])
    assert acc[k] > 0 and pj[k] == pytest.approx(JOLT_GAIN * acc[k], rel=1e-15) and not pj[:k].any()
    assert np.abs(log["plat.stroke[1]"]).max() > 1e-3 and not log["plat.flag.outside_workspace"].any()


def test_the_3d_view_draws_the_eight_avatars_at_their_poses(mcap, log):
    from immersim.orchestrator.foxglove import read_transforms

    tf = [transforms for _, transforms in read_transforms(mcap)]
    assert len(tf) == len(log["net.avatar[1].x"])   # one set per logged step
    for p in range(1, 9):
        frames = [next(x for x in f if x["child_frame_id"] == f"coll/avatar_{p}") for f in tf]
        np.testing.assert_array_equal([x["translation"]["x"] for x in frames], log[f"coll.body[{p}].x"])
