"""immersim diff: the signals that differ, by how much, and from which step; exit 0 / 1."""
from __future__ import annotations

import pytest

import immersim
from immersim.orchestrator.cli import main

from .conftest import CAMPUS, rewrite_log

CHANGE_STEP, DELTA = 12, 1e-6


@pytest.fixture(scope="module")
def changed(osc_log, tmp_path_factory):
    """The oscillator log with m2.v raised by DELTA from sample CHANGE_STEP on (nothing else changed)."""
    def bump(topic, k, obj):
        if topic == "m2" and k >= CHANGE_STEP:
            obj["v"] += DELTA

    return rewrite_log(osc_log, tmp_path_factory.mktemp("changed") / "changed.mcap", bump)


def test_diff_names_the_one_signal_and_the_step_it_changes_at(osc_log, changed, capsys):
    d = immersim.diff_logs(osc_log, changed)
    assert [s.name for s in d.differing] == ["m2.v"] and not d.only_a and not d.only_b and not d.equal
    s = d.differing[0]
    assert s.first_step == CHANGE_STEP and s.first_t == CHANGE_STEP * 0.033
    assert s.first_values[1] - s.first_values[0] == pytest.approx(DELTA, rel=1e-9)
    assert s.max_abs == pytest.approx(DELTA, rel=1e-6) and s.unit == "m/s"
    assert len(d.signals) == 10  # 5 variables x 2 units
    assert main(["diff", str(osc_log), str(changed)]) == 1
    out = capsys.readouterr().out
    assert f"m2.v [m/s]" in out and f"t = 0.396 s (step {CHANGE_STEP})" in out
    assert out.splitlines()[-1].endswith("10 signals compared (rtol 0, atol 0): 1 differ")
    # within tolerance: equal, exit 0 (absolute, or relative to |b|)
    assert main(["diff", str(osc_log), str(changed), "--atol", "2e-6"]) == 0
    assert capsys.readouterr().out.endswith("10 signals compared (rtol 0, atol 2e-06): equal\n")
    rel = s.max_rel
    assert immersim.diff_logs(osc_log, changed, rtol=rel * 1.01).equal
    assert not immersim.diff_logs(osc_log, changed, rtol=rel * 0.5).equal
    assert main(["diff", str(osc_log), str(changed), "m1.*"]) == 0  # a pattern leaves m2.v out


def test_signals_in_one_log_only_and_bad_tolerance(osc_log, campus_sweep, capsys):
    d = immersim.diff_logs(osc_log, campus_sweep / "000_fcl.mcap", ["m1.x", "m1.v", "plat.stroke[1]"])
    assert d.only_a == ["m1.x", "m1.v"] and d.only_b == ["plat.stroke[1]"] and not d.signals and not d.equal
    assert main(["diff", str(osc_log), str(osc_log), "--rtol", "-1"]) == 2
    assert capsys.readouterr().err == "immersim: error: --rtol must be a finite number >= 0, got -1.0\n"


def test_json_and_ros1_logs_of_one_run_are_equal(tmp_path):
    """campus_drive logged as JSON and as ros1 (immersim.run with overrides): every value equal
    (the values are compared, not the bytes)."""
    json_log = immersim.run(CAMPUS, {"simulation.stop": 0.5, "log.encoding": "json"}, tmp_path / "json.mcap")
    ros1_log = immersim.run(CAMPUS, {"simulation.stop": 0.5}, tmp_path / "ros1.mcap")
    d = immersim.diff_logs(json_log, ros1_log)
    assert d.equal and len(d.signals) > 300, str(d)


@pytest.mark.parametrize("other", ["001_basis_point", "002_honeycomb"])
def test_campus_backends_differ_from_the_collision_onwards(campus_sweep, other):
    """fcl against another collision backend on campus_drive: each net.contact[1] input first
    differs where the coll.pair[1] output feeding it does, one step later when the scenario
    declares that connection delayed (the network reads the previous step); avatar 1's path and
    the platform (which reads the network in the same step) part when the contact flag reaches
    the network; the network is identical before."""
    from immersim.orchestrator.scenario import load_scenario

    lag = {c.dst_var: int(c.delayed) for c in load_scenario(CAMPUS).connections
           if c.src_unit == "coll" and c.src_var.startswith("pair[1].")}
    d = immersim.diff_logs(campus_sweep / "000_fcl.mcap", campus_sweep / f"{other}.mcap")
    first = {s.name: s.first_step for s in d.signals}
    for coll, net in [("in_contact", "active"), ("nx", "nx"), ("ny", "ny"), ("depth", "depth")]:
        if first[f"coll.pair[1].{coll}"] is not None and f"contact[1].{net}" in lag:
            assert first[f"net.contact[1].{net}"] == first[f"coll.pair[1].{coll}"] + lag[f"contact[1].{net}"], coll
    hit = first["net.contact[1].active"]
    assert hit is not None and 3.5 < hit * 0.033 < 3.9
    assert first["net.avatar[1].x"] == first["plat.stroke[1]"] == hit
    net_first = min(s.first_step for s in d.differing if s.name.startswith("net."))
    assert net_first == min(first[f"net.contact[1].{v}"] for v in ("active", "nx", "ny", "depth")
                            if first[f"net.contact[1].{v}"] is not None)


def test_read_log_and_overlay_show_the_same_change(osc_log, changed):
    """read_log of the two logs differs in m2.v only, from CHANGE_STEP on, by DELTA; the overlay
    draws both runs' m2.v, equal before that step."""
    import matplotlib.pyplot as plt
    import numpy as np

    from immersim.orchestrator.plotting import overlay_figures

    a, b = immersim.read_log(osc_log), immersim.read_log(changed)
    differs = (a != b).any()
    assert list(differs[differs].index) == ["m2.v"]
    d = (b["m2.v"] - a["m2.v"]).to_numpy()
    assert np.all(d[:CHANGE_STEP] == 0) and np.allclose(d[CHANGE_STEP:], DELTA, rtol=1e-9, atol=0)
    figs = overlay_figures([osc_log, changed], ["m2.v"])
    try:
        (ax,) = figs[0].axes
        ya, yb = (ln.get_ydata() for ln in ax.get_lines())
        assert [ln.get_label() for ln in ax.get_lines()] == ["osc", "changed"] and ax.get_ylabel() == "[m/s]"
        assert np.array_equal(ya[:CHANGE_STEP], yb[:CHANGE_STEP]) and np.all(ya[CHANGE_STEP:] != yb[CHANGE_STEP:])
    finally:
        plt.close(figs[0])
