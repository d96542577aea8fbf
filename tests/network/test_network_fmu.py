"""The network FMU: validation, README table, golden reference, two instances, NaN, state, libcosim.

Regenerate the reference with ``python tests/network/test_network_fmu.py --write-reference``.
"""
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from immersim.orchestrator.build import build_unit, default_build_dir
from tests.fmpy_runner import Runner, readme_has_generated_table, simulate

UNIT = Path(__file__).resolve().parents[2] / "fmus" / "network"
H = 0.033
PARAMS = {"players": 2, "entities": 24, "latency_ms": 30.0, "jitter_ms": 5.0, "seed": 7}
REF_OUTPUTS = (["avatar[1].x", "avatar[1].y", "avatar[1].yaw", "avatar[1].vx", "avatar[1].f_x", "avatar[1].f_y",
                "avatar[1].w_z", "avatar[2].x", "avatar[2].y", "perceived[2].x", "perceived[2].y",
                "entity[1].x", "entity[1].y", "entity[16].x", "inconsistency_max", "inconsistency_rms"])


@pytest.fixture(scope="module")
def fmu():
    return build_unit(UNIT, default_build_dir())


def drive(k):
    """Driver inputs of the reference run: player 1 accelerates into a left turn, player 2 brakes at 1 s."""
    return {"avatar[1].throttle": 0.8, "avatar[1].steer": 0.3 if k > 15 else 0.0,
            "avatar[2].throttle": 0.6 if k < 30 else -0.5, "avatar[2].steer": -0.1}


def simulate_reference(path, n_steps=60):
    return simulate(path, PARAMS, drive, REF_OUTPUTS, n_steps)


def test_readme_holds_the_generated_table():
    assert readme_has_generated_table(UNIT)


def test_validates(fmu):
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    assert md.coSimulation.canGetAndSetFMUstate


def test_golden_reference(fmu):
    ref = np.genfromtxt(UNIT / "reference.csv", delimiter=",", names=True)
    got = simulate_reference(fmu, len(ref))
    for j, name in enumerate(REF_OUTPUTS):
        col = ref[ref.dtype.names[j + 1]]
        np.testing.assert_allclose(got[:, j + 1], col, rtol=1e-6, atol=1e-6, err_msg=name)
    assert np.ptp(got[:, 1]) > 1.0            # the avatar moved


def test_two_instances_in_one_process_are_identical_and_independent(fmu):
    a, b = Runner(fmu, "a", PARAMS), Runner(fmu, "b", PARAMS)
    try:
        for k in range(30):
            a.step(drive(k))
            b.step(drive(k))
        assert np.array_equal(a.get(REF_OUTPUTS), b.get(REF_OUTPUTS))
        for k in range(30, 36):                    # the ControllerPacket needs ~70 ms to reach the master
            b.step({"avatar[1].throttle": -1.0})
            a.step(drive(k))
        assert not np.array_equal(a.get(["avatar[1].vx"]), b.get(["avatar[1].vx"]))
    finally:
        a.close()
        b.close()


def test_nan_input_is_an_error_naming_the_variable(fmu):
    r = Runner(fmu, "nanny", PARAMS)
    try:
        r.step(drive(0))
        with pytest.raises(FMICallException):
            r.step({"avatar[2].steer": float("nan")})
        assert any("avatar[2].steer" in m and "nanny" in m for m in r.messages), r.messages
    finally:
        r.close()


def test_bad_parameter_is_named(fmu):
    md = read_model_description(str(fmu))
    messages = []
    with pytest.raises(FMICallException):
        r = Runner.__new__(Runner)
        try:
            Runner.__init__(r, fmu, "badtopo", {"topology": "ring"})
        finally:
            messages += r.messages
    assert any("topology" in m and "ring" in m and "badtopo" in m for m in messages), messages
    del md


def test_state_round_trip_covers_queue_and_rng(fmu):
    r = Runner(fmu, "st", {**PARAMS, "loss": 0.2})
    try:
        for k in range(10):
            r.step(drive(k))
        state = r.fmu.getFMUstate()
        k0 = r.k
        first = []
        for k in range(15):
            r.step(drive(k0 + k))
            first.append(r.get(REF_OUTPUTS + ["messages", "bytes"]))
        r.fmu.setFMUstate(state)
        r.k = k0
        for k in range(15):
            r.step(drive(k0 + k))
            assert np.array_equal(r.get(REF_OUTPUTS + ["messages", "bytes"]), first[k])
        r.fmu.freeFMUstate(state)
    finally:
        r.close()


