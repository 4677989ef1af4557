"""HTML reports of `rig compare` and `rig diagnose`: one self-contained interactive file.

The page embeds plotly.js once (no network, no sibling folder), so the .html alone can be
e-mailed. For every requested trial (the held-out trials of a diagnosis marked): the data
and each model per channel over the whole trial and, focused, from let-off to the check
with a button per phase; the residuals (model - data) with the noise band; measured
events as dotted lines and each model's events as markers on its curves; the error by
phase as a heat map; the errors and events as tables. A diagnosis adds its verdict and
candidates as tables, an unclipped candidate chart with values, and the base model
against base + winner with the residual spectrum. A provenance block ends the page
(command line, rig version and git commit, run file, model files and effect values).

The page records in ``<body data-figures data-plots-drawn>`` how many figures it holds
and how many Plotly drew, and script errors in ``<html data-errors>``.
"""

from __future__ import annotations

import html
import math
import platform
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig.analysis import compare as cp
from rig.analysis import plots as pl
from rig.analysis.compare import Comparison
from rig.errors import InputError

DATA_LABEL = {"measured": "measured", "synthetic": "synthetic measurement",
              "simulated": "simulated run file"}
FOCUS_MARGIN_S = 0.005


@dataclass
class Provenance:
    """Where a report's numbers come from."""

    run: Path
    run_attrs: dict[str, Any] = field(default_factory=dict)
    models: list[tuple[str, str, Any]] = field(default_factory=list)  # label, file, model
    command: str = field(default_factory=lambda: " ".join(sys.argv))

    @classmethod
    def of(cls, run: str | Path, models: Sequence[tuple[str, str | Path | None, Any]]
           ) -> Provenance:
        """The run file's root attributes and the models (label, YAML or None, ActionModel)."""
        import h5py

        attrs: dict[str, Any] = {}
        try:
            with h5py.File(run, "r") as f:
                attrs = {k: (v.item() if isinstance(v, np.generic) else v)
                         for k, v in f.attrs.items()}
        except OSError:
            pass
        return cls(Path(run), attrs, [(lb, str(f) if f is not None else "(built-in base model)",
                                       m) for lb, f, m in models])

    @property
    def kind(self) -> str:
        return str(self.run_attrs.get("kind", "measured"))

    def html(self) -> str:
        from rig.recordings.runfile import git_commit
        from rig.version import __version__

        a = self.run_attrs
        rows = [["command line", self.command],
                ["rig", f"{__version__} (git {git_commit()}) on {platform.node()}, Python "
                        f"{platform.python_version()}"],
                ["run file", f"{self.run} ({a.get('kind', '?')}, status {a.get('status', '?')}"
                             f", created {a.get('created', '?')} by rig "
                             f"{a.get('software_version', '?')} git "
                             f"{str(a.get('git_commit', '?'))[:12]})"]]
        for label, file, model in self.models:
            effects = "; ".join(
                f"{e.name}(" + ", ".join(f"{k}={v:.6g}" for k, v in e.values.items()) + ")"
                for e in getattr(model, "effects", [])) or "none (rigid base model)"
            rows.append([f"model {label}", f"{file}; effects: {effects}"])
        return "<h2>Provenance</h2>" + pl.table(rows, ["", ""])


def _data_label(kind: str) -> str:
    return DATA_LABEL.get(kind, kind)


def _focus(comp: Comparison) -> tuple[float, float]:
    """Let-off to the check (s), with a margin; falls back to the whole trial."""
    ev = comp.events
    t0, t1 = float(comp.time[0]), float(comp.time[-1])
    lo = next((ev[e] for e in ("let_off", "toe_meets_button", "strike") if math.isfinite(
        ev.get(e, math.nan))), t0)
    hi = next((ev[e] for e in ("check", "string_release", "key_bottom")
               if math.isfinite(ev.get(e, math.nan)) and ev[e] > lo), t1)
    return max(t0, lo - FOCUS_MARGIN_S), min(t1, hi + FOCUS_MARGIN_S)


