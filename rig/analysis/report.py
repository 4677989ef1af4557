"""HTML reports with PNG plots (matplotlib, Agg) written next to the HTML.

``REPORT.html`` and ``REPORT_files/*.png``: measurement and models overlaid per
channel, residuals with the phases shaded, the error-by-phase heat map, the
before/after bar chart, and for a diagnosis the candidates' held-out error
removed. The page marks any plot that fails to load and records how many
loaded in ``<body data-images-loaded>`` once the page has loaded.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rig.analysis import compare as cp
from rig.analysis.compare import Comparison

DISPLAY = {"rad": (1e3, "mrad"), "m": (1e3, "mm"), "m/m": (1e6, "microstrain"),
           "N": (1.0, "N"), "m/s": (1.0, "m/s")}
PHASE_COLOURS = ("#f2f2f2", "#dfe9f5", "#fbe5d6", "#e2f0d9", "#fff2cc", "#ead1f5", "#d9f2f2")


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _scale(units: str) -> tuple[float, str]:
    return DISPLAY.get(units, (1.0, units))


def _shade(ax: Any, comp: Comparison, labels: bool) -> None:
    for i, (name, a, b) in enumerate(comp.phases):
        ax.axvspan(a * 1e3, b * 1e3, color=PHASE_COLOURS[i % len(PHASE_COLOURS)], lw=0, zorder=0)
        if labels:
            ax.text((a + b) / 2 * 1e3, 1.0, name, transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=6, rotation=20)


def plot_overlay(comp: Comparison, path: Path) -> Path:
    plt = _plt()
    n = len(comp.channels)
    fig, axes = plt.subplots(n, 1, figsize=(9, 2.2 * n + 0.6), sharex=True, squeeze=False)
    t = comp.time * 1e3
    for ax, c in zip(axes[:, 0], comp.channels, strict=True):
        k, u = _scale(comp.measurement.units.get(c, ""))
        _shade(ax, comp, ax is axes[0, 0])
        ax.plot(t, comp.measured[c] * k, color="black", lw=1.6, label="measured")
        for m in comp.models:
            ax.plot(t, m.predicted[c] * k, lw=1.0, label=m.label)
        rel = " (from rest)" if comp.measurement.relative(c) else ""
        ax.set_ylabel(f"{c}{rel}\n[{u}]", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="upper left")
    axes[-1, 0].set_xlabel("time [ms]")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_residuals(comp: Comparison, path: Path) -> Path:
    plt = _plt()
    n = len(comp.channels)
    fig, axes = plt.subplots(n, 1, figsize=(9, 2.0 * n + 0.6), sharex=True, squeeze=False)
    t = comp.time * 1e3
    for ax, c in zip(axes[:, 0], comp.channels, strict=True):
        k, u = _scale(comp.measurement.units.get(c, ""))
        _shade(ax, comp, ax is axes[0, 0])
        for m in comp.models:
            ax.plot(t, m.residual[c] * k, lw=0.9, label=m.label)
        sig = comp.noise.get(c, math.nan)
        if math.isfinite(sig):
            ax.axhspan(-sig * k, sig * k, color="grey", alpha=0.3, lw=0, label="noise +-1 sigma")
        ax.axhline(0, color="black", lw=0.5)
        ax.set_ylabel(f"{c} residual\n[{u}]", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="upper left")
    axes[-1, 0].set_xlabel("time [ms] (phases shaded)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_heatmap(comp: Comparison, path: Path) -> Path:
    plt = _plt()
    phases = [p for p, _, _ in comp.phases]
    nm = len(comp.models)
    fig, axes = plt.subplots(1, nm, figsize=(1.2 + 1.1 * len(phases) * nm, 0.5 * len(
        comp.channels) + 2.2), squeeze=False)
    vmax = max((v for m in comp.models for c in comp.channels for v in
                m.phase_errors[c].values() if math.isfinite(v)), default=1.0) * 100
    im = None
    for ax, m in zip(axes[0], comp.models, strict=True):
        z = np.array([[m.phase_errors[c].get(p, math.nan) * 100 for p in phases]
                      for c in comp.channels])
        im = ax.imshow(z, cmap="magma_r", vmin=0, vmax=vmax or 1.0, aspect="auto")
        ax.set_xticks(range(len(phases)), phases, rotation=40, ha="right", fontsize=7)
        ax.set_yticks(range(len(comp.channels)), comp.channels, fontsize=7)
        ax.set_title(m.label, fontsize=9)
        for i in range(z.shape[0]):
            for j in range(z.shape[1]):
                if math.isfinite(z[i, j]):
                    ax.text(j, i, f"{z[i, j]:.2g}", ha="center", va="center", fontsize=6,
                            color="white" if z[i, j] > 0.6 * vmax else "black")
    if im is not None:
        fig.colorbar(im, ax=axes[0].tolist(), label="RMS residual / channel range [%]")
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_bars(comp: Comparison, path: Path) -> Path:
    plt = _plt()
    names = [*comp.channels, "all channels"]
    x = np.arange(len(names))
    w = 0.8 / max(1, len(comp.models))
    fig, ax = plt.subplots(figsize=(1.3 * len(names) + 2, 3.4))
    for i, m in enumerate(comp.models):
        vals = [m.errors[c].nrms * 100 for c in comp.channels] + [m.mean_nrms() * 100]
        ax.bar(x + (i - (len(comp.models) - 1) / 2) * w, vals, w, label=m.label)
    ax.set_xticks(x, names, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("RMS residual / range [%]")
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_candidates(diag: object, path: Path) -> Path:
    from rig.analysis.diagnose import Diagnosis

    assert isinstance(diag, Diagnosis)
    plt = _plt()
    cands = [c for c in diag.candidates if not c.error]
    fig, ax = plt.subplots(figsize=(7, 0.4 * len(cands) + 1.4))
    y = np.arange(len(cands))[::-1]
    vals = [max(c.removal, -1.0) * 100 for c in cands]
    ax.barh(y, vals, color=["#2a9d8f" if c.significant else "#bbbbbb" for c in cands])
    ax.set_yticks(y, [c.name for c in cands], fontsize=8)
    ax.axvline(diag.min_gain * 100, color="black", ls="--", lw=0.8, label="significance floor")
    ax.set_xlabel("held-out error removed [%] (green: significant)")
    ax.legend(fontsize=7)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _table(rows: Sequence[Sequence[str]], head: Sequence[str]) -> str:
    h = "".join(f"<th>{html.escape(x)}</th>" for x in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(x)}</td>" for x in r) + "</tr>"
                   for r in rows)
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


def _error_table(comp: Comparison) -> str:
    rows = []
    for c in comp.channels:
        k, u = _scale(comp.measurement.units.get(c, ""))
        for label, key in (("RMS", "rms"), ("normalized RMS", "nrms"), ("max", "max")):
            vals = []
            for m in comp.models:
                e = m.errors[c]
                v = getattr(e, key)
                vals.append(f"{v * 100:.2f} %" if key == "nrms" else f"{v * k:.4g} {u}")
            rows.append([c if key == "rms" else "", label, *vals])
    rows.append(["all channels", "normalized RMS",
                 *[f"{m.mean_nrms() * 100:.2f} %" for m in comp.models]])
    for name, event, units in cp.KEY_EVENTS:
        meas = comp.strike_speed if not event else comp.events.get(event, math.nan) * 1e3
        rows.append([f"{name} error", f"{units} (measured {meas:.4g})",
                     *[f"{m.event_errors[name]:+.3g}" for m in comp.models]])
    return _table(rows, ["channel / event", "error", *[m.label for m in comp.models]])


_SCRIPT = """<script>
window.addEventListener('load', function () {
  var imgs = document.querySelectorAll('img'), ok = 0;
  imgs.forEach(function (im) {
    if (im.complete && im.naturalWidth > 0) { ok += 1; }
    else { im.insertAdjacentHTML('afterend', '<p class="missing">plot failed to load: ' +
                                 im.getAttribute('src') + '</p>'); }
  });
  document.body.setAttribute('data-images-loaded', ok + '/' + imgs.length);
});
</script>"""
_STYLE = """<style>body{font-family:sans-serif;max-width:1100px;margin:1em auto;color:#222}
table{border-collapse:collapse;font-size:13px;margin:.5em 0}td,th{border:1px solid #ccc;
padding:2px 8px;text-align:right}td:first-child,th:first-child{text-align:left}
img{max-width:100%;display:block;margin:.5em 0}.missing{color:#b00}pre{font-size:12px;
background:#f6f6f6;padding:.5em;white-space:pre-wrap}</style>"""


def write(comp: Comparison, out: Path, title: str = "rig compare",
          diagnosis: object | None = None) -> Path:
    """Write ``out`` (HTML) and its plots into ``<out stem>_files/``; returns ``out``."""
    out = Path(out)
    if out.suffix.lower() not in (".html", ".htm"):
        raise ValueError(f"report: expected an .html path, got {out}")
    files = out.parent / f"{out.stem}_files"
    files.mkdir(parents=True, exist_ok=True)
    imgs = [("Measurement and models, per channel", plot_overlay(comp, files / "overlay.png")),
            ("Residuals (model - measured); phases of the blow shaded",
             plot_residuals(comp, files / "residuals.png")),
            ("Error by phase (RMS residual over the channel's range)",
             plot_heatmap(comp, files / "phases.png")),
            ("Before / after: normalized RMS error per channel",
             plot_bars(comp, files / "bars.png"))]
    parts = [f"<h1>{html.escape(title)}</h1>",
             f"<p>{html.escape(comp.measurement.label)}: input <b>{comp.input}</b>, "
             f"{comp.time[-1] * 1e3:.0f} ms at {comp.measurement.rate:g} Hz; channels "
             f"{html.escape(', '.join(comp.channels))}.</p>"]
    fails = [m for m in comp.models if not m.ok]
    for m in fails:
        parts.append(f"<p class='missing'>{html.escape(m.label)}: simulation failed: "
                     f"{html.escape(m.result.message)}</p>")
    if diagnosis is not None:
        from rig.analysis.diagnose import Diagnosis

        assert isinstance(diagnosis, Diagnosis)
        parts.append("<h2>Diagnosis</h2><pre>" + html.escape("\n".join(
            diagnosis.report_lines())) + "</pre>")
        imgs.append(("Candidates: held-out error removed",
                     plot_candidates(diagnosis, files / "candidates.png")))
    parts.append("<h2>Errors</h2>" + _error_table(comp))
    ev_rows = [[n, f"{comp.events.get(n, math.nan) * 1e3:.2f}", comp.event_source.get(n, ""),
                *[f"{m.events.get(n, math.nan) * 1e3:.2f}" for m in comp.models]]
               for n in cp.EVENT_ORDER]
    parts.append("<h2>Events [ms]</h2>" + _table(ev_rows, ["event", "measured", "from",
                                                           *[m.label for m in comp.models]]))
    for caption, p in imgs:
        rel = f"{files.name}/{p.name}"
        parts.append(f"<h2>{html.escape(caption)}</h2><img src='{html.escape(rel)}' "
                     f"alt='{html.escape(caption)}'>")
    doc = ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>" + html.escape(title)
           + "</title>" + _STYLE + "</head><body>" + "\n".join(parts) + _SCRIPT
           + "</body></html>")
    out.write_text(doc)
    return out
