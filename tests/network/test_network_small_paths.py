"""The small-scene shortcuts (campus size) change no output: each is checked against the
array code it replaces, bit for bit.

* ownership (eq. 3-6, 3-11/3-12, 3-3) in Python floats, with the sphere-of-radius-``a`` cull,
  vs the array code (every rule and reading of the foci, resting and degenerate avatars);
* the display error (eq. 3-1/3-2) of small views in Python floats, and
  skipped for a resting scene whose copies hold records of that state;
* the contact pre-check in Python floats; avatars at a sub-step fixed point not sub-stepped
  (their frame arrays reused);
* the memo'd messages found by group version / ownership epoch / view object, and the link
  jitter of several classes drawn in one call;
  all vs the array code, messages built every frame, one draw per link class, every sub-step;
* the FMU wrapper's "outputs unchanged" shortcut (``OUTPUTS_UNCHANGED`` at rest) vs writing
  every output every step, through driving, bounces, idling and a state restore;
* the FMU wrapper's output check on the outputs the step wrote (the first check after set-up
  or a restore reads every output; a non-finite output is still named).
"""
import importlib.util
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from immersim.fmus.common import OUTPUTS_UNCHANGED
from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network import consistency as cons
from immersim.models.network import links as links_mod
from immersim.models.network import model as model_mod
from immersim.models.network import world as world_mod

T = 0.033
LOSSY = {"lan": LinkClass(0.3, 0.2, 0.05, 1000.0), "wan": LinkClass(20.0, 8.0, 0.1, 50.0)}
UNIT = Path(__file__).resolve().parents[2] / "fmus" / "network" / "network_fmu.py"


def _plain(monkeypatch):
    """Switch every small-scene shortcut off (the array code and per-frame messages)."""
    monkeypatch.setattr(cons, "SCALAR_PAIRS", -1)
    monkeypatch.setattr(world_mod, "SCALAR_CONTACT_PAIRS", -1)
    monkeypatch.setattr(links_mod, "MERGE_DRAWS", False)
    monkeypatch.setattr(world_mod, "REST_SKIP", False)
    monkeypatch.setattr(model_mod, "REST_DISPLAY", False)
    for name in ("SCALAR_VIEW", "MEMO_PAIRS"):
        monkeypatch.setattr(model_mod, name, -1)


@pytest.mark.parametrize("rule,foci", [("mahalanobis", "frame"), ("mahalanobis", "reach"), ("euclidean", "frame")])
def test_scalar_ownership_equals_the_array_code(monkeypatch, rule, foci):
    rng = np.random.default_rng(5)
    for trial in range(300):
        G, E = rng.integers(1, 6), rng.integers(1, 30)
        apos = rng.uniform(0, 20, (G, 2))
        vel = rng.normal(0, 8, (G, 2)) * (rng.random((G, 1)) < 0.7)     # some avatars at rest
        if trial % 7 == 0:
            vel[:] = np.round(vel)                                       # exact ties of speed
        epos = np.r_[apos[rng.integers(0, G, E // 2)] + rng.normal(0, 3, (E // 2, 2)), rng.uniform(0, 20, (E - E // 2, 2))]
        cur = rng.integers(0, G, E)
        min_axis = 0.0 if trial % 11 == 0 else float(rng.choice([0.5, 2.0, 5.0]))   # 0: degenerate (array code)
        args = (rule, apos, vel, epos, cur, T, 30.0, min_axis, foci)
        with np.errstate(divide="ignore", invalid="ignore"):   # a = 0: the array code's inf/NaN
            fast = cons.assign_owners(*args)
            with monkeypatch.context() as mp:
                mp.setattr(cons, "SCALAR_PAIRS", -1)
                plain = cons.assign_owners(*args)
        np.testing.assert_array_equal(fast, plain)


def test_ownership_from_lists_equals_the_arrays():
    """``assign_owners`` given the positions and velocities as lists (the small frame's; the
    velocity array left out) gives the array call's owners, degenerate ellipsoids included
    (``min_axis`` 0 and a resting avatar: the array code from the listed velocities)."""
    rng = np.random.default_rng(8)
    for trial in range(200):
        G, E = int(rng.integers(1, 5)), int(rng.integers(1, 12))
        apos = rng.uniform(0, 20, (G, 2))
        vel = rng.normal(0, 8, (G, 2)) * (rng.random((G, 1)) < 0.7)
        epos = rng.uniform(0, 20, (E, 2))
        cur = rng.integers(0, G, E)
        min_axis = 0.0 if trial % 5 == 0 else 5.0
        for rule in ("mahalanobis", "euclidean"):
            with np.errstate(divide="ignore", invalid="ignore"):
                ref = cons.assign_owners(rule, apos, vel, epos, cur, T, 30.0, min_axis)
                out = cons.assign_owners(rule, apos, None, epos, cur, T, 30.0, min_axis,
                                         lists=(apos.tolist(), vel.tolist(), epos.tolist()))
            np.testing.assert_array_equal(out, ref)


def _trace(cfg, steps, bounce_every=0):
    m = NetworkModel(cfg)
    out = []
    for k in range(steps):
        idle = k < 15 or steps // 3 <= k < steps // 2   # at rest first (exactly), then coasting
        for g in range(cfg.driven_groups):
            m.set_input(g, 0.0 if idle else (0.8 if k < steps // 2 else -0.6), 0.0 if idle else 0.2 * (g - 1))
        if bounce_every and k % bounce_every == bounce_every - 1:
            m.bounce(k % cfg.groups, (-1.0, 0.3))
        out.append(m.step(T).as_dict())
    return m, out


def _same(a, b):
    (ma, oa), (mb, ob) = a, b
    assert oa == ob
    for name in ("cache", "owner", "per_object_max", "per_object_rms", "hist", "shown_frame", "busy"):
        np.testing.assert_array_equal(getattr(ma, name), getattr(mb, name), err_msg=name)
    assert ma.totals.by_type == mb.totals.by_type
    assert ma.rng.bit_generator.state == mb.rng.bit_generator.state


CASES = [
    dict(),                                                             # the campus_drive size
    dict(links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(40.0, 15.0, 0.0, 2.0)}),
    dict(links=LOSSY, prediction_order=2),
    dict(links=LOSSY, prediction_order=0, ownership="euclidean", topology="client_server"),
    dict(topology="full_mesh", grid=False, entities=3),
    dict(ownership_foci="reach", dis_threshold=0.1, scene_size=40.0),
    dict(entities=0, render_nodes=1),                                   # the campus_idle size, no slaves
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_small_scene_shortcuts_change_nothing(monkeypatch, case):
    cfg = replace(NetworkConfig(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=4, scene_size=60.0,
                                entity_speed=3.0), **CASES[case])
    fast = _trace(cfg, 90, bounce_every=13)
    _plain(monkeypatch)
    _same(fast, _trace(cfg, 90, bounce_every=13))


def _load_wrapper():
    spec = importlib.util.spec_from_file_location("network_fmu_under_test", UNIT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.network


def _instance(cls, params, name="t"):
    """An instance of the wrapper class ``cls`` with ``params``, out of initialization mode."""
    s = cls(instance_name=name, resources=str(UNIT.parent), visible=False, logging_callback=None)
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