def _overlay(comp: Comparison, channels: Sequence[str], kind: str, lo: float, hi: float,
             title: str, buttons: bool) -> Any:
    fig = pl.stacked(channels, title=title)
    n = len(channels)
    pl.phase_bands(fig, comp.phases, n, lo, hi)
    pl.event_lines(fig, comp.events, n, _data_label(kind), lo, hi, span=(lo, hi))
    mask = pl.window(comp.time, lo, hi)
    t = comp.time[mask]
    dl = _data_label(kind)
    for r, c in enumerate(channels, 1):
        k, u = pl.scale(comp.measurement.units.get(c, ""))
        y = comp.measured[c][mask] * k
        pl.line(fig, t, y, r, dl, "black", r == 1, width=2.0)
        for i, m in enumerate(comp.models):
            col = pl.MODEL_COLOURS[i % len(pl.MODEL_COLOURS)]
            ym = m.predicted[c][mask] * k
            pl.line(fig, t, ym, r, m.label, col, r == 1, dash="dash" if i else None)
            pl.event_markers(fig, t, ym, m.events, r, m.label, col, "diamond", r == 1, lo, hi)
        rel = " from rest" if comp.measurement.relative(c) else ""
        fig.update_yaxes(title_text=f"{c}{rel} [{u}]", title_font={"size": 12}, row=r, col=1)
    fig.update_xaxes(range=[lo * 1e3, hi * 1e3])
    if buttons:
        opts = [{"label": "let-off to check", "method": "relayout",
                 "args": [{"xaxis.range": [lo * 1e3, hi * 1e3]}]}]
        for name, a, b in comp.phases:
            a2, b2 = max(a, lo), min(b, hi)
            if math.isfinite(a2) and math.isfinite(b2) and b2 > a2:
                pad = 0.1 * (b2 - a2)
                opts.append({"label": name, "method": "relayout",
                             "args": [{"xaxis.range": [(a2 - pad) * 1e3, (b2 + pad) * 1e3]}]})
        fig.update_layout(updatemenus=[{"type": "buttons", "direction": "right", "x": 0,
                                        "y": 1.0, "xanchor": "left", "yanchor": "bottom",
                                        "pad": {"b": 80}, "buttons": opts,
                                        "font": {"size": 12}}],
                          margin={"t": 170}, title={"y": 0.999})
    return fig


def _residuals(comp: Comparison, channels: Sequence[str], kind: str) -> Any:
    fig = pl.stacked(channels, height_per_row=150,
                     title="Residuals (model - " + _data_label(kind) + "); grey: noise +-1 sigma")
    n = len(channels)
    pl.phase_bands(fig, comp.phases, n)
    pl.event_lines(fig, comp.events, n, _data_label(kind),
                   span=(float(comp.time[0]), float(comp.time[-1])))
    import plotly.graph_objects as go

    for r, c in enumerate(channels, 1):
        k, u = pl.scale(comp.measurement.units.get(c, ""))
        sig = comp.noise.get(c, math.nan)
        if math.isfinite(sig) and sig > 0:
            fig.add_trace(go.Scatter(x=[comp.time[0] * 1e3, comp.time[-1] * 1e3,
                                        comp.time[-1] * 1e3, comp.time[0] * 1e3],
                                     y=[sig * k, sig * k, -sig * k, -sig * k], fill="toself",
                                     fillcolor="rgba(120,120,120,0.35)", line={"width": 0},
                                     name="noise +-1 sigma", legendgroup="noise",
                                     showlegend=r == 1, hoverinfo="skip"), row=r, col=1)
        for i, m in enumerate(comp.models):
            pl.line(fig, comp.time, m.residual[c] * k, r, m.label,
                    pl.MODEL_COLOURS[i % len(pl.MODEL_COLOURS)], r == 1, width=1.2)
        fig.update_yaxes(title_text=f"{c} [{u}]", title_font={"size": 12}, row=r, col=1)
    return fig


