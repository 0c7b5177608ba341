"""report.html: the interactive report, one self-contained file (plotly, its plotly.js inlined;
no network).  The summary of report.md, then per run an x–y path and every channel: recording,
nominal and updated replay, and below them the residuals with the noise band (±3 noise floors
widened by the replay's own uncertainty), the samples outside the band marked, the windows of
significant mismatch shaded and the re-anchoring edges (a new replay window) as dotted lines."""
from __future__ import annotations

import html
import json
from typing import Any

import numpy as np

from host_tools.analyzer.report.sections import Analysis
from host_tools.analyzer.report.series import BAND_K, Series

# a series longer than this is shown decimated (every k-th sample; series/<run>.csv has all)
MAX_POINTS = 5000

COLORS = {"recording": "#222222", "nominal": "#d62728", "updated": "#1f77b4",
          "band": "rgba(128,128,128,0.25)", "window": "rgba(255,165,0,0.22)",
          "outside": "#ff7f0e", "anchor": "#7f7f7f"}


def _dec(s: Series) -> np.ndarray:
    n = s.t.size
    return np.arange(n) if n <= MAX_POINTS else np.arange(0, n, int(np.ceil(n / MAX_POINTS)))


def _l(a: np.ndarray, idx: np.ndarray) -> list[float | None]:
    return [None if not np.isfinite(v) else float(v) for v in np.asarray(a)[idx]]


def channel_figure(s: Series) -> dict[str, Any]:
    """A plotly figure (as a dict) of one channel: values above, residuals below."""
    idx = _dec(s)
    t = _l(s.t, idx)
    kind = "closed loop" if s.replay == "closed_loop" else "simulation"
    tr: list[dict[str, Any]] = [{"type": "scatter", "mode": "markers", "x": t, "y": _l(s.rec, idx),
           "name": "recording", "marker": {"size": 3, "color": COLORS["recording"]},
           "xaxis": "x", "yaxis": "y"},
          {"type": "scatter", "mode": "lines", "x": t, "y": _l(s.nominal, idx),
           "name": f"nominal {kind}", "line": {"color": COLORS["nominal"], "width": 1.2},
           "xaxis": "x", "yaxis": "y"}]
    if s.updated is not None:
        tr.append({"type": "scatter", "mode": "lines", "x": t, "y": _l(s.updated, idx),
                   "name": f"updated {kind}", "line": {"color": COLORS["updated"], "width": 1.2},
                   "xaxis": "x", "yaxis": "y"})
    band = _l(s.band, idx)
    tr += [{"type": "scatter", "mode": "lines", "x": t, "y": band, "line": {"width": 0},
            "hoverinfo": "skip", "showlegend": False, "xaxis": "x", "yaxis": "y2"},
           {"type": "scatter", "mode": "lines", "x": t, "y": [-b if b is not None else None
                                                              for b in band],
            "fill": "tonexty", "fillcolor": COLORS["band"], "line": {"width": 0},
            "name": f"noise band (±{BAND_K:g} floors)", "xaxis": "x", "yaxis": "y2"},
           {"type": "scatter", "mode": "lines", "x": t, "y": _l(s.resid_nominal, idx),
            "name": "nominal residual", "line": {"color": COLORS["nominal"], "width": 1},
            "xaxis": "x", "yaxis": "y2"}]
    if s.resid_updated is not None:
        tr.append({"type": "scatter", "mode": "lines", "x": t, "y": _l(s.resid_updated, idx),
                   "name": "updated residual", "line": {"color": COLORS["updated"], "width": 1},
                   "xaxis": "x", "yaxis": "y2"})
    out = s.outside_band()[idx]
    if out.any():
        tr.append({"type": "scatter", "mode": "markers",
                   "x": [v for v, o in zip(t, out) if o],
                   "y": [v for v, o in zip(_l(s.resid_nominal, idx), out) if o],
                   "name": "nominal residual outside the band",
                   "marker": {"size": 4, "color": COLORS["outside"]},
                   "xaxis": "x", "yaxis": "y2"})
    shapes: list[dict[str, Any]] = []
    for a, b in s.windows:
        for yref in ("y domain", "y2 domain"):
            shapes.append({"type": "rect", "xref": "x", "yref": yref, "x0": a, "x1": b,
                           "y0": 0, "y1": 1, "fillcolor": COLORS["window"], "line": {"width": 0},
                           "layer": "below"})
    for e in s.anchor_edges:
        shapes.append({"type": "line", "xref": "x", "yref": "paper", "x0": e, "x1": e,
                       "y0": 0, "y1": 1, "line": {"color": COLORS["anchor"], "width": 1,
                                                  "dash": "dot"}})
    title = (f"{s.run}: {s.channel} [{s.unit}] ({len(s.windows)} mismatch window(s) shaded; "
             f"{len(s.anchor_edges)} re-anchoring edge(s) dotted)")
    layout = {"title": {"text": html.escape(title), "font": {"size": 13}}, "height": 430,
              "margin": {"l": 60, "r": 20, "t": 40, "b": 40},
              "xaxis": {"title": {"text": "t [s]"}, "anchor": "y2"},
              "yaxis": {"domain": [0.42, 1.0], "title": {"text": html.escape(s.unit)}},
              "yaxis2": {"domain": [0.0, 0.36], "title": {"text": "residual"}},
              "shapes": shapes, "legend": {"font": {"size": 10}, "traceorder": "normal"}}
    return {"data": tr, "layout": layout}


