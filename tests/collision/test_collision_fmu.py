"""The collision FMU: validation, README table, golden reference, bad input, state, FMPy vs libcosim."""
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from immersim.orchestrator.build import build_unit, default_build_dir
from tests.fmpy_runner import Runner, readme_has_generated_table, simulate, wrapper_class

UNIT = Path(__file__).resolve().parents[2] / "fmus" / "collision"
H = 0.033
SCENE = "tanks:n=4,tris=5.4k;missile:z=8"
# max_distance 5 m: the dive starts 3 m above the tank (exact distances) and ends 5.05 m below it (capped)
PARAMS = {"scene": SCENE, "pairs": "missile vs any tank; tank_0 vs tank_1", "max_distance": 5.0}
REF_OUTPUTS = ["pair[1].in_contact", "pair[1].distance", "pair[1].depth", "pair[1].px", "pair[1].py", "pair[1].pz",
               "pair[1].nx", "pair[1].ny", "pair[1].nz", "pair[1].toi", "pair[1].closing_speed",
               "pair[2].distance", "n_candidates", "n_narrow", "at_rest"]


@pytest.fixture(scope="module")
def fmu():
    return build_unit(UNIT, default_build_dir())


def missile_inputs(k):
    """A missile diving onto tank_0 (origin) at 15 m/s, nose down, reaching it around step 25."""
    return {"body[1].x": 0.3, "body[1].y": 0.2, "body[1].z": 8.0 - 0.5 * (k + 1), "body[1].pitch": 1.2}


def simulate_reference(path, n_steps=30):
    return simulate(path, dict(PARAMS, **missile_inputs(-1)), missile_inputs, REF_OUTPUTS, n_steps)


def test_readme_holds_generated_variable_table():
    assert readme_has_generated_table(UNIT)


def test_validates(fmu):
    assert validate_fmu(str(fmu)) == []


def test_golden_reference(fmu):
    ref = np.loadtxt(UNIT / "reference.csv", delimiter=",", skiprows=1)
    got = simulate_reference(fmu, len(ref))
    np.testing.assert_allclose(got, ref, rtol=1e-7, atol=1e-9)
    contact = got[:, 1 + REF_OUTPUTS.index("pair[1].in_contact")]
    assert contact[0] == 0 and contact.max() == 1  # the dive reaches the tank
    toi = got[:, 1 + REF_OUTPUTS.index("pair[1].toi")]
    first = int(np.argmax(contact))
    assert 0 <= toi[first] <= H  # the step that first touches reports its time of impact


def test_two_instances_in_one_process(fmu):
    a = Runner(fmu, "a", dict(PARAMS, max_distance=100.0))
    b = Runner(fmu, "b", {"scene": "box:name=wall,sx=1,sy=4,sz=4;sphere:name=ball,r=0.5,dynamic=1", "pairs": ""})
    try:
        for k in range(3):
            a.step({"body[1].z": 20.0})
            b.step({"body[1].x": 2.0 - 0.4 * k})
        da, db = a.get(["pair[1].distance"])[0], b.get(["pair[1].distance"])[0]
    finally:
        a.close()
        b.close()
    assert 15.0 < da < 20.0
    assert db == pytest.approx(2.0 - 0.8 - 0.5 - 0.5, abs=0.02)  # icosphere facets: within 2 cm


def test_nan_pose_is_an_error_naming_the_variable(fmu):
    r = Runner(fmu, "nanny", PARAMS)
    try:
        r.step({"body[1].z": 10.0})
        with pytest.raises(FMICallException):
            r.step({"body[1].yaw": float("nan")})
        assert any("body[1].yaw" in m and "not finite" in m and "nanny" in m for m in r.messages), r.messages
    finally:
        r.close()