def _spectrum(comp: Comparison, channels: Sequence[str]) -> Any:
    """Amplitude spectrum (Hann window) of each model's residual per channel."""
    fig = pl.stacked(channels, height_per_row=160, title="Residual spectrum (Hann window)")
    rate = comp.measurement.rate
    for r, c in enumerate(channels, 1):
        k, u = pl.scale(comp.measurement.units.get(c, ""))
        for i, m in enumerate(comp.models):
            x = np.nan_to_num(np.asarray(m.residual[c], float) * k)
            x = x - x.mean()
            w = np.hanning(x.size)
            amp = 2 * np.abs(np.fft.rfft(x * w)) / max(w.sum(), 1e-12)
            f = np.fft.rfftfreq(x.size, 1.0 / rate)
            import plotly.graph_objects as go

            fig.add_trace(go.Scatter(x=f[1:], y=amp[1:], mode="lines", name=m.label,
                                     legendgroup=m.label, showlegend=r == 1,
                                     line={"color": pl.MODEL_COLOURS[i % len(
                                         pl.MODEL_COLOURS)], "width": 1.2}), row=r, col=1)
        fig.update_yaxes(type="log", title_text=f"{c} [{u}]", title_font={"size": 12},
                         row=r, col=1)
    fig.update_xaxes(title_text="frequency [Hz]", row=len(channels), col=1)
    fig.update_layout(hovermode="closest")
    return fig


def _heatmap(comp: Comparison) -> Any:
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    phases = [p for p, _, _ in comp.phases]
    nm = len(comp.models)
    fig = make_subplots(rows=1, cols=nm, subplot_titles=[m.label for m in comp.models],
                        shared_yaxes=True, horizontal_spacing=0.04)
    vals = [v for m in comp.models for c in comp.channels for v in m.phase_errors[c].values()
            if math.isfinite(v)]
    vmax = (max(vals) if vals else 1.0) * 100 or 1.0
    for j, m in enumerate(comp.models, 1):
        z = [[m.phase_errors[c].get(p, math.nan) * 100 for p in phases] for c in comp.channels]
        text = [[f"{v:.2g}" if math.isfinite(v) else "" for v in row] for row in z]
        fig.add_trace(go.Heatmap(z=z, x=phases, y=comp.channels, text=text,
                                 texttemplate="%{text}", textfont={"size": 12},
                                 colorscale="Magma", reversescale=True, zmin=0, zmax=vmax,
                                 showscale=j == nm,
                                 colorbar={"title": {"text": "% of range"}},
                                 hovertemplate="%{y} in %{x}: %{z:.3g} % of range<extra>"
                                               + html.escape(m.label) + "</extra>"),
                      row=1, col=j)
    fig.update_xaxes(tickangle=-30, tickfont={"size": 12})
    fig.update_yaxes(tickfont={"size": 12}, autorange="reversed")
    fig.update_layout(height=60 + 34 * len(comp.channels) + 160, font=pl.FONT,
                      title={"text": "Error by phase: RMS residual / channel range [%]",
                             "font": {"size": 15}},
                      margin={"l": 140, "r": 20, "t": 70, "b": 110}, template="plotly_white")
    return fig


def _bars(comp: Comparison) -> Any:
    import plotly.graph_objects as go

    names = [*comp.channels, "all channels"]
    fig = go.Figure()
    for i, m in enumerate(comp.models):
        vals = [m.errors[c].nrms * 100 for c in comp.channels] + [m.mean_nrms() * 100]
        fig.add_trace(go.Bar(x=names, y=vals, name=m.label, text=[f"{v:.2f}" for v in vals],
                             textposition="outside",
                             marker_color=pl.MODEL_COLOURS[i % len(pl.MODEL_COLOURS)]))
    fig.update_layout(barmode="group", height=380, font=pl.FONT, template="plotly_white",
                      title={"text": "Normalized RMS error per channel [% of range]",
                             "font": {"size": 15}}, yaxis_title="% of range",
                      margin={"l": 70, "r": 20, "t": 60, "b": 90})
    return fig


