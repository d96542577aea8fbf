"""The platform FMU: validation, golden reference, robustness, state, FMPy vs libcosim."""
import math
from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from immersim.models.platform.kinematics import inverse_kinematics, workspace_check
from immersim.orchestrator.build import build_unit, default_build_dir
from immersim.orchestrator.errors import FmuCallError
from immersim.orchestrator.fmu import FmuInstance
from tests.fmpy_runner import readme_has_generated_table, simulate

UNIT = Path(__file__).resolve().parents[2] / "fmus" / "platform"
REF_OUTPUTS = ["pose.x", "pose.y", "pose.z", "pose.gamma", "pose.beta", "pose.alpha"] + \
    [f"stroke[{i}]" for i in range(1, 7)] + [f"force[{i}]" for i in range(1, 7)] + ["track_err"]
H = 0.033
H_NS = 33_000_000


@pytest.fixture(scope="module")
def fmu():
    return build_unit(UNIT, default_build_dir())


class Runner:
    """The orchestrator's FMPy instance (:class:`FmuInstance`) with a step counter, values as arrays."""

    def __init__(self, path, name="p", params=None):
        self.inst = FmuInstance(name, path)
        self.inst.initialize(0, None, params or {})
        self.fmu = self.inst.fmu  # the fmpy FMU2Slave
        self.k = 0

    @property
    def messages(self):
        return list(self.inst.messages)

    def get(self, names):
        return np.array([float(v) for v in self.inst.get_values(names)])

    def step(self, inputs=None):
        if inputs:
            self.inst.set_values(inputs)
        self.inst.do_step(self.k * H_NS, H_NS)
        self.k += 1

    def close(self):
        self.inst.terminate()


def sine_inputs(k):
    t = (k + 1) * H
    w = 2 * math.pi * 0.5
    return {"ref.y": 0.03 * math.sin(w * t), "ref.z": 0.015 * math.cos(w * t) - 0.015, "ref.gamma": 0.05 * math.sin(w * t)}


def simulate_reference(path, n_steps=91):
    return simulate(path, {"cueing": "pose"}, sine_inputs, REF_OUTPUTS, n_steps, runner=Runner)


def test_readme_holds_generated_variable_table():
    assert readme_has_generated_table(UNIT)


def test_validates(fmu):
    assert validate_fmu(str(fmu)) == []


def test_golden_reference_and_ik_consistency(fmu):
    got = simulate_reference(fmu)
    ref = np.loadtxt(UNIT / "reference.csv", delimiter=",", skiprows=1)
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=1e-7, atol=1e-9)
    poses = got[:, 1:7]
    np.testing.assert_allclose(got[:, 7:13], inverse_kinematics(poses), atol=1e-12)
    # after the transient the platform is the prefiltered sine: the critically damped filter
    # (omega_f = 15 rad/s) has gain 1/(1 + (w/omega_f)^2) and phase -2 atan(w/omega_f); the input,
    # held over each step at its end value, leads by half a step
    t, w, wf = got[:, 0], math.pi, 15.0
    y_ss = 0.03 / (1 + (w / wf) ** 2) * np.sin(w * t - 2 * math.atan(w / wf) + w * H / 2)
    assert np.max(np.abs(poses[30:, 1] - y_ss[30:])) < 5e-5


def test_two_instances_in_one_process(fmu):
    a = Runner(fmu, "a", {"cueing": "pose"})
    b = Runner(fmu, "b", {"cueing": "pose", "M": 300.0})
    try:
        for k in range(20):
            a.step({"ref.y": 0.02})
            b.step({"ref.z": -0.02})
        ya, zb = a.get(["pose.y", "pose.z"]), b.get(["pose.y", "pose.z"])
    finally:
        a.close()
        b.close()
    assert ya[0] > 0.015 and abs(ya[1]) < 1e-12
    assert zb[1] < -0.015 and abs(zb[0]) < 1e-12