def _init_error_messages(fmu, params):
    """Initialise an instance with ``params`` in a fresh process (pythonfmu turns a failed
    initialisation into fmi2Fatal, after which freeing the instance may crash the process)
    and return the logged messages and whether exitInitializationMode failed."""
    import json
    import subprocess

    code = (
        "import json, sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from test_collision_fmu import Runner\n"
        f"r = Runner({str(fmu)!r}, 'meshy', json.loads({json.dumps(json.dumps(params))}), init=False)\n"
        "failed = False\n"
        "try:\n    r.fmu.exitInitializationMode()\nexcept Exception:\n    failed = True\n"
        "print(json.dumps({'failed': failed, 'messages': r.messages}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    data = json.loads(out.stdout.strip().splitlines()[-1])
    return data["failed"], data["messages"]


def test_missing_mesh_is_an_error_at_initialisation_naming_the_file(fmu, tmp_path):
    missing = tmp_path / "no_such_rock.stl"
    failed, messages = _init_error_messages(fmu, {"scene": f"mesh:file={missing},dynamic=1"})
    assert failed
    assert any("no_such_rock.stl" in m and "does not exist" in m and "meshy" in m for m in messages), messages


def test_corrupt_mesh_is_an_error_at_initialisation_naming_the_file(fmu, tmp_path):
    bad = tmp_path / "garbage.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n\x00\x01")
    failed, messages = _init_error_messages(fmu, {"scene": f"mesh:file={bad},dynamic=1"})
    assert failed
    assert any("garbage.ply" in m and "meshy" in m for m in messages), messages


def test_unknown_backend_is_an_error(fmu):
    failed, messages = _init_error_messages(fmu, {"backend": "gjk"})
    assert failed
    assert any("backend" in m and "gjk" in m for m in messages), messages


def test_fmu_state_roll_back(fmu):
    r = Runner(fmu, params=dict(PARAMS, **missile_inputs(-1)))
    try:
        for k in range(20):
            r.step(missile_inputs(k))
        s = r.fmu.getFMUstate()
        k0 = r.k
        for k in range(20, 28):
            r.step(missile_inputs(k))
        first = r.get(REF_OUTPUTS)
        r.fmu.setFMUstate(s)
        r.k = k0
        for k in range(20, 28):
            r.step(missile_inputs(k))
        np.testing.assert_array_equal(r.get(REF_OUTPUTS), first)
        r.fmu.freeFMUstate(s)
    finally:
        r.close()


def test_unchanged_inputs_return_the_cached_outputs_and_roll_back(fmu):
    """Steps without a pose change: same contact, distance, point and normal, no time of
    impact or closing speed, nothing tested; a state saved in a rest step restores it."""
    outs = REF_OUTPUTS + ["pair[2].toi"]
    r = Runner(fmu, params=dict(PARAMS, **missile_inputs(-1)))
    try:
        for k in range(12):  # into contact
            r.step(missile_inputs(k))
        moving = dict(zip(outs, r.get(outs)))
        assert moving["pair[1].in_contact"] == 1 and moving["at_rest"] == 0
        rest = []
        for _ in range(3):
            r.step(missile_inputs(11))
            rest.append(dict(zip(outs, r.get(outs))))
        s = r.fmu.getFMUstate()
        k0 = r.k
        for got in rest:
            assert got["at_rest"] == 1 and got["n_candidates"] == got["n_narrow"] == 0
            assert got["pair[1].toi"] == got["pair[2].toi"] == -1.0 and got["pair[1].closing_speed"] == 0.0
            for name in ("pair[1].in_contact", "pair[1].distance", "pair[1].depth", "pair[1].px",
                         "pair[1].nx", "pair[1].ny", "pair[1].nz", "pair[2].distance"):
                assert got[name] == moving[name], name
        r.step(missile_inputs(12))
        after = r.get(outs)
        assert dict(zip(outs, after))["at_rest"] == 0
        r.fmu.setFMUstate(s)
        r.k = k0
        r.step(missile_inputs(11))  # still at rest after the roll back
        assert dict(zip(outs, r.get(outs)))["at_rest"] == 1
        r.step(missile_inputs(12))
        np.testing.assert_array_equal(r.get(outs), after)
        r.fmu.freeFMUstate(s)
    finally:
        r.close()