def _candidates(diag: Any) -> Any:
    """Every evaluated candidate's held-out error removed, unclipped, with its value."""
    import plotly.graph_objects as go

    cands = [c for c in diag.candidates if not c.error and math.isfinite(c.removal)]
    names = [c.name for c in cands][::-1]
    vals = [c.removal * 100 for c in cands][::-1]
    cols = ["#2a9d8f" if c.significant else "#aaaaaa" for c in cands][::-1]
    fig = go.Figure(go.Bar(x=vals, y=names, orientation="h", marker_color=cols,
                           text=[f"{v:.1f} %" for v in vals], textposition="outside",
                           cliponaxis=False, hovertemplate="%{y}: %{x:.2f} %<extra></extra>",
                           name="held-out error removed"))
    fig.add_vline(x=diag.min_gain * 100, line={"dash": "dash", "color": "black"},
                  annotation_text=f"significance floor {diag.min_gain * 100:.0f} %",
                  annotation_position="top")
    lo = min([0.0, *vals])
    hi = max([diag.min_gain * 100, *vals])
    pad = 0.15 * (hi - lo or 1.0)
    fig.update_layout(height=120 + 34 * max(1, len(cands)), font=pl.FONT,
                      template="plotly_white", xaxis={"range": [lo - pad, hi + pad],
                                                      "title": "held-out error removed [%]"},
                      title={"text": "Candidate effects (green: significant)",
                             "font": {"size": 15}},
                      margin={"l": 190, "r": 40, "t": 70, "b": 50})
    return fig


def _error_table(comp: Comparison) -> str:
    rows = []
    for c in comp.channels:
        k, u = pl.scale(comp.measurement.units.get(c, ""))
        for label, key in (("RMS", "rms"), ("normalized RMS", "nrms"), ("max", "max")):
            vals = []
            for m in comp.models:
                v = getattr(m.errors[c], key)
                vals.append(f"{v * 100:.2f} %" if key == "nrms" else f"{v * k:.4g} {u}")
            rows.append([c if key == "rms" else "", label, *vals])
    rows.append(["all channels", "normalized RMS",
                 *[f"{m.mean_nrms() * 100:.2f} %" for m in comp.models]])
    for name, event, units in cp.KEY_EVENTS:
        meas = comp.strike_speed if not event else comp.events.get(event, math.nan) * 1e3
        rows.append([f"{name} error", f"{units} (data {meas:.4g})",
                     *[f"{m.event_errors[name]:+.3g}" for m in comp.models]])
    return pl.table(rows, ["channel / event", "error", *[m.label for m in comp.models]])


def _event_table(comp: Comparison, kind: str) -> str:
    def ms_(v: float) -> str:
        return f"{v * 1e3:.2f}" if math.isfinite(v) else "--"

    names = sorted(cp.EVENT_ORDER, key=lambda n: (not math.isfinite(
        comp.events.get(n, math.nan)), comp.events.get(n, math.inf)))
    rows = [[pl.event_label(n), ms_(comp.events.get(n, math.nan)),
             comp.event_source.get(n, ""), *[ms_(m.events.get(n, math.nan))
                                             for m in comp.models]] for n in names]
    return pl.table(rows, ["event", _data_label(kind), "from", *[m.label for m in comp.models]])


