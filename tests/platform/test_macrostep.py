"""The one-call compiled macro step against the composed path (CasADi VM), the symbolic washout
against the numpy one, clamping, failed steps and the on-disk library cache."""
import numpy as np
import pytest

from immersim.models.platform import codegen, macrostep
from immersim.models.platform.control import prefiltered_loop
from immersim.models.platform.cueing import (NWM, NWS, Washout, WashoutParams, continuous_system, expm_small,
                                             washout_matrices, washout_sx)
from immersim.models.platform.integrators import IntegratorConfig
from immersim.models.platform.kinematics import OutsideWorkspaceError, clamp_to_workspace, workspace_check
from immersim.models.platform.simulator import PlatformSim, SimConfig, StepInputs

H = 0.033


@pytest.mark.parametrize("h", [1e-3, 0.033, 0.5, 4.0])
def test_numpy_expm_of_the_washout_system_is_scipys(h):
    from scipy.linalg import expm

    A, B, *_ = continuous_system(WashoutParams())
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    np.testing.assert_allclose(expm_small(M * h), expm(M * h), rtol=0, atol=1e-14)


def test_symbolic_washout_is_the_numpy_washout():
    import casadi as ca

    p = WashoutParams(tilt_rate=0.2)
    w, cue, wm = ca.SX.sym("w", NWS), ca.SX.sym("cue", 7), ca.SX.sym("wm", NWM)
    f = ca.Function("f", [w, cue, wm], list(washout_sx(w, cue, wm)))
    ref_np, state, mats = Washout(p), np.zeros(NWS), washout_matrices(p, H)
    rng = np.random.default_rng(1)
    for _ in range(200):
        c = rng.normal(size=7) * 3.0
        ref = ref_np.step(c[:3], c[3:6], c[6], H)
        state, ref_sx = (np.asarray(v, float).ravel() for v in f(state, c, mats))
        np.testing.assert_allclose(ref_sx, ref, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(state, np.concatenate([ref_np.x, ref_np.tilt]), rtol=1e-13, atol=1e-15)


def _inputs(kind, k):
    t = k * H
    if kind == "washout":  # hard avatar manoeuvres with collision jolts: tilt, clamps
        return StepInputs(f=np.array([10.0 * np.sin(2 * t), 5.0 * np.cos(1.5 * t), 0.3]),
                          omega=np.array([0.05 * np.sin(t), 0.04, 0.3 * np.sin(0.2 * t)]),
                          jolt=12.0 if k % 17 == 5 else 0.0)
    return StepInputs(ref=np.array([0.05 * np.sin(t), 0.15 * np.sin(0.7 * t), 0.03 * np.cos(t),
                                    0.1 * np.sin(t), 0.3 * np.sin(0.5 * t), 0.05]))


@pytest.mark.parametrize("cueing", ["washout", "pose"])
def test_one_native_call_equals_the_composed_path_in_the_casadi_vm(cueing):
    cfg = SimConfig(cueing=cueing, cos_beta_min=0.995)  # beta above ~0.1 rad trips the flag
    fast = PlatformSim(cfg)
    slow = PlatformSim(SimConfig(cueing=cueing, cos_beta_min=0.995, integrator=IntegratorConfig(compiled=False)))
    assert fast.macro.has_driver and not slow.macro.has_driver and not slow.macro.compiled
    flags = np.zeros(4)
    for k in range(45):
        a, b = fast.step(_inputs(cueing, k), H, k * H), slow.step(_inputs(cueing, k), H, k * H)
        np.testing.assert_allclose(a.packed, b.packed, rtol=1e-11, atol=1e-11)
        assert (a.saturated, a.near_singular, a.outside_workspace, a.at_rest) == \
            (b.saturated, b.near_singular, b.outside_workspace, b.at_rest)
        flags += (a.saturated, a.near_singular, a.outside_workspace, a.at_rest)
        np.testing.assert_allclose(fast.macro.state, slow.macro.state, rtol=1e-11, atol=1e-11)
    assert flags[2] > 0  # the clamping branch ran
    if cueing == "pose":
        assert flags[1] > 0


def test_native_clamp_is_the_bisection_of_clamp_to_workspace():
    sim = PlatformSim(SimConfig(cueing="pose"))
    ref = np.array([0.02, 0.2, 0.0, 0.0, 0.2, 0.0])
    assert not workspace_check(ref).inside[0]
    sim.step(StepInputs(ref=ref), H)
    expected, clamped = clamp_to_workspace(ref)
    assert clamped and sim.out.outside_workspace
    np.testing.assert_array_equal(sim.u[:6], expected)
    np.testing.assert_array_equal(sim.raw_ref, ref)
    assert workspace_check(sim.u[:6]).inside[0]


def test_reference_outside_in_error_mode_raises_and_leaves_the_state():
    sim = PlatformSim(SimConfig(cueing="pose", on_workspace="error"))
    sim.step(StepInputs(ref=np.array([0, 0.03, 0, 0, 0, 0])), H)
    before, out = sim.get_state()["state"], sim.out
    with pytest.raises(OutsideWorkspaceError, match=r"pose reference \[.*0\.3.*\] at t = 0\.033 s is outside the workspace"):
        sim.step(StepInputs(ref=np.array([0, 0.3, 0, 0, 0, 0])), H, H)
    np.testing.assert_array_equal(sim.macro.state, before)
    assert sim.out is out


def test_diverging_step_raises_and_leaves_the_state():
    sim = PlatformSim(SimConfig(control_mode="direct", cueing="pose"))
    push = StepInputs(force_cmd=np.array([0, 0, 0, 3000.0, 3000.0, 3000.0]))
    with pytest.raises((ArithmeticError, OutsideWorkspaceError), match="reach") as info:
        for k in range(200):
            before = sim.macro.state.copy()
            sim.step(push, H, k * H)
    assert f"t = {(k + 1) * H:g} s" in str(info.value)
    np.testing.assert_array_equal(sim.macro.state, before)
    assert np.isfinite(sim.macro.state).all()


def test_a_second_instance_and_a_new_process_reuse_the_compiled_library(monkeypatch):
    rhs = prefiltered_loop("computed_torque", "full")
    assert macrostep.MacroStep(rhs).has_driver  # compiled (or loaded from the disk cache)
    macrostep._library.cache_clear()

    def no_compiler(*args, **kwargs):
        raise AssertionError("the compiler ran although the library is in the cache")

    monkeypatch.setattr(codegen.subprocess, "run", no_compiler)
    assert macrostep.MacroStep(rhs).has_driver  # same C source -> same hash -> cached .so


def test_without_a_compiler_the_casadi_vm_runs_the_same_step(monkeypatch):
    monkeypatch.setattr(codegen, "compiler", lambda: None)
    macrostep._library.cache_clear()
    try:
        vm = macrostep.MacroStep(prefiltered_loop("computed_torque", "full"))
    finally:
        macrostep._library.cache_clear()
    assert not vm.compiled and vm.run() == -1
