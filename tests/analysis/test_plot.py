"""immersim plot over several runs: a panel per signal, a colour per run, every signal drawn."""
from __future__ import annotations

import matplotlib
import numpy as np
import orjson
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from immersim.orchestrator.cli import main  # noqa: E402
from immersim.orchestrator.plotting import TooManySignals, overlay_figures, plot_signals  # noqa: E402

from .conftest import rewrite_log  # noqa: E402


def _panels(figs):
    return [ax for f in figs for ax in f.axes]


def test_sweep_overlay_one_panel_per_signal_one_colour_per_backend(campus_sweep):
    figs = overlay_figures(campus_sweep, ["plat.stroke[1]", "coll.pair[1].in_contact", "net.avatar[1].jolt"])
    try:
        panels = _panels(figs)
        assert [ax.get_title(loc="left") for ax in panels] == \
            ["net.avatar[1].jolt", "coll.pair[1].in_contact", "plat.stroke[1]"]
        for ax in panels:
            lines = ax.get_lines()
            assert [ln.get_label() for ln in lines] == \
                ["coll.backend = fcl", "coll.backend = basis_point", "coll.backend = honeycomb"]
            assert len({ln.get_color() for ln in lines}) == 3
            assert all(len(ln.get_xdata()) == 123 for ln in lines)  # time aligned: every sample of 4 s
        jolt, contact, stroke = panels
        assert jolt.get_ylabel() == "[m/s]" and stroke.get_ylabel() == "[m]"
        assert [t.get_text() for t in contact.get_yticklabels()] == ["False", "True"]
        # a Boolean is a step held from its sample: drawstyle steps-post
        assert contact.get_lines()[0].get_drawstyle() == "steps-post" and stroke.get_lines()[0].get_drawstyle() == "default"
        # the drawn peaks are the sweep's jolt_max metric of each run
        from immersim.orchestrator.sweep import read_summary

        peaks = [float(r["jolt_max"]) for r in read_summary(campus_sweep / "summary.csv")]
        assert [np.max(ln.get_ydata()) for ln in jolt.get_lines()] == peaks and min(peaks) > 5
    finally:
        for f in figs:
            plt.close(f)


def test_logs_given_one_by_one_and_pages_instead_of_a_cut(campus_sweep, tmp_path, capsys):
    logs = [str(campus_sweep / f"{r}.mcap") for r in ("000_fcl", "002_honeycomb")]
    assert main(["plot", *logs, "plat.*", "-o", str(tmp_path / "p.png")]) == 0
    pages = capsys.readouterr().out.split()
    # 48 platform signals at 12 panels a page: 4 pages, every signal drawn once
    files = ("p.png", "p-2.png", "p-3.png", "p-4.png")
    assert pages == [str(tmp_path / n) for n in files]
    assert all((tmp_path / n).stat().st_size > 10_000 for n in files)
    figs = overlay_figures(logs, ["plat.*"])
    names = [ax.get_title(loc="left") for ax in _panels(figs)]
    assert len(names) == len(set(names)) == 48
    assert {ln.get_label() for ax in _panels(figs) for ln in ax.get_lines()} == {"000_fcl", "002_honeycomb"}
    for f in figs:
        plt.close(f)
    with pytest.raises(TooManySignals, match=r"^48 signals match plat\.\*: more than 20 \(--max-signals\); "
                                             r"narrow the patterns$"):
        plot_signals(logs, ["plat.*"], tmp_path / "q.png", max_signals=20)
    assert main(["plot", "plat.*", "-o", str(tmp_path / "q.png")]) == 2
    assert capsys.readouterr().err == \
        "immersim: error: 'plat.*' is not an MCAP file or a sweep folder: give the logs before the patterns\n"


def test_string_signals_are_steps_with_their_values(osc_log, tmp_path):
    """A String output (JSON channel) is drawn as steps between its values' levels."""
    def add_mode(topic, k, obj):
        if topic == "m1":
            obj["mode"] = "hold" if k < 10 else "track"

    def add_schema(path, out):
        from mcap.reader import make_reader
        from mcap.writer import Writer

        with open(path, "rb") as fin, open(out, "wb") as fout:
            w = Writer(fout)
            w.start()
            ids = {}
            for schema, channel, msg in make_reader(fin).iter_messages():
                if channel.id not in ids:
                    data = schema.data
                    if channel.topic == "m1":
                        js = orjson.loads(data)
                        js["properties"]["mode"] = {"type": "string", "causality": "output"}
                        data = orjson.dumps(js)
                    sid = w.register_schema(schema.name, schema.encoding, data)
                    ids[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sid,
                                                         channel.metadata)
                w.add_message(ids[channel.id], msg.log_time, msg.data, msg.publish_time)
            w.finish()
        return out

    log = add_schema(rewrite_log(osc_log, tmp_path / "a.mcap", add_mode), tmp_path / "mode.mcap")
    figs = overlay_figures(log, ["m1.mode", "m1.at_rest"])
    try:
        rest, mode = _panels(figs)  # in log order
        assert [t.get_text() for t in mode.get_yticklabels()] == ["hold", "track"]
        line = mode.get_lines()[0]
        assert line.get_drawstyle() == "steps-post"
        assert list(line.get_ydata()) == [0] * 10 + [1] * 21
        assert [t.get_text() for t in rest.get_yticklabels()] == ["False", "True"]
    finally:
        for f in figs:
            plt.close(f)


def test_colour_by_a_grid_key(campus_sweep):
    """--color-by a key all runs share: one colour, told apart by line style; an unknown key is
    an error naming the sweep's keys."""
    from immersim.orchestrator.analysis.runs import RunsError

    figs = overlay_figures(campus_sweep, ["plat.stroke[1]"], color_by="simulation.stop")
    try:
        lines = figs[0].axes[0].get_lines()
        assert len({ln.get_color() for ln in lines}) == 1
        assert [ln.get_linestyle() for ln in lines] == ["-", "--", ":"]
    finally:
        plt.close(figs[0])
    with pytest.raises(RunsError, match=r"^--color-by 'coll\.nope': not a grid key of the sweep \(keys: coll\.backend\)$"):
        overlay_figures(campus_sweep, ["plat.stroke[1]"], color_by="coll.nope")
