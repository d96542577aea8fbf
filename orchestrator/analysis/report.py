"""``immersim report``: one self-contained HTML page comparing runs.

The page holds the runs' table (grid values and metrics, units in the headers; a click on a
header sorts by that column), one bar chart per metric (y axis with its unit) and the chosen
signals of every run overlaid, one panel per signal (plotly: zoom, pan, hover values; a click
on a run in the legend hides it in every panel). Everything is inline: plotly.js is embedded
gzip-compressed (a third of its size) and unpacked by the browser's ``DecompressionStream``,
so the page opens from disk without a server or network.
"""
from __future__ import annotations

import base64
import gzip
import html
import json
import math
from functools import lru_cache
from pathlib import Path
from typing import List, Optional, Sequence

from ..mcapio import read_info
from .runs import Run, RunSet, collect_runs, run_series

#: at most this many overlaid signal panels (more: an error asking for narrower patterns)
MAX_SIGNALS = 24
_DASHES = ("solid", "dash", "dot", "dashdot")

_CSS = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 1.6em; }
table { border-collapse: collapse; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; white-space: nowrap; }
td.text, th.text { text-align: left; }
th { background: #f0f0f0; cursor: pointer; user-select: none; }
th[aria-sort=ascending]::after { content: " \\25B2"; } th[aria-sort=descending]::after { content: " \\25BC"; }
#status { color: #a00; }
"""

#: unpacks plotly.js, then draws every figure of the JSON block ``figures``; sorts the table
_JS = """
function sortTable(th) {
  const table = th.closest("table"), col = th.cellIndex, body = table.tBodies[0];
  const dir = th.getAttribute("aria-sort") === "ascending" ? "descending" : "ascending";
  for (const other of th.parentNode.children) other.removeAttribute("aria-sort");
  th.setAttribute("aria-sort", dir);
  const key = td => { const v = td.dataset.v; return v !== undefined && v !== "" && !isNaN(+v) ? +v : td.textContent; };
  const rows = Array.from(body.rows);
  rows.sort((a, b) => {
    const x = key(a.cells[col]), y = key(b.cells[col]);
    const c = typeof x === "number" && typeof y === "number" ? x - y : String(x).localeCompare(String(y));
    return dir === "ascending" ? c : -c;
  });
  rows.forEach(r => body.appendChild(r));
}
document.querySelectorAll("table.sortable th").forEach(th => th.addEventListener("click", () => sortTable(th)));
async function loadPlotly() {
  if (typeof DecompressionStream === "undefined") throw new Error("this browser cannot unpack the embedded plotly.js (no DecompressionStream)");
  const packed = await fetch("data:application/gzip;base64," + document.getElementById("plotly-gz").textContent.trim());
  const code = await new Response(packed.body.pipeThrough(new DecompressionStream("gzip"))).text();
  const s = document.createElement("script"); s.textContent = code; document.head.appendChild(s);
}
(async () => {
  try {
    await loadPlotly();
    const figs = JSON.parse(document.getElementById("figures").textContent);
    for (const [id, fig] of Object.entries(figs)) {
      await Plotly.newPlot(id, fig.data, fig.layout, {responsive: true, displaylogo: false});
    }
    document.body.dataset.rendered = Object.keys(figs).length;
  } catch (e) {
    document.getElementById("status").textContent = "The plots could not be drawn: " + e;
    throw e;
  }
})();
"""


@lru_cache(maxsize=1)
def _plotly_gz_b64() -> str:
    from plotly.offline import get_plotlyjs

    return base64.b64encode(gzip.compress(get_plotlyjs().encode(), 9, mtime=0)).decode()


def _fmt(v: str) -> str:
    try:
        x = float(v)
    except ValueError:
        return v
    return "" if math.isnan(x) else f"{x:.6g}"


def _table(runs: RunSet) -> tuple:
    """(header cells, rows of (display, sort value)) of the runs' table."""
    if any(r.row for r in runs.runs):
        point_keys = list(dict.fromkeys(k for r in runs.runs for k in r.point))
        metric_cols = list(runs.metrics)
        cols = ["id"] + point_keys + ["status", "steps", "t_end_s", "wall_time_s"] + metric_cols
        heads = cols[:len(cols) - len(metric_cols)] + [
            f"{m} [{u}]" if (u := runs.metric_unit(m)) else m for m in metric_cols]
        rows = [[(_fmt(r.row.get(c, r.point.get(c, ""))), r.row.get(c, "")) for c in cols] for r in runs.runs]
        return heads, rows
    heads = ["log", "status", "steps", "t_end [s]", "size [MB]"]
    rows = []
    for r in runs.runs:
        info = read_info(r.path)
        meta = info.metadata.get("run", {})
        t_end = max((c.last_ns for c in info.channels.values()), default=0) / 1e9
        size = r.path.stat().st_size / 1e6
        rows.append([(r.label, r.label), (meta.get("status", "truncated" if info.truncated else ""), ""),
                     (meta.get("steps_done", ""), meta.get("steps_done", "")), (f"{t_end:.6g}", repr(t_end)),
                     (f"{size:.3g}", repr(size))])
    return heads, rows


def _table_html(heads: List[str], rows: List[list]) -> str:
    def cls(v: str) -> str:
        try:
            float(v)
            return ""
        except ValueError:
            return ' class="text"'

    first = rows[0] if rows else []
    th = "".join(f"<th{cls(str(first[i][1]) if first else '')}>{html.escape(h)}</th>" for i, h in enumerate(heads))
    body = "".join("<tr>" + "".join(f'<td{cls(str(v))} data-v="{html.escape(str(v))}">{html.escape(str(d))}</td>'
                                    for d, v in row) + "</tr>" for row in rows)
    return f'<table id="runs" class="sortable"><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>'


def _styles(runs: RunSet, color_by: Optional[str]) -> List[dict]:
    from plotly.colors import qualitative

    palette, seen, out = qualitative.Plotly, {}, []
    for g in runs.colour_groups(color_by):
        out.append({"color": palette[g % len(palette)], "dash": _DASHES[seen.get(g, 0) % len(_DASHES)]})
        seen[g] = seen.get(g, 0) + 1
    return out


def _metrics_figure(runs: RunSet, styles: List[dict]):
    """One figure, a bar chart per metric (3 a row), each y axis titled with the metric's unit;
    None without metrics."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    names = list(runs.metrics)
    if not names:
        return None
    cols = min(3, len(names))
    rows = -(-len(names) // cols)
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=names, horizontal_spacing=0.09,
                        vertical_spacing=min(0.5 / rows, 0.12))
    labels = [r.label for r in runs.runs]
    for i, m in enumerate(names):
        unit = runs.metric_unit(m)
        ys = [float(r.row.get(m) or "nan") for r in runs.runs]
        row, col = i // cols + 1, i % cols + 1
        fig.add_trace(go.Bar(x=labels, y=ys, marker_color=[s["color"] for s in styles], showlegend=False,
                             hovertemplate="%{x}<br>" + m + " = %{y:.6g}" + (f" {unit}" if unit else "")
                                           + "<extra></extra>"), row=row, col=col)
        fig.update_yaxes(title_text=f"[{unit}]" if unit else "", row=row, col=col)
        fig.update_xaxes(showticklabels=len(labels) <= 6, row=row, col=col)
    fig.update_layout(height=260 * rows + 60, template="plotly_white", margin=dict(l=60, r=20, t=40, b=40))
    return fig


def _signal_patterns(runs: RunSet, signals: Optional[Sequence[str]]) -> List[str]:
    if signals:
        return list(signals)
    used = [d["signal"] for d in runs.metrics.values() if d.get("signal")]
    return list(dict.fromkeys(used)) or ["*"]


def _trace_figure(runs: RunSet, patterns: List[str], styles: List[dict]):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    from ..plotting import TooManySignals

    series = run_series(runs, patterns, skip_missing=True)
    if len(series) > MAX_SIGNALS:
        raise TooManySignals(f"{len(series)} signals match {' '.join(patterns)}: a report overlays at most "
                             f"{MAX_SIGNALS}; choose them with --signals")
    names = list(series)
    fig = make_subplots(rows=len(names), cols=1, shared_xaxes=True, vertical_spacing=min(0.04, 0.3 / len(names)),
                        subplot_titles=names)
    for k, name in enumerate(names, 1):
        unit = ""
        for i, (t, y, unit, kind) in series[name].items():
            run: Run = runs.runs[i]
            vals = y.astype(float) if kind in ("boolean", "integer") else (y.astype(str) if kind == "string" else y)
            fig.add_trace(go.Scatter(x=t, y=vals, mode="lines", name=run.label, legendgroup=run.label,
                                     showlegend=k == 1, line=dict(width=1.3, **styles[i]),
                                     line_shape="hv" if kind != "number" else "linear",
                                     hovertemplate=f"{run.label}<br>t = %{{x:.6g}} s<br>{name} = %{{y:.9g}}"
                                                   + (f" {unit}" if unit else "") + "<extra></extra>"),
                          row=k, col=1)
        fig.update_yaxes(title_text=f"[{unit}]" if unit else "", row=k, col=1)
        if {s[3] for s in series[name].values()} == {"boolean"}:
            fig.update_yaxes(tickvals=[0, 1], ticktext=["False", "True"], range=[-0.1, 1.1], row=k, col=1)
    fig.update_xaxes(title_text="simulation time [s]", row=len(names), col=1)
    fig.update_layout(height=170 * len(names) + 120, template="plotly_white", hovermode="x unified",
                      legend=dict(orientation="h", y=1.0, yanchor="bottom"), margin=dict(l=70, r=20, t=60, b=40))
    return fig, names


def write_report(sources: Sequence[Path | str] | Path | str, output: Path | str,
                 signals: Optional[Sequence[str]] = None, color_by: Optional[str] = None) -> Path:
    """Write the HTML report of the runs in ``sources`` to ``output``.

    Parameters
    ----------
    sources : path-like or sequence of them
        Sweep output folders (``summary.csv``, ``sweep.json`` and the runs' logs) and MCAP logs.
    output : path-like
        The HTML file.
    signals : sequence of str, optional
        Globs over ``unit.variable`` to overlay; default: the signals the sweep's metrics
        reduce, or every signal of plain logs (at most :data:`MAX_SIGNALS` panels).
    color_by : str, optional
        Grid key giving the colours of a sweep's runs.

    Returns
    -------
    Path
        ``output``.
    """
    import plotly.io as pio

    runs = collect_runs([sources] if isinstance(sources, (str, Path)) else sources)
    styles = _styles(runs, color_by)
    heads, rows = _table(runs)
    metrics = _metrics_figure(runs, styles)
    figs = {"metrics": metrics} if metrics is not None else {}
    traces, names = _trace_figure(runs, _signal_patterns(runs, signals), styles)
    figs["traces"] = traces
    payload = "{" + ",".join(f"{json.dumps(k)}:{pio.to_json(f, validate=False)}" for k, f in figs.items()) + "}"
    payload = payload.replace("</", "<\\/")  # no "</script>" inside the JSON block
    title = " + ".join(p.name for p in runs.sources)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>immersim report: {html.escape(title)}</title>
<style>{_CSS}</style></head>
<body>
<h1>immersim report: {html.escape(title)}</h1>
<p>{len(runs.runs)} runs from {html.escape(", ".join(str(p) for p in runs.sources))}.
Click a column header to sort; drag in a plot to zoom, double-click to reset; click a run in the legend to hide it.</p>
<p id="status"></p>
<h2>Runs</h2>
{_table_html(heads, rows)}
{'<h2>Metrics</h2><div id="metrics"></div>' if metrics is not None else ""}
<h2>Signals</h2>
<p>{len(names)} signals: {html.escape(", ".join(names))}</p>
<div id="traces"></div>
<script type="application/octet-stream" id="plotly-gz">{_plotly_gz_b64()}</script>
<script type="application/json" id="figures">{payload}</script>
<script>{_JS}</script>
</body></html>
"""
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(page, encoding="utf-8")
    return output
