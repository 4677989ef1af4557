"""Plotly figures shared by the reports and `rig plot`: channels on a time axis in
milliseconds, phase bands, event markers, and the page scaffolding that embeds
plotly.js once and records, in ``<body>`` attributes, how many figures drew and
any script error (what the headless-Chromium tests read).

Display units: radians are shown in mrad, metres in mm, strain in microstrain;
the run files and every computation stay in SI.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rig.sensors.display import DISPLAY, scale  # noqa: F401 (re-exported for the report)

PHASE_COLOURS = ("#eeeeee", "#d6e4f5", "#fbe0cc", "#dcefd2", "#fff0bf", "#e7cff4", "#d2f0f0")
MODEL_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2")
# the channels a piano maker looks at first; a page shows at most MAX_CHANNELS of them
PREFERRED = ("hammer_angle", "key_dip", "shank_strain", "force", "whippen_angle", "key_angle",
             "hammer_head_velocity", "jack_angle", "repetition_angle")
MAX_CHANNELS = 6
EVENT_LABELS = {"key_starts": "key starts", "toe_meets_button": "toe meets button",
                "let_off": "let-off",
                "strike": "strike", "string_release": "string release",
                "check": "check", "key_bottom": "key bottom",
                "key_release": "key release"}
FONT = {"family": "sans-serif", "size": 13}


def pick_channels(names: Sequence[str], limit: int = MAX_CHANNELS) -> list[str]:
    """At most ``limit`` channels, the piano maker's first (PREFERRED order), then the rest."""
    first = [c for c in PREFERRED if c in names]
    return (first + [c for c in names if c not in first])[:limit]


def event_label(name: str) -> str:
    return EVENT_LABELS.get(name, name.replace("_", " "))


def stacked(rows: Sequence[str], height_per_row: int = 170, title: str = "") -> Any:
    """A figure with one subplot row per name, sharing the time axis."""
    from plotly.subplots import make_subplots

    n = max(1, len(rows))
    fig = make_subplots(rows=n, cols=1, shared_xaxes=True, vertical_spacing=min(0.06, 0.3 / n))
    fig.update_layout(height=height_per_row * n + 150, margin={"l": 80, "r": 20, "t": 110,
                                                                 "b": 50},
                      title={"text": title, "font": {"size": 15}, "y": 0.995,
                             "yanchor": "top"} if title else None,
                      font=FONT, hovermode="x unified",
                      legend={"orientation": "v", "x": 1.01, "y": 1.0, "xanchor": "left",
                              "font": {"size": 12}},
                      template="plotly_white")
    fig.update_xaxes(title_text="time [ms]", row=n, col=1)
    return fig


def phase_bands(fig: Any, phases: Sequence[tuple[str, float, float]], rows: int,
                t_lo: float | None = None, t_hi: float | None = None) -> None:
    """Shade each phase (times in s) on every row, below the traces. The names are in the
    page's phase key and in the band's hover, never printed over each other."""
    for i, (name, a, b) in enumerate(phases):
        lo = a if t_lo is None else max(a, t_lo)
        hi = b if t_hi is None else min(b, t_hi)
        if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
            continue
        for r in range(1, rows + 1):
            fig.add_vrect(x0=lo * 1e3, x1=hi * 1e3, fillcolor=PHASE_COLOURS[i % len(
                PHASE_COLOURS)], opacity=1.0, layer="below", line_width=0, row=r, col=1,
                name=name, exclude_empty_subplots=False)


def phase_key(phases: Sequence[tuple[str, float, float]]) -> str:
    """The phases as coloured chips with their time spans (HTML)."""
    chips = []
    for i, (name, a, b) in enumerate(phases):
        span = f"{a * 1e3:.1f}-{b * 1e3:.1f} ms" if math.isfinite(a) and math.isfinite(b) \
            else "-"
        colour = PHASE_COLOURS[i % len(PHASE_COLOURS)]
        chips.append(f"<span class='chip' style='background:{colour}'>"
                     f"{html.escape(name)} <small>{span}</small></span>")
    return "<p class='phases'>phases: " + " ".join(chips) + "</p>"


def event_lines(fig: Any, events: Mapping[str, float], rows: int, label: str,
                t_lo: float = -math.inf, t_hi: float = math.inf,
                span: tuple[float, float] | None = None) -> None:
    """Vertical dotted lines at the events (s) on every row; their names above the top row,
    each on the lowest of up to five levels where it does not overlap an earlier name
    (``span``: the axis range in s, to size the labels; default the events' own span)."""
    shown = sorted((t, n) for n, t in events.items() if math.isfinite(t) and t_lo <= t <= t_hi)
    if not shown:
        return
    a, b = span if span is not None else (shown[0][0], shown[-1][0])
    width = max(b - a, 1e-9)
    ends: list[float] = []          # right end of the last label on each level (axis fraction)
    for t, name in shown:
        text = event_label(name)
        x = (t - a) / width
        half = 0.5 * (len(text) * 7.0 + 8) / 1000.0
        level = next((i for i, e in enumerate(ends) if e < x - half), len(ends))
        if level == len(ends):
            ends.append(0.0)
        ends[level] = x + half
        for r in range(1, rows + 1):
            fig.add_vline(x=t * 1e3, line={"color": "#555", "width": 1, "dash": "dot"},
                          row=r, col=1, exclude_empty_subplots=False)
        fig.add_annotation(x=t * 1e3, y=1.0 + 0.12 * level, xref="x", yref="y domain",
                           text=text, showarrow=False, font={"size": 11, "color": "#333"},
                           yanchor="bottom",
                           hovertext=f"{label} {text}: {t * 1e3:.2f} ms")


