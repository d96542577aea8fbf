"""Network configuration: derived sizes and the bounds its checks enforce (exact messages)."""
import pytest

from immersim.models.network.config import NetworkConfig


def test_render_node_count_is_groups_times_nodes_per_group():
    assert NetworkConfig(groups=3, render_nodes=4).n_render == 12
    assert NetworkConfig(groups=1, render_nodes=1).n_render == 1


@pytest.mark.parametrize("kw, message", [
    (dict(groups=0), "groups = 0 must be >= 1"),
    (dict(grid_cells=0), "grid_cells = 0 must be >= 1"),
    (dict(ownership_scale=0.5), r"ownership_scale = 0.5 must be > 0.5 \(eq. 3-12\)"),
    (dict(groups=2, driven_groups=3), r"driven_groups = 3 must be in \[0, groups\]"),
    (dict(prediction_order=3), "prediction_order = 3 must be 0, 1 or 2"),
])
def test_bounds_are_enforced_at_their_edges(kw, message):
    with pytest.raises(ValueError, match=f"NetworkConfig: {message}"):
        NetworkConfig(**kw)
    edge = {k: (v + 1 if k in ("groups", "grid_cells") else v) for k, v in kw.items()}
    if "ownership_scale" in kw:
        edge["ownership_scale"] = 0.5000001
    if "driven_groups" in kw:
        edge["driven_groups"] = 2
    if "prediction_order" in kw:
        edge["prediction_order"] = 2
    NetworkConfig(**edge)