def _diagnosis_html(diag: Any) -> str:
    from rig.analysis import signature as sg

    comp = diag.comparison
    mc = comp.models[0]
    best = diag.best
    out = [f"<p class='verdict'>{html.escape(diag.verdict())}</p>",
           f"<p class='note'>model {html.escape(mc.label)}, input {html.escape(comp.input)}; "
           f"held-out data: {html.escape(diag.split)}; significant: removes at least "
           f"{diag.min_gain * 100:.0f} % of the held-out error and, on some channel, at least "
           f"{diag.min_noise_gain:g} x its noise variance.</p>"]
    rows = []
    for i, c in enumerate(diag.candidates, 1):
        if c.error:
            rows.append([str(i), c.name, "--", "not evaluated", "--", "--", c.error])
            continue
        vals = ", ".join(f"{k} = {v:.4g} +- {c.sigma.get(k, math.nan):.2g} "
                         f"{c.units.get(k, '')}".rstrip() for k, v in c.values.items()) or "-"
        rows.append([str(i), c.name, f"{c.removal * 100:.1f} %",
                     "yes" if c.significant else "no", f"{c.noise_gain:.1f}", vals, c.note])
    out.append("<h3>Candidates, ranked by held-out error removed</h3>" + pl.table(
        rows, ["#", "effect", "held-out error removed", "significant", "x noise variance",
               "fitted values", "note"]))
    if best is not None and best.channel_removal:
        out.append("<h3>" + html.escape(best.name) + ": error removed per channel</h3>"
                   + pl.table([[c, f"{v * 100:.1f} %"] for c, v in
                               best.channel_removal.items()], ["channel", "removed"]))
    out.append("<h3>Where the model fails (normalized RMS residual)</h3>" + pl.table(
        [[c, f"{v * 100:.2f} %"] for c, v in sg.worst_channels(comp, mc)],
        ["channel", "RMS / range"]))
    srows = [[s.channel, s.phase, s.kind, f"{s.nrms * 100:.2f} %", f"{s.excess:.1f}",
              f"{s.bias_share:.0%}", f"{s.lag_share:.0%} ({s.lag_s * 1e3:+.2f} ms)",
              f"{s.osc_share:.0%}" + (f" at {s.frequency_hz:.0f} Hz"
                                      if math.isfinite(s.frequency_hz) else ""),
              ", ".join(f"{pl.event_label(k)} {v * 1e3:+.2f} ms" for k, v in s.events.items())]
             for s in diag.signatures[:8]]
    out.append("<h3>Largest residuals by channel and phase</h3>" + pl.table(
        srows, ["channel", "phase", "kind", "RMS / range", "x noise", "bias", "lag",
                "oscillation", "timing (model - data)"]))
    timing = getattr(diag, "timing", None)
    if timing is not None and timing.rows:
        out.append("<h3>The blow's events: each model against the events found in the trials "
                   "[ms]</h3>" + timing_table(timing))
    out.extend(f"<p class='note'>{html.escape(n)}</p>" for n in diag.notes)
    return "\n".join(out)


def timing_table(timing: Any) -> str:
    """The rows of a ``rig.analysis.timing.Timing``: each event of each trial, the time found
    with its 95 % interval, and each model's time with its SD under the input's noise,
    marked where it lies outside (docs/workflow.md, "The blow's events")."""
    from rig.analysis import timing as tm

    rows = []
    for r in timing.rows:
        cells = [pl.event_label(r.event), r.trial, f"{r.measured * 1e3:.2f}",
                 f"{r.low * 1e3:.2f} to {r.high * 1e3:.2f}"]
        for label in timing.labels:
            t = r.models.get(label, math.nan)
            if not math.isfinite(t):
                cells.append("none (outside)")
                continue
            sd = r.spread.get(label, math.nan)
            spread = f" +- {sd * 1e3:.2f}" if math.isfinite(sd) else ""
            off = r.beyond(label, timing.tolerance)
            mark = f" (outside, {off * 1e3:+.2f})" if off != 0 else ""
            cells.append(f"{t * 1e3:.2f}{spread}{mark}")
        rows.append(cells)
    note = (f"<p class='note'>A model's time is outside when it lies beyond the found "
            f"interval by more than {timing.tolerance * 1e3:.1f} ms plus {tm.Z:.2f} SD of its time "
            "under the input's noise (+- one SD shown; in brackets how far beyond).</p>")
    return pl.table(rows, ["event", "trial", "found", "95 % interval",
                           *timing.labels]) + note