def event_markers(fig: Any, t: np.ndarray, y: np.ndarray, events: Mapping[str, float],
                  row: int, name: str, colour: str, symbol: str, legend: bool,
                  t_lo: float = -math.inf, t_hi: float = math.inf) -> None:
    """Markers on a curve (t in s, y in display units) at its events, names on hover."""
    xs, ys, texts = [], [], []
    for ev, te in events.items():
        if not (math.isfinite(te) and t_lo <= te <= t_hi) or t.size == 0:
            continue
        i = int(np.clip(np.searchsorted(t, te), 0, t.size - 1))
        if not math.isfinite(float(y[i])):
            continue
        xs.append(te * 1e3)
        ys.append(float(y[i]))
        texts.append(f"{name}: {event_label(ev)} {te * 1e3:.2f} ms")
    if not xs:
        return
    import plotly.graph_objects as go

    fig.add_trace(go.Scatter(x=xs, y=ys, mode="markers", name=f"{name} events",
                             legendgroup=f"{name} events", showlegend=legend,
                             marker={"symbol": symbol, "size": 10, "color": colour,
                                     "line": {"width": 1, "color": "black"}},
                             hovertext=texts, hoverinfo="text"), row=row, col=1)


def line(fig: Any, t: np.ndarray, y: np.ndarray, row: int, name: str, colour: str,
         legend: bool, width: float = 1.5, dash: str | None = None) -> None:
    import plotly.graph_objects as go

    fig.add_trace(go.Scatter(x=t * 1e3, y=y, mode="lines", name=name, legendgroup=name,
                               showlegend=legend,
                               line={"color": colour, "width": width, "dash": dash}),
                  row=row, col=1)


def window(t: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (t >= lo) & (t <= hi)


def figure_html(fig: Any, div_id: str) -> str:
    """A figure as a <div> and its script (plotly.js is in the page head), counted on draw."""
    import plotly.io as pio

    return pio.to_html(fig, include_plotlyjs=False, full_html=False, div_id=div_id,
                       config={"displaylogo": False, "responsive": True},
                       post_script=_COUNT)


_COUNT = ("window.rigDrawn = (window.rigDrawn || 0) + 1; "
          "document.body.setAttribute('data-plots-drawn', String(window.rigDrawn));")
_ERRORS = """<script>
window.rigErrors = [];
window.addEventListener('error', function (e) {
  window.rigErrors.push(String(e.message || e));
  document.documentElement.setAttribute('data-errors', window.rigErrors.join(' | '));
});
</script>"""
_STYLE = """<style>body{font-family:sans-serif;max-width:1200px;margin:1em auto;color:#222;
padding:0 1em}table{border-collapse:collapse;font-size:13px;margin:.5em 0}td,th{border:1px
solid #ccc;padding:2px 8px;text-align:right}td:first-child,th:first-child{text-align:left}
th{background:#f3f3f3}.chip{display:inline-block;padding:1px 8px;margin:2px;border-radius:3px;
font-size:13px;border:1px solid #ccc}.phases{line-height:1.9}.missing{color:#b00}
.badge{background:#b35c00;color:#fff;border-radius:3px;padding:1px 6px;font-size:13px;
margin-left:.5em}.verdict{font-size:16px;padding:.5em;background:#eef6ee;border-left:4px solid
#2a9d8f}.note{color:#555;font-size:13px}details{margin:.5em 0}h2{border-bottom:1px solid #ddd;
margin-top:1.6em}</style>"""


def page(title: str, body: Sequence[str], n_figures: int) -> str:
    """A self-contained HTML page: plotly.js embedded once, error collector first."""
    from plotly.offline import get_plotlyjs

    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>" + html.escape(title)
            + "</title>" + _ERRORS + _STYLE + "<script type='text/javascript'>"
            + get_plotlyjs() + "</script></head>"
            + f"<body data-figures='{n_figures}' data-plots-drawn='0'>" + "\n".join(body)
            + "</body></html>")


def table(rows: Sequence[Sequence[str]], head: Sequence[str]) -> str:
    h = "".join(f"<th>{html.escape(x)}</th>" for x in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(x)}</td>" for x in r) + "</tr>"
                   for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"