def test_nan_input_is_an_error_naming_the_variable(fmu):
    r = Runner(fmu, "nanny", {"cueing": "pose"})
    try:
        r.step({"ref.y": 0.01})
        r.inst.set_values({"ref.gamma": float("nan")})
        with pytest.raises(FMICallException) as exc:  # FMPy's own doStep refuses the step
            r.fmu.doStep(currentCommunicationPoint=r.k * H, communicationStepSize=H)
        assert exc.value.status in (2, 3)  # fmi2Discard (TableSlave's refused step) or fmi2Error
        assert any("ref.gamma" in m and "not finite" in m and "nanny" in m for m in r.messages), r.messages
    finally:
        r.close()


def test_reference_outside_workspace_is_clamped_and_flagged(fmu):
    r = Runner(fmu, params={"cueing": "pose"})
    try:
        for _ in range(60):
            r.step({"ref.y": 0.5, "ref.z": 0.2})
        y, z, flag = r.get(["pose.y", "pose.z", "flag.outside_workspace"])
    finally:
        r.close()
    assert flag == 1.0
    assert workspace_check(np.array([0, y, z, 0, 0, 0])).inside[0]
    assert y > 0.05 and np.isclose(z / y, 0.2 / 0.5, rtol=1e-3)  # pulled back along the request


def test_reference_outside_workspace_error_mode(fmu):
    r = Runner(fmu, "strict", {"cueing": "pose", "on_workspace": "error"})
    try:
        r.step({"ref.y": 0.01})
        with pytest.raises(FmuCallError, match=r"unit strict: fmi2DoStep returned (error|discard) at t = 0.033 s: .*"
                                               r"OutsideWorkspaceError: strict: pose reference .* outside the workspace"):
            r.step({"ref.y": 0.5})
    finally:
        r.close()


def test_beta_towards_90_degrees_is_flagged_before_any_nan(fmu):
    r = Runner(fmu, params={"cueing": "pose"})
    names = ["pose.beta", "flag.near_singular", "flag.outside_workspace"] + REF_OUTPUTS
    try:
        first_flag = None
        for k in range(100):
            beta = k / 99 * math.pi / 2
            r.step({"ref.beta": beta})
            vals = r.get(names)
            assert np.all(np.isfinite(vals))
            if first_flag is None and vals[1] == 1.0:
                first_flag = beta
        assert first_flag is not None and first_flag < math.radians(81)
        assert vals[0] < math.radians(60)  # the platform itself stays in its workspace
    finally:
        r.close()


def test_fmu_state_roll_back(fmu):
    r = Runner(fmu, params={"cueing": "washout"})
    try:
        for _ in range(10):
            r.step({"cue.f_x": 1.0, "cue.w_z": 0.2})
        s = r.fmu.getFMUstate()
        k0 = r.k
        for _ in range(10):
            r.step({"cue.f_x": -1.0, "jolt": 3.0})
        first = r.get(REF_OUTPUTS)
        r.fmu.setFMUstate(s)
        r.k, r.inst.t_ns = k0, k0 * H_NS
        for _ in range(10):
            r.step({"cue.f_x": -1.0, "jolt": 3.0})
        np.testing.assert_array_equal(r.get(REF_OUTPUTS), first)
        r.fmu.freeFMUstate(s)
    finally:
        r.close()


def test_same_outputs_under_fmpy_and_libcosim(fmu):
    from immersim.orchestrator.crosscheck import simulate_fmpy, simulate_libcosim

    start = {"cueing": "washout", "cue.f_x": 1.5, "cue.w_y": 0.1, "cue.f_z": -0.5}
    outs = REF_OUTPUTS
    a = simulate_fmpy(fmu, start, 40, outs)[0]
    b = simulate_libcosim(fmu, start, 40, outs)[0]
    for name in outs:
        np.testing.assert_allclose(a[name], b[name], rtol=1e-12, atol=1e-15, err_msg=name)
    assert np.max(np.abs(a["pose.x"])) > 1e-3  # something moved


if __name__ == "__main__":  # regenerate the golden file: python tests/platform/test_fmu.py
    path = build_unit(UNIT, default_build_dir())
    data = simulate_reference(path)
    np.savetxt(UNIT / "reference.csv", data, delimiter=",", header="time," + ",".join(REF_OUTPUTS), comments="",
               fmt="%.17g")
    print(f"wrote {UNIT / 'reference.csv'} ({len(data)} rows)")