def test_same_outputs_under_fmpy_and_libcosim(fmu):
    from immersim.orchestrator.crosscheck import simulate_fmpy, simulate_libcosim

    start = dict(PARAMS, **{"body[1].x": 0.5, "body[1].z": 2.5, "body[1].pitch": 0.3})
    outs = ["pair[1].distance", "pair[1].depth", "pair[1].px", "pair[1].pz", "pair[1].nz", "pair[2].distance"]
    a = simulate_fmpy(fmu, start, 5, outs)[0]
    b = simulate_libcosim(fmu, start, 5, outs)[0]
    for name in outs:
        np.testing.assert_allclose(a[name], b[name], rtol=1e-12, atol=1e-15, err_msg=name)
    assert a["pair[1].depth"][0] > 0  # the missile sits in the tank: a contact


@pytest.mark.parametrize("backend", ["fcl", "basis_point", "honeycomb"])
def test_every_backend_runs_in_the_fmu(fmu, backend):
    params = {"scene": "tank:tris=5.4k;missile:z=8", "pairs": "missile vs tank", "backend": backend,
              "st": 0.1, "cells_n": 4, "cells_m": 4, "body[1].z": 8.0, "max_distance": 100.0}
    r = Runner(fmu, f"b_{backend}", params)
    try:
        r.step({"body[1].x": 0.5, "body[1].z": 7.0, "body[1].pitch": 0.3})
        apart = r.get(["pair[1].in_contact", "pair[1].distance"])
        r.step({"body[1].z": 2.5})
        hit = r.get(["pair[1].in_contact", "n_candidates", "n_narrow"])
    finally:
        r.close()
    assert apart[0] == 0 and apart[1] > 2.0
    assert hit[0] == 1 and hit[1] >= 1 and hit[2] >= 1


if __name__ == "__main__":  # regenerate the golden file: python tests/collision/test_collision_fmu.py
    path = build_unit(UNIT, default_build_dir())
    data = simulate_reference(path)
    np.savetxt(UNIT / "reference.csv", data, delimiter=",", header="time," + ",".join(REF_OUTPUTS), comments="",
               fmt="%.17g")
    print(f"wrote {UNIT / 'reference.csv'} ({len(data)} rows)")


def test_steps_without_a_changed_output_write_nothing_and_say_so():
    """The wrapper's "outputs unchanged" answer (far pairs and pairs at rest hand out the
    results already written, the counters repeat) leaves every output as writing them all
    would: the same values step by step, with a state restored in between."""
    from immersim.fmus.common import OUTPUTS_UNCHANGED

    cls = wrapper_class(UNIT)
    outs = [v.name for v in cls.VARIABLES if v.causality == "output"]
    params = {"scene": "tanks:n=4,tris=5.4k,spacing=12;box:name=a,sx=4,sy=2,sz=4.4,dynamic=1,x=-20;"
                       "sphere:name=e,r=1,dynamic=1,x=40",
              "pairs": "a vs any tank (horizontal); e vs a", "max_distance": 2.0}

    def run(every_step):
        s = cls(instance_name="t", resources=str(UNIT), visible=False, logging_callback=None)
        s.values.update(params)
        s.setup_experiment(0.0, None, None)
        s.exit_initialization_mode()
        rows, unchanged, saved = [], 0, None
        for k in range(60):
            s.values["body[1].x"] = -20.0 + 0.4 * min(k, 40)  # drives up to tank_0 (origin), stops
            s.values["body[2].y"] = 0.25 * k  # the ball keeps rolling, far from everything
            if k == 20:
                saved = s._get_fmu_state()
            if k == 30:
                s._set_fmu_state(saved)
            if every_step:
                s._shown, s._counters = [None] * len(s._shown), None
            t = s._time
            unchanged += s.step_model(t, H) is OUTPUTS_UNCHANGED
            s._time = t + H
            rows.append([s.values[n] for n in outs])
        return rows, unchanged

    fast, n_unchanged = run(False)
    full, _ = run(True)
    assert fast == full
    assert 10 < n_unchanged < 50  # far steps and the steps at rest next to the tank
