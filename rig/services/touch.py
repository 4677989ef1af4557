"""`rig touch`: the action's touch weights (down-, up-, balance, strike and front weight,
friction, key and action ratios) as a technician quotes them (rig.model.touch)."""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rig.errors import refuse_existing
from rig.model import touch as tm
from rig.model.action import ActionModel

ACCEL = 10.0  # m/s^2: the key-front acceleration whose force rig touch prints by default


def touch(model_file: Path | None, effects: Sequence[str] = ()) -> tuple[ActionModel, tm.Touch]:
    """The model from its YAML (the base model without one) and its touch figures."""
    model = ActionModel.from_yaml(model_file, effects=effects)
    return model, tm.measure(model)


def document(model: ActionModel, result: tm.Touch, model_file: Path | None,
             accel: float = ACCEL) -> dict[str, Any]:
    """`rig touch --json`'s document (schema rig.touch/1, docs/json.md)."""
    force = tm.acceleration_force(result, accel)
    return {"schema": "rig.touch/1", "model": str(model_file) if model_file else None,
            "effects": list(model.effect_names), **result.to_json(),
            "acceleration": {"m_s2": accel, "force_N": force, "grams": tm.grams(force)}}


def plot_html(result: tm.Touch, title: str) -> str:
    """A self-contained HTML page (Plotly) of the key force along the slow press: down,
    up and frictionless, in grams at the key front against the key-front dip in mm."""
    import plotly.graph_objects as go

    from rig.analysis import plots

    dip = result.dip_m * 1e3
    fig = go.Figure()
    for name, force, colour in (("down press", result.down_n, plots.MODEL_COLOURS[1]),
                                ("up press", result.up_n, plots.MODEL_COLOURS[0]),
                                ("frictionless", result.frictionless_n, "#777777")):
        fig.add_trace(go.Scatter(x=dip, y=[tm.grams(float(f)) for f in force], name=name,
                                 mode="lines+markers", line={"color": colour}))
    mid = result.method["mid_stroke_dip_m"] * 1e3
    fig.add_vline(x=mid, line={"dash": "dot", "color": "#999999"},
                  annotation_text=f"mid-stroke {mid:.2f} mm")
    fig.update_layout(title=title, template="plotly_white", font=plots.FONT,
                      xaxis_title="key-front dip [mm]",
                      yaxis_title="key force [g at the key front]", hovermode="x unified")
    weights = (f"down-weight {result.figures['down_weight']:.2f} g, up-weight "
               f"{result.figures['up_weight']:.2f} g, balance weight "
               f"{result.figures['balance_weight']:.2f} g, friction "
               f"{result.figures['friction']:.2f} g; the stroke ends where: "
               f"{result.stroke_end}")
    body = [f"<h1>{html.escape(title)}</h1>", f"<p>{html.escape(weights)}</p>",
            plots.figure_html(fig, "touch-stroke")]
    return plots.page(title, body, 1)


def write_plot(result: tm.Touch, out: Path, title: str, force: bool) -> None:
    """Write ``plot_html`` to ``out``; an existing file only with ``force``."""
    refuse_existing(out, force, "plot")
    out.write_text(plot_html(result, title))
