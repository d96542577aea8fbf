"""``at_rest`` means "stepping on with unchanged inputs changes no output" (lazy stepping).

The orchestrator skips a unit that reports ``at_rest`` while its inputs stay unchanged and
later gives it one catch-up ``doStep`` over the skipped interval (``orchestrator/master.py``).
That is only exact if, from a state at rest, ``N`` steps of 33 ms and one step of ``N * 33 ms``
give the same value for every output — checked here on the built FMU under plain FMPy, on the
campus_idle configuration (3 players x 3 render nodes, no free entities).
"""
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from immersim.models.network import NetworkConfig, NetworkModel
from immersim.orchestrator.build import build_unit, default_build_dir
from tests.fmpy_runner import Runner

UNIT = Path(__file__).resolve().parents[2] / "fmus" / "network"
H = 0.033
IDLE = {"players": 3, "render_nodes": 3, "entities": 0, "seed": 0, "prediction_order": 1}


@pytest.fixture(scope="module")
def fmu():
    return build_unit(UNIT, default_build_dir())


@pytest.fixture(scope="module")
def outputs(fmu):
    return [v.name for v in read_model_description(str(fmu)).modelVariables if v.causality == "output"]


def _step(r, n, inputs=None):
    """One doStep of ``n`` frames from ``k H`` (communication points on the master's grid ``k H``)."""
    if inputs:
        r.set(inputs)
    r.fmu.doStep(currentCommunicationPoint=r.k * H, communicationStepSize=n * H)
    r.k += n


def _runner(fmu, name, params):
    return Runner(fmu, name, params)


@pytest.mark.parametrize("n_idle", [7, 61])   # within one heartbeat period; over two (heartbeats, time-outs)
def test_catch_up_step_equals_idle_steps_one_by_one(fmu, outputs, n_idle):
    eager, lazy = _runner(fmu, "eager", IDLE), _runner(fmu, "lazy", IDLE)
    try:
        for _ in range(3):
            _step(eager, 1)
            _step(lazy, 1)
        rest = eager.get(outputs)
        assert eager.get(["at_rest"])[0] == 1.0
        assert eager.get(["messages"])[0] > 0 and eager.get(["online_nodes"])[0] == 12  # 9 render nodes + 3 controllers
        for _ in range(n_idle):
            _step(eager, 1)
            # at rest: every output (traffic included) is the same after every idle step
            np.testing.assert_array_equal(eager.get(outputs), rest)
        _step(lazy, n_idle)                          # what the lazy master does: one catch-up step
        np.testing.assert_array_equal(lazy.get(outputs), eager.get(outputs))
        # and both go on identically once the driver wakes the scene up
        for k in range(40):
            drive = {"avatar[1].throttle": 0.8, "avatar[2].steer": 0.2 if k > 10 else 0.0}
            _step(eager, 1, drive)
            _step(lazy, 1, drive)
            np.testing.assert_array_equal(lazy.get(outputs), eager.get(outputs))
        assert eager.get(["at_rest"])[0] == 0.0 and eager.get(["avatar[1].vx"])[0] != 0.0
    finally:
        eager.close()
        lazy.close()


def test_moving_scene_is_not_at_rest_and_a_stopped_one_is():
    m = NetworkModel(NetworkConfig.from_flat(groups=2, render_nodes=2, entities=0, driven_groups=2, seed=3))
    m.step(H)
    assert not m.at_rest()                               # no earlier step to compare its traffic with
    m.step(H)
    assert m.at_rest()
    m.set_input(0, 0.5, 0.0)
    m.step(H)
    assert not m.at_rest()                               # input changed (and a ControllerPacket is in flight)
    for _ in range(10):
        m.step(H)
    assert not m.at_rest()                               # the avatar moves


def test_dis_updates_are_never_at_rest():
    """With DIS (dis_threshold > 0) the 1 s re-publication changes a frame's traffic: not at rest."""
    cfg = NetworkConfig.from_flat(groups=2, render_nodes=2, entities=0, driven_groups=2, seed=3, dis_threshold=0.1)
    m = NetworkModel(cfg)
    traffic = set()
    for _ in range(40):
        m.step(H)
        traffic.add(m.metrics.frame_bytes)
        assert not m.at_rest()
    assert len(traffic) > 1                              # which is why


def test_frame_traffic_excludes_heartbeats_and_matches_a_33ms_step():
    """``frame_messages`` of a 33 ms step = the step's messages minus its heartbeats."""
    m = NetworkModel(NetworkConfig.from_flat(groups=3, render_nodes=3, entities=5, driven_groups=3, seed=1))
    for k in range(70):
        before = dict(m.totals.by_type)
        m.step(H)
        hb = m.totals.by_type.get("HEARTBEAT", 0) - before.get("HEARTBEAT", 0)
        n_hb = hb // 44
        assert m.metrics.frame_messages == m.metrics.messages - n_hb
        assert m.metrics.frame_bytes == m.metrics.bytes - hb


@pytest.mark.parametrize("topology", ["hybrid_p2p", "full_mesh"])
def test_a_control_packet_at_standstill_is_not_rest_until_the_traffic_is_steady(topology):
    """Steering at zero speed moves nothing, but its ControllerPacket changes a frame's traffic:
    whenever the model claims at_rest, the next step (same inputs) has the same traffic, so a
    lazy master that repeats the last outputs logs what an eager one does."""
    m = NetworkModel(NetworkConfig.from_flat(groups=2, render_nodes=2, entities=0, driven_groups=2, seed=3,
                                             topology=topology))
    for _ in range(3):
        m.step(H)
    assert m.at_rest()
    m.set_input(0, 0.0, 0.3)
    seen = []
    for _ in range(8):
        m.step(H)
        seen.append((m.metrics.frame_messages, m.metrics.frame_bytes, m.at_rest()))
    assert not seen[0][2]
    assert len({s[:2] for s in seen}) > 1                # the packet did change a frame's traffic
    for (msg, nbytes, rest), (msg_next, nbytes_next, _) in zip(seen, seen[1:]):
        if rest:
            assert (msg_next, nbytes_next) == (msg, nbytes)
    assert seen[-1][2]                                   # and the scene is at rest again