def test_collision_input_bounces_and_reports_a_jolt(fmu):
    r = Runner(fmu, "bump", PARAMS)
    try:
        for k in range(20):
            r.step({"avatar[1].throttle": 1.0})
        vx, vy = r.get(["avatar[1].vx", "avatar[1].vy"])
        speed = np.hypot(vx, vy)
        n = -np.array([vx, vy]) / speed                      # head-on obstacle
        r.step({"contact[1].active": True, "contact[1].nx": n[0], "contact[1].ny": n[1]})
        jolt, jolt_acc, vx2, vy2 = r.get(["avatar[1].jolt", "avatar[1].jolt_acc", "avatar[1].vx", "avatar[1].vy"])
        assert jolt == pytest.approx(1.5 * speed, rel=0.05)   # restitution 0.5
        assert jolt_acc == pytest.approx(jolt / H, rel=1e-12)  # m/s2: the same dv held over the 33 ms step
        assert vx2 * vx + vy2 * vy < 0                        # moving away
        r.step({"contact[1].active": False})
        assert r.get(["avatar[1].jolt"])[0] == 0.0 and r.get(["avatar[1].jolt_acc"])[0] == 0.0
    finally:
        r.close()


def test_same_outputs_under_fmpy_and_libcosim(fmu):
    from immersim.orchestrator.crosscheck import simulate_fmpy, simulate_libcosim
    start = {**PARAMS, "avatar[1].throttle": 0.7, "avatar[1].steer": 0.2, "avatar[2].throttle": 0.4}
    outs = REF_OUTPUTS
    a = simulate_fmpy(fmu, start, 40, outs)[0]
    b = simulate_libcosim(fmu, start, 40, outs)[0]
    for name in outs:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


if __name__ == "__main__" and "--write-reference" in sys.argv:
    path = build_unit(UNIT, default_build_dir())
    data = simulate_reference(path)
    header = ",".join(["time"] + [n.replace("[", "_").replace("]", "").replace(".", "_") for n in REF_OUTPUTS])
    np.savetxt(UNIT / "reference.csv", data, delimiter=",", header=header, comments="", fmt="%.12g")
    print(f"wrote {UNIT / 'reference.csv'} ({len(data)} rows)")


def test_contact_depth_moves_the_avatar_out_and_is_not_felt(fmu):
    """The same head-on bounce with contact[1].depth = 0.4 m: the avatar ends the step 0.4 m
    further out along the normal than without it, with the same jolt; a negative depth is an
    error naming the instance, the variable and the time."""
    out = {}
    for depth in (0.0, 0.4):
        r = Runner(fmu, f"deep{int(depth * 10)}", PARAMS)
        try:
            for k in range(20):
                r.step({"avatar[1].throttle": 1.0})
            vx, vy = r.get(["avatar[1].vx", "avatar[1].vy"])
            n = -np.array([vx, vy]) / np.hypot(vx, vy)
            r.step({"contact[1].active": True, "contact[1].nx": n[0], "contact[1].ny": n[1], "contact[1].depth": depth})
            out[depth] = (np.array(r.get(["avatar[1].x", "avatar[1].y"])), r.get(["avatar[1].jolt"])[0], n)
        finally:
            r.close()
    (p0, j0, n), (p1, j1, _) = out[0.0], out[0.4]
    assert np.allclose(p1 - p0, 0.4 * n, atol=1e-9) and j1 == j0 > 0
    r = Runner(fmu, "negdepth", PARAMS)
    try:
        r.step(drive(0))
        with pytest.raises(FMICallException):
            r.step({"contact[2].active": True, "contact[2].nx": 1.0, "contact[2].depth": -0.1})
        assert any("negdepth" in m and "contact[2].depth = -0.1 must be >= 0" in m and "t = 0.033" in m
                   for m in r.messages), r.messages
    finally:
        r.close()
