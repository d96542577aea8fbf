"""The switch between the fast and plain forms of the network model's steps (:class:`Paths`):
whole runs with the shortcuts on and off give the same outputs, bit for bit.

* the small-scene shortcuts (campus size): ownership, display error and contact pre-check in
  Python floats, a resting scene's display error and sub-steps skipped, memo'd messages and
  merged link draws, against the array code and per-frame messages (contacts, bounces);
* the per-frame shortcuts: batches timed in Python floats, view pairs, messages, display,
  records and kinematics of small scenes, against the array code, with joins, graceful leaves
  and crashes (the online-node count included);
* every shortcut off at once (:meth:`Paths.plain`).
"""
import math
from dataclasses import fields

import numpy as np
import pytest

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel
from immersim.models.network.paths import Paths

from .helpers import LOSSY


T = 0.033
LINKS = {"lan": LinkClass(0.3, 0.1, 0.0, 1000.0), "wan": LinkClass(20.0, 5.0, 0.0, 100.0)}
#: the small-scene shortcuts off (the array code and per-frame messages)
SMALL_PLAIN = Paths(scalar_owners=-1, scalar_contacts=-1, merge_draws=False, rest_skip=False, rest_display=False,
                    scalar_view=-1, memo_pairs=-1)
#: the per-frame shortcuts off: batches planned and timed, view pairs, messages, display and
#: kinematics in arrays, every frame's records in a table
FRAME_PLAIN = Paths(float_batch=-1, scalar_grid=-1, scalar_messages=-1, scalar_view=-1, few_records=-1,
                    scalar_avatars=0, scalar_entities=0)


def _trace(cfg, steps, bounce_every=0, paths=None):
    m = NetworkModel(cfg, paths)
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
def test_small_scene_shortcuts_change_nothing(case):
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=4, scene_size=60.0,
                                  entity_speed=3.0).replace(**CASES[case])
    fast = _trace(cfg, 90, bounce_every=13)
    _same(fast, _trace(cfg, 90, bounce_every=13, paths=SMALL_PLAIN))


def _run(cfg, steps=180, paths=None):
    m = NetworkModel(cfg, paths)
    m.schedule_leave(0.7, 1)                        # a graceful leave of a slave,
    m.schedule_leave(0.4, 3, graceful=False)        # a crashed master (times out after 3 s),
    m.schedule_join(2.4, 1)                         # and both rejoin
    m.schedule_join(5.2, 3)
    out = []
    for k in range(steps):
        for g in range(cfg.driven_groups):
            m.set_input(g, 0.0 if k < 10 else 0.9 - 0.4 * g, 0.25 * (g - 1) if k > 40 else 0.0)
        if k % 17 == 16:
            m.bounce(k % cfg.groups, (-1.0, 0.4))
        s = m.step(T).as_dict()
        assert s["online_nodes"] == int(np.count_nonzero(m.online))
        out.append((s, m.at_rest(), m.world.avatar_outputs(T), m.perceived_avatars(1).tolist(),
                    m.per_object_max.tolist(), m.per_object_rms.tolist()))
    return m, out


FRAME_CASES = [
    dict(),                                                             # the campus_drive size
    dict(links={"lan": LinkClass(0.3, 0.2, 0.05, 1000.0), "wan": LinkClass(20.0, 8.0, 0.1, 50.0)}),
    dict(prediction_order=2, links={"lan": LinkClass(0.3, 0.1, 0.0, 0.0), "wan": LinkClass(30.0, 12.0, 0.0, 0.0)}),
    dict(prediction_order=0, topology="client_server"),
    dict(entities=20, scene_size=30.0, ownership="euclidean"),
    dict(ownerless=False, frame_phase=False, state_traffic="object_view"),   # the former defaults
]


@pytest.mark.parametrize("case", range(len(FRAME_CASES)))
def test_frame_shortcuts_change_nothing(case):
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=5, scene_size=60.0,
                                  entity_speed=3.0, links=LINKS).replace(**FRAME_CASES[case])
    fast, fo = _run(cfg)
    plain, po = _run(cfg, paths=FRAME_PLAIN)
    assert fo == po
    for name in ("cache", "owner", "hist", "shown_frame", "busy", "online"):
        assert np.array_equal(getattr(fast, name), getattr(plain, name)), name
    assert fast.totals.by_type == plain.totals.by_type and fast.totals.frames == plain.totals.frames
    assert fast.rng.bit_generator.state == plain.rng.bit_generator.state
    assert fast.supernode.timeouts == 1 and fast.supernode.leaves == 1
    assert any(s["handovers"] + s["released"] + s["claimed"] for s, *_ in fo)
    assert max(s["inconsistency_max"] for s, *_ in fo) > 0.0
    assert not math.isnan(fo[-1][0]["inconsistency_rms"])


@pytest.mark.parametrize("case", [0, 2, 3])
def test_every_shortcut_off_changes_nothing(case):
    """Paths.plain(): every step in its plain form at once, the same run as the default."""
    cfg = NetworkConfig.from_flat(groups=3, render_nodes=3, entities=8, driven_groups=3, seed=4, scene_size=60.0,
                                  entity_speed=3.0).replace(**CASES[case])
    _same(_trace(cfg, 90, bounce_every=13), _trace(cfg, 90, bounce_every=13, paths=Paths.plain()))


def test_plain_paths_switch_every_shortcut_off():
    plain, default = Paths.plain(), Paths()
    changed = {f.name for f in fields(Paths) if getattr(plain, f.name) != getattr(default, f.name)}
    assert changed == {f.name for f in fields(Paths)} - {"brute_owners", "measure_chunk"}
    assert Paths.plain(scalar_view=5).scalar_view == 5 and Paths.plain(scalar_view=5).memo_pairs == -1
    with pytest.raises(AttributeError):
        default.scalar_view = 1            # frozen: one switch object, shared safely
