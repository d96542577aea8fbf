"""Connections declared ``delayed`` under Gauss-Seidel: the destination reads the source's
previous step (as Jacobi), in one process and with units in workers."""
import logging

import numpy as np
import pytest

from immersim.orchestrator.errors import ScenarioError
from immersim.orchestrator.execution import run_scenario
from immersim.orchestrator.scenario import load_scenario

from .helpers import oscillator_scenario
from .test_remote import _same_logs


def _delayed(text: str, *dsts: str) -> str:
    for dst in dsts:
        text = text.replace(f'to = "{dst}"', f'to = "{dst}"\ndelayed = true')
    return text


@pytest.mark.parametrize("where", [None, {"m2:process": 1}, {"m1:process": 1}])
def test_gauss_seidel_with_every_connection_delayed_is_jacobi(tmp_path, test_fmus, where, caplog):
    """m1 <-> m2 both declared delayed: no order between them, each reads the other's previous
    step (m2's inputs are gathered before m1 steps, though m1 steps first): the Jacobi log, bit
    for bit, also with either unit in a worker; a declared delay is not warned about."""
    fmu = test_fmus["oscillator"]
    jac = oscillator_scenario(tmp_path, fmu, step=0.033, stop=2.0, algorithm="jacobi",
                              extrapolation="linear", name="j.toml")
    gs = oscillator_scenario(tmp_path, fmu, step=0.033, stop=2.0, algorithm="gauss-seidel",
                             extrapolation="linear", name="g.toml")
    gs.write_text(_delayed(gs.read_text(), "m2.x_other", "m1.x_other"))
    run_scenario(jac, tmp_path / "j.mcap")
    with caplog.at_level(logging.WARNING):
        res = run_scenario(gs, tmp_path / "g.mcap", overrides=where)
    assert not [r for r in caplog.records if "cycle broken" in r.getMessage()]
    assert sorted(res.delayed_connections) == ["m1.x -> m2.x_other", "m2.x -> m1.x_other"]
    assert _same_logs(tmp_path / "j.mcap", tmp_path / "g.mcap") >= 8


def test_one_declared_delay_reverses_the_order(tmp_path, test_fmus):
    """Only m1 -> m2 declared delayed: m2 -> m1 alone orders the units (m2 first), which is
    Gauss-Seidel over the file order m2, m1 (where the cycle breaks at m1 -> m2 by itself)."""
    fmu = test_fmus["oscillator"]
    a = oscillator_scenario(tmp_path, fmu, step=0.033, stop=2.0, algorithm="gauss-seidel", name="a.toml")
    a.write_text(_delayed(a.read_text(), "m2.x_other"))
    text = oscillator_scenario(tmp_path, fmu, step=0.033, stop=2.0, algorithm="gauss-seidel", name="b.toml").read_text()
    head, units, conns = text.split("[[units]]", 1)[0], text.split("[[units]]")[1:], ""
    m1, m2 = ("[[units]]" + u for u in units)
    m2, conns = m2.split("[[connections]]", 1)
    b = tmp_path / "b.toml"
    b.write_text(head + m2 + m1.split("[[connections]]")[0] + "[[connections]]" + conns)
    ra, rb = run_scenario(a, tmp_path / "a.mcap"), run_scenario(b, tmp_path / "b.mcap")
    assert ra.delayed_connections == rb.delayed_connections == ["m1.x -> m2.x_other"]
    assert _same_logs(tmp_path / "a.mcap", tmp_path / "b.mcap") >= 8


def test_a_unit_reading_fresh_and_delayed_values_of_earlier_units_is_refused(tmp_path, test_fmus, built_fmus):
    """plat reads m1 fresh and m2 through a declared delay, both stepped before it: refused
    with the two connections named (its inputs cannot be gathered at one instant)."""
    osc = test_fmus["oscillator"]
    p = tmp_path / "mixed.toml"
    p.write_text(f'''
[simulation]
stop = 0.1
[[units]]
name = "m1"
fmu = "{osc}"
[[units]]
name = "m2"
fmu = "{osc}"
[[units]]
name = "plat"
fmu = "{built_fmus['platform']}"
[[connections]]
from = "m1.x"
to = "plat.cue.f_x"
[[connections]]
from = "m2.x"
to = "plat.cue.f_y"
delayed = true
''')
    # refused at load (exit 2), before any step and before the log is opened
    with pytest.raises(ScenarioError, match=r"mixed.toml: connection m2.x -> plat.cue.f_y is delayed but plat also "
                                            r"reads m1.x -> plat.cue.f_x in the same step"):
        run_scenario(p, tmp_path / "mixed.mcap")
    assert not (tmp_path / "mixed.mcap").exists()


def test_delayed_must_be_a_boolean(tmp_path, test_fmus):
    scn = oscillator_scenario(tmp_path, test_fmus["oscillator"])
    scn.write_text(scn.read_text().replace('to = "m2.x_other"', 'to = "m2.x_other"\ndelayed = 1'))
    with pytest.raises(ScenarioError, match=r"osc.toml: connections\[0\].delayed: expected true or false, got 1"):
        load_scenario(scn)