class _Page:
    def __init__(self) -> None:
        self.parts: list[str] = []
        self.n = 0

    def fig(self, fig: Any) -> None:
        self.n += 1
        self.parts.append(pl.figure_html(fig, f"fig{self.n}"))

    def add(self, text: str) -> None:
        self.parts.append(text)


def write(comps: Comparison | Sequence[Comparison], out: Path, title: str = "rig compare",
          diagnosis: Any | None = None, *, provenance: Provenance | None = None,
          held_out: Sequence[int] = (), channels: Sequence[str] | None = None,
          held_out_text: str = "") -> Path:
    """Write the report ``out`` (.html) for every comparison (one per trial); returns ``out``.

    ``held_out``: indices into ``comps`` of trials a diagnosis scored on (marked);
    ``channels``: the channels plotted (default: at most pl.MAX_CHANNELS, the piano
    maker's first; the tables keep every compared channel).
    """
    out = Path(out)
    if out.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"report: expected an .html path, got {out}")
    comp_list = [comps] if isinstance(comps, Comparison) else list(comps)
    if not comp_list:
        raise InputError("report: no comparison to show")
    kind = provenance.kind if provenance is not None else "measured"
    dl = _data_label(kind)
    p = _Page()
    first = comp_list[0]
    p.add(f"<h1>{html.escape(title)}</h1>")
    p.add(f"<p>Data: <b>{html.escape(dl)}</b>, {len(comp_list)} trial(s) "
          f"({html.escape(', '.join(c.measurement.label for c in comp_list))}); models "
          f"driven by the {html.escape(first.input)}; "
          f"{first.time[-1] * 1e3:.0f} ms at {first.measurement.rate:g} Hz. Zoom by "
          f"dragging, double-click to reset; hover for values.</p>")
    if diagnosis is not None:
        p.add("<h2>Diagnosis</h2>" + _diagnosis_html(diagnosis))
        p.fig(_candidates(diagnosis))
    for ti, comp in enumerate(comp_list):
        chans = [c for c in (channels or pl.pick_channels(comp.channels)) if c in comp.channels]
        badge = "<span class='badge'>held out</span>" if ti in held_out else ""
        p.add(f"<h2>Trial {html.escape(comp.measurement.label)}{badge}</h2>")
        if ti in held_out and held_out_text:
            p.add(f"<p class='note'>{html.escape(held_out_text)}</p>")
        for m in comp.models:
            if not m.ok:
                p.add(f"<p class='missing'>{html.escape(m.label)}: simulation failed: "
                      f"{html.escape(m.result.message)}</p>")
        if len(chans) < len(comp.channels):
            p.add(f"<p class='note'>plots show {len(chans)} of {len(comp.channels)} compared "
                  f"channels ({html.escape(', '.join(chans))}); the tables show all. "
                  f"<code>--channel</code> chooses.</p>")
        p.add(pl.phase_key(comp.phases))
        lo, hi = _focus(comp)
        p.add(f"<p class='note'>Dotted lines: {html.escape(dl)} events; diamonds: each "
              f"model's events (hover for times); the buttons zoom to a phase.</p>")
        p.fig(_overlay(comp, chans, kind, lo, hi, f"Let-off to check ({lo * 1e3:.1f}-"
                       f"{hi * 1e3:.1f} ms)", buttons=True))
        p.fig(_overlay(comp, chans, kind, float(comp.time[0]), float(comp.time[-1]),
                       "Whole trial", buttons=False))
        p.fig(_residuals(comp, chans, kind))
        if diagnosis is not None:
            p.fig(_spectrum(comp, chans))
        p.fig(_heatmap(comp))
        p.fig(_bars(comp))
        p.add("<h3>Errors</h3>" + _error_table(comp))
        p.add("<h3>Events [ms], in time order</h3>" + _event_table(comp, kind))
    if provenance is not None:
        p.add(provenance.html())
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(pl.page(title, p.parts, p.n), encoding="utf-8")
    return out

