"""Network configuration: derived sizes, flat keywords routed to their groups, and the bounds
its checks enforce (exact messages)."""
from dataclasses import fields

import pytest

from immersim.models.network.config import GROUPS, NetworkConfig, WorldConfig


def test_render_node_count_is_groups_times_nodes_per_group():
    assert NetworkConfig.from_flat(groups=3, render_nodes=4).n_render == 12
    assert NetworkConfig.from_flat(groups=1, render_nodes=1).n_render == 1


def test_every_flat_keyword_lands_in_the_one_group_that_holds_it():
    names = [f.name for group in GROUPS.values() for f in fields(group)]
    assert len(names) == len(set(names)) and not set(names) & {f.name for f in fields(NetworkConfig)}
    cfg = NetworkConfig.from_flat(groups=2, restitution=0.25, pastry_L=8, ownerless=True, frame_s=0.02,
                                  topology="full_mesh")
    assert (cfg.groups, cfg.world.restitution, cfg.membership.pastry_L, cfg.consistency.ownerless,
            cfg.scene.frame_s, cfg.net.topology) == (2, 0.25, 8, True, 0.02, "full_mesh")
    # the rest of each group keeps its defaults, and a copy changes only what it names
    assert cfg.world == WorldConfig(restitution=0.25)
    again = cfg.replace(drag=0.5)
    assert again.world == WorldConfig(restitution=0.25, drag=0.5) and again.consistency == cfg.consistency
    assert cfg.replace(world=WorldConfig()).world.restitution == 0.5


def test_an_unknown_keyword_is_named():
    with pytest.raises(TypeError, match="NetworkConfig: unknown option\\(s\\) restitutoin"):
        NetworkConfig.from_flat(restitutoin=0.2)


@pytest.mark.parametrize("kw, message", [
    (dict(groups=0), "groups = 0 must be >= 1"),
    (dict(grid_cells=0), "grid_cells = 0 must be >= 1"),
    (dict(ownership_scale=0.5), r"ownership_scale = 0.5 must be > 0.5 \(eq. 3-12\)"),
    (dict(groups=2, driven_groups=3), r"driven_groups = 3 must be in \[0, groups\]"),
    (dict(prediction_order=3), "prediction_order = 3 must be 0, 1 or 2"),
    (dict(heartbeat_s=0.0), "heartbeat_s = 0.0 must be > 0"),
])
def test_bounds_are_enforced_at_their_edges(kw, message):
    with pytest.raises(ValueError, match=f"NetworkConfig: {message}"):
        NetworkConfig.from_flat(**kw)
    edge = {k: (v + 1 if k in ("groups", "grid_cells") else v) for k, v in kw.items()}
    if "ownership_scale" in kw:
        edge["ownership_scale"] = 0.5000001
    if "driven_groups" in kw:
        edge["driven_groups"] = 2
    if "prediction_order" in kw:
        edge["prediction_order"] = 2
    if "heartbeat_s" in kw:
        edge["heartbeat_s"] = 1e-9
    NetworkConfig.from_flat(**edge)
