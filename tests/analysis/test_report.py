"""immersim report: one self-contained HTML page, checked in headless Chromium (Debian's):
no script error, the runs' table sortable, every plot drawn."""
from __future__ import annotations

from pathlib import Path

import pytest

from immersim.orchestrator.analysis.report import write_report
from immersim.orchestrator.cli import main
from immersim.orchestrator.sweep import read_summary

from ..browser import open_page, require_chromium

READY = "document.body && document.body.dataset.rendered"
DOM = {
    "rows": "Array.from(document.querySelectorAll('#runs tbody tr')).map(r => r.cells[0].textContent)",
    "heads": "Array.from(document.querySelectorAll('#runs th')).map(th => th.textContent)",
    "plots": "document.querySelectorAll('.js-plotly-plot').length",
    "svgs": "document.querySelectorAll('.js-plotly-plot .main-svg').length",
    "traces": "document.getElementById('traces').data.length",
    "yaxes": "Object.keys(document.getElementById('traces').layout).filter(k => k.startsWith('yaxis'))"
             ".map(k => document.getElementById('traces').layout[k].title.text)",
    "metric_units": "(() => { const l = document.getElementById('metrics').layout; return Object.keys(l)"
                    ".filter(k => k.startsWith('yaxis')).sort((a, b) => (+a.slice(5) || 1) - (+b.slice(5) || 1))"
                    ".map(k => l[k].title.text); })()",
    "metric_titles": "document.getElementById('metrics').layout.annotations.map(a => a.text)",
    "sorted": "(() => { const th = Array.from(document.querySelectorAll('#runs th'))"
              ".find(t => t.textContent.startsWith('jolt_max')); th.click();"
              " const i = th.cellIndex; return Array.from(document.querySelectorAll('#runs tbody tr'))"
              ".map(r => [r.cells[0].textContent, +r.cells[i].dataset.v]); })()",
    "external": "Array.from(document.querySelectorAll('script[src], link[href]')).length",
}


@pytest.fixture(scope="module")
def report(campus_sweep, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "report.html"
    assert main(["report", str(campus_sweep), "-o", str(out)]) == 0
    return out


def test_report_is_one_self_contained_file(report, campus_sweep):
    """Under 5 MB, no external resource (plotly.js inline), the metrics with their units."""
    text = report.read_text()
    assert report.stat().st_size < 5_000_000
    assert "<script src" not in text and "http://" not in text.split('id="plotly-gz"')[0]
    assert "jolt_max [m/s]" in text and "stroke_max [m]" in text and "contact_1 [1]" in text
    assert "coll_s [s]" in text and "loop_s [s]" in text


def test_report_renders_in_headless_chromium(report, campus_sweep, tmp_path):
    require_chromium()
    run = open_page(report, READY, DOM, screenshot=tmp_path / "report.png")
    assert run.errors == []
    assert run.values["rows"] == ["000_fcl", "001_basis_point", "002_honeycomb"]
    assert run.values["heads"][:3] == ["id", "simulation.stop", "coll.backend"]
    assert "jolt_max [m/s]" in run.values["heads"]
    metrics = [c for c in read_summary(campus_sweep / "summary.csv")[0]
               if c.split(" ")[0] in {"contact_1", "contact_2", "contact_3", "depth_1", "depth_2", "depth_3",
                                      "missile_hit", "jolt_max", "stroke_max", "incons_max", "coll_s", "loop_s"}]
    assert run.values["plots"] == 2 and run.values["svgs"] >= 4  # metrics and traces, drawn
    assert run.values["metric_titles"] == metrics
    units = dict(zip(run.values["metric_titles"], run.values["metric_units"]))
    assert units["jolt_max"] == "[m/s]" and units["coll_s"] == "[s]" and units["stroke_max"] == "[m]"
    assert units["contact_1"] == "[1]" and units["depth_1"] == "[m]" and len(metrics) == 12
    # the metrics' signals overlaid: pair[1..4].in_contact, pair[1..3].depth, avatar[1].jolt, 6 strokes,
    # inconsistency_max
    assert run.values["traces"] == 15 * 3
    # in log order: net.avatar[1].jolt, net.inconsistency_max, pair[1..3].in_contact (a Boolean, no unit) and
    # depth in turn, pair[4].in_contact, plat.stroke[1..6]
    assert run.values["yaxes"] == ["[m/s]", "[m]", "", "[m]", "", "[m]", "", "[m]", ""] + ["[m]"] * 6
    jolts = dict(run.values["sorted"])
    assert [k for k, _ in run.values["sorted"]] == sorted(jolts, key=jolts.get)  # one click: ascending
    assert run.values["external"] == 0
    assert (tmp_path / "report.png").stat().st_size > 50_000


def test_a_script_error_is_caught(tmp_path):
    """The check above can fail: a page whose script throws reports the error."""
    require_chromium()
    page = tmp_path / "bad.html"
    page.write_text("<html><body><script>document.body.dataset.rendered = 1; undefinedFunction();</script>"
                    "</body></html>")
    run = open_page(page, READY)
    assert any("undefinedFunction is not defined" in e for e in run.errors)


def test_report_of_logs_given_one_by_one(campus_sweep, tmp_path, capsys):
    """Plain logs: a table of the logs, the chosen signals overlaid; too many signals is an error."""
    logs = [campus_sweep / "000_fcl.mcap", campus_sweep / "002_honeycomb.mcap"]
    out = write_report(logs, tmp_path / "r.html", signals=["plat.stroke[1]", "net.avatar[1].x"])
    text = out.read_text()
    assert '"name":"000_fcl"' in text and '"name":"002_honeycomb"' in text and "size [MB]" in text
    assert main(["report", *map(str, logs), "-o", str(tmp_path / "s.html")]) == 2
    assert capsys.readouterr().err.startswith("immersim: error: 336 signals match *: a report overlays at most 24;")


def test_without_chromium_ci_fails_instead_of_skipping(monkeypatch):
    from .. import browser

    monkeypatch.setattr(browser, "chromium", lambda: None)
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match=r"chromium is not installed: \.ci/run installs it"):
        require_chromium()
    monkeypatch.setenv("CI", "")
    with pytest.raises(pytest.skip.Exception):
        require_chromium()
