"""The network FMU: validation, README table, golden reference, two instances, NaN, state, libcosim.

Regenerate the reference with ``python tests/network/test_network_fmu.py --write-reference``.
"""
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from immersim.fmus.common import OUTPUTS_UNCHANGED
from immersim.models.network import LinkClass
from immersim.orchestrator.build import build_unit, default_build_dir
from tests.fmpy_runner import Runner, readme_has_generated_table, simulate

UNIT = Path(__file__).resolve().parents[2] / "fmus" / "network"
H = T = 0.033
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


def _load_wrapper():
    spec = importlib.util.spec_from_file_location("network_fmu_under_test", UNIT / "network_fmu.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.network


def _instance(cls, params, name="t"):
    """An instance of the wrapper class ``cls`` with ``params``, out of initialization mode."""
    s = cls(instance_name=name, resources=str(UNIT), visible=False, logging_callback=None)
    s.values.update(params)
    s.setup_experiment(0.0, None, None)
    s.exit_initialization_mode()
    return s


def _fmu_run(cls, params, steps):
    s = _instance(cls, params)
    outs = [v.name for v in cls.VARIABLES if v.causality == "output"]
    rows, unchanged, saved = [], 0, None
    for k in range(steps):
        drive = k >= 60                         # at rest first (a drag-braked avatar never stops exactly)
        s.values["avatar[1].throttle"] = 0.7 if drive else 0.0
        s.values["avatar[2].steer"] = 0.3 if k >= 70 else 0.0
        hit = k in (5, 75)                      # a contact at rest (no jolt) and one while driving
        s.values["contact[1].active"] = hit
        s.values["contact[1].nx"], s.values["contact[1].ny"] = (-1.0, 0.0) if hit else (0.0, 0.0)
        if k == 20:
            saved = s._get_fmu_state()
        if k == 40:
            s._set_fmu_state(saved)            # back to step 20 (at rest): the clock goes back 20 steps
        t = s._time
        unchanged += s.step_model(t, T) is OUTPUTS_UNCHANGED
        s._time = t + T
        rows.append([s.values[n] for n in outs])
    return rows, unchanged


def test_fmu_unchanged_outputs_shortcut_equals_writing_every_step(monkeypatch):
    cls = _load_wrapper()
    params = dict(players=3, render_nodes=3, entities=0, seed=0, prediction_order=1)
    fast, n_unchanged = _fmu_run(cls, params, 120)
    monkeypatch.setattr(cls, "SKIP_UNCHANGED", False)
    plain, n_plain = _fmu_run(cls, params, 120)
    assert n_plain == 0 and n_unchanged > 40        # the idle steps keep their outputs ...
    assert fast == plain                            # ... and every output is the same


def test_fmu_output_check_reads_the_written_outputs_and_names_a_bad_one(monkeypatch):
    """The wrapper's output check sums the Real outputs the step wrote instead of all of them:
    the first check after set-up (and after a state restore) reads every output, a step whose
    written outputs are finite passes (the base class's check agrees), and a non-finite one is
    refused with the variable named, as the base class names it."""
    from immersim.fmus.common import TableSlave

    cls = _load_wrapper()

    def fresh():
        s = _instance(cls, dict(players=3, render_nodes=3, entities=8, seed=0, prediction_order=1), "chk")
        s.values["avatar[1].throttle"] = 0.8
        return s

    s = fresh()
    s.values["avatar[4].x"] = float("nan")       # an output no step writes: the first check reads it
    assert not s.do_step(0.0, T) and "output avatar[4].x = nan" in s.failed
    s = fresh()
    for k in range(30):
        assert s.do_step(k * T, T), s.failed
        TableSlave._check_outputs(s, (k + 1) * T)   # every output finite: the base check agrees
        assert len(s._out) == 3 * 10 + 3 * 2 + 8 * 2 + 2 and not s._check_all
    state = s._get_fmu_state()
    s._set_fmu_state(state)
    assert s._check_all                           # a restore: the next check reads every output
    assert s.do_step(30 * T, T) and not s._check_all
    world = s.model.world
    outputs = world.avatar_outputs

    def bad(h=None, constants=True):              # avatar 2's vx (field 3 of its 10) NaN
        out = outputs(h, constants)
        out[10 + 3] = float("nan")
        return out

    monkeypatch.setattr(world, "avatar_outputs", bad)
    assert not s.do_step(31 * T, T) and "output avatar[2].vx = nan" in s.failed   # found by the sum


if __name__ == "__main__" and "--write-reference" in sys.argv:
    path = build_unit(UNIT, default_build_dir())
    data = simulate_reference(path)
    header = ",".join(["time"] + [n.replace("[", "_").replace("]", "").replace(".", "_") for n in REF_OUTPUTS])
    np.savetxt(UNIT / "reference.csv", data, delimiter=",", header=header, comments="", fmt="%.12g")
    print(f"wrote {UNIT / 'reference.csv'} ({len(data)} rows)")


def test_fmu_ownerless_parameter_reaches_the_model():
    """``ownerless`` (on by default) is the model's ``NetworkConfig.consistency.ownerless``: with it the
    entities outside every region have no owner (-1) and are not published, so fewer objects
    are published than without it; with ``ownership = none`` (fixed owners) it has no effect."""
    cls = _load_wrapper()
    assert next(v for v in cls.VARIABLES if v.name == "ownerless").start is True
    params = dict(players=2, render_nodes=2, entities=24, seed=3, scene_size=200.0)
    published = {}
    for flag in (False, True):
        s = _instance(cls, {**params, "ownerless": flag}, f"own{int(flag)}")
        assert s.model.cfg.consistency.ownerless is flag
        for k in range(60):
            assert s.do_step(k * T, T), s.failed
        owners = s.model.owner[2:]
        assert (owners >= 0).all() if not flag else (owners == -1).any()
        published[flag] = s.model.metrics.published
    assert published[True] < published[False] == 2 + 24
    s = _instance(cls, {**params, "ownerless": True, "ownership": "none"}, "fixed")
    for k in range(10):
        assert s.do_step(k * T, T), s.failed
    assert (s.model.owner >= 0).all() and s.model.metrics.published == 2 + 24


def test_fmu_state_traffic_parameter_reaches_the_model_and_names_a_bad_rule():
    cls = _load_wrapper()
    assert next(v for v in cls.VARIABLES if v.name == "state_traffic").start == "neighbour_nodes"
    params = dict(players=2, render_nodes=1, entities=4, seed=0)
    s = _instance(cls, {**params, "state_traffic": "object_view"}, "ov")
    assert s.model.cfg.net.state_traffic == "object_view"
    with pytest.raises(ValueError, match="parameter state_traffic = 'all' must be one of object_view, neighbour_nodes"):
        _instance(cls, {**params, "state_traffic": "all"}, "bad")


def test_fmu_frame_phase_parameter_reaches_the_model():
    cls = _load_wrapper()
    assert next(v for v in cls.VARIABLES if v.name == "frame_phase").start is True
    s = _instance(cls, dict(players=3, render_nodes=1, entities=4, seed=0), "ph")
    assert s.model.cfg.scene.frame_phase is True and s.model.phase.shape == (3,)
    assert _instance(cls, dict(players=3, render_nodes=1, entities=4, seed=0, frame_phase=False),
                     "noph").model.phase is None


def test_fmu_options_set_through_fmpy_give_the_models_outputs(fmu):
    """``ownerless``, ``state_traffic`` and ``frame_phase`` set through FMPy (Boolean and String
    parameters) give, step for step, the outputs of the model configured with them directly."""
    from immersim.models.network import NetworkConfig, NetworkModel

    opts = dict(ownerless=False, state_traffic="object_view", frame_phase=False)   # (each not its default)
    r = Runner(fmu, "opts", {**PARAMS, **opts})
    cfg = NetworkConfig.from_flat(groups=2, render_nodes=3, entities=24, driven_groups=2, seed=7,
                                  links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(30.0, 5.0, 0.0, 100.0)}, **opts)
    m = NetworkModel(cfg)
    names = ["entity[1].x", "entity[16].y", "inconsistency_max", "inconsistency_rms", "messages", "bytes"]
    try:
        for k in range(40):
            r.step(drive(k))
            for p, key in ((0, 1), (1, 2)):
                d = drive(k)
                m.set_input(p, d[f"avatar[{key}].throttle"], d[f"avatar[{key}].steer"], k * T)
            s = m.step(T)
            want = [*m.world.epos[0, :1], m.world.epos[15, 1], s.inconsistency_max, s.inconsistency_rms,
                    s.frame_messages, s.frame_bytes]
            assert np.array_equal(r.get(names), np.array(want, float)), k
    finally:
        r.close()