def path_figure(run: str, series: list[Series]) -> dict[str, Any] | None:
    """The x–y path of a run: the recording (ground truth, else the odometry) with the nominal
    and updated replays."""
    by = {s.channel: s for s in series}
    for xc, yc, what in (("x_m", "y_m", "ground truth"), ("x_odo_m", "y_odo_m", "odometry")):
        if xc in by and yc in by and by[xc].t.size == by[yc].t.size:
            break
    else:
        return None
    x, y = by[xc], by[yc]
    idx = _dec(x)
    tr = [{"type": "scatter", "mode": "lines+markers", "x": _l(x.rec, idx), "y": _l(y.rec, idx),
           "name": f"recording ({what})", "marker": {"size": 2},
           "line": {"color": COLORS["recording"], "width": 1}},
          {"type": "scatter", "mode": "lines", "x": _l(x.nominal, idx), "y": _l(y.nominal, idx),
           "name": "nominal simulation", "line": {"color": COLORS["nominal"], "width": 1.2}}]
    if x.updated is not None and y.updated is not None:
        tr.append({"type": "scatter", "mode": "lines", "x": _l(x.updated, idx),
                   "y": _l(y.updated, idx), "name": "updated simulation",
                   "line": {"color": COLORS["updated"], "width": 1.2}})
    layout = {"title": {"text": html.escape(f"{run}: x–y path ({what}; a long run's replay "
                                            "restarts at each re-anchoring edge)"),
                        "font": {"size": 13}},
              "height": 480, "margin": {"l": 60, "r": 20, "t": 40, "b": 40},
              "xaxis": {"title": {"text": "x [m]"}},
              "yaxis": {"title": {"text": "y [m]"}, "scaleanchor": "x", "scaleratio": 1}}
    return {"data": tr, "layout": layout}


def _md_to_html(lines: list[str]) -> str:
    """The few markdown forms the summary uses (headings, bullets, bold, code) as HTML."""
    import re
    out, in_list = [], False
    for ln in lines:
        e = html.escape(ln)
        e = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", e)
        e = re.sub(r"`(.+?)`", r"<code>\1</code>", e)
        e = re.sub(r"\[(.+?)\]\((.+?)\)", r'<a href="\2">\1</a>', e)
        if ln.startswith("  - "):      # a nested bullet: an item of the last item's list
            out.append(f"<ul><li>{e[4:]}</li></ul>")
            continue
        if ln.startswith("- "):
            if not in_list:
                out.append("<ul>")
                in_list = True
            out.append(f"<li>{e[2:]}</li>")
            continue
        if in_list:
            out.append("</ul>")
            in_list = False
        if ln.startswith("## "):
            out.append(f"<h2>{e[3:]}</h2>")
        elif ln.startswith("# "):
            out.append(f"<h1>{e[2:]}</h1>")
        elif ln.strip():
            out.append(f"<p>{e}</p>")
    if in_list:
        out.append("</ul>")
    return "\n".join(out)


def report_html(an: Analysis, summary_md: list[str], runs: list[tuple[int, list[Series]]]
                ) -> str:
    """The whole page."""
    from plotly.offline import get_plotlyjs

    figs: list[tuple[str, dict[str, Any]]] = []
    body = [_md_to_html(summary_md), "<h2>Runs and channels</h2>",
            "<p>Per run: the x–y path, then every channel. Upper panel: recording (dots), "
            "nominal and updated replay. Lower panel: residuals (recording − replay) with the "
            f"noise band (±{BAND_K:g} noise floors, widened by the replay's own uncertainty); "
            "orange dots: nominal residual outside the band; shaded: windows of significant "
            "mismatch; dotted lines: re-anchoring edges (a long run is replayed in windows "
            "restarted from the recording). All samples: <code>series/&lt;run&gt;.csv</code>."
            "</p>"]
    for i, series in runs:
        name = an.preps[i].name
        body.append(f"<h3 id=\"run-{i}\">{html.escape(name)}</h3>")
        pf = path_figure(name, series)
        if pf is not None:
            figs.append((f"fig-{i}-path", pf))
            body.append(f"<div id=\"fig-{i}-path\" class=\"fig\"></div>")
        for k, s in enumerate(series):
            fid = f"fig-{i}-{k}"
            figs.append((fid, channel_figure(s)))
            body.append(f"<div id=\"{fid}\" class=\"fig\"></div>")
    data = json.dumps({fid: f for fid, f in figs}, allow_nan=False, separators=(",", ":"))
    # "</" cannot end the script element early inside JSON strings
    data = data.replace("</", "<\\/")
    return "\n".join([
        "<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\">",
        "<title>Mismatch report</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em}"
        "code{background:#f3f3f3;padding:0 .2em}.fig{margin:0 0 1.5em 0}</style>",
        f"<script type=\"text/javascript\">{get_plotlyjs()}</script>",
        "</head><body>", *body,
        f"<script type=\"application/json\" id=\"figs\">{data}</script>",
        "<script type=\"text/javascript\">"
        "const F=JSON.parse(document.getElementById('figs').textContent);"
        "for(const id in F){Plotly.newPlot(id,F[id].data,F[id].layout,"
        "{responsive:true,displaylogo:false});}</script>",
        "</body></html>", ""])
