"""`rig touch`: the action's touch weights (down-, up-, balance, strike and front weight,
friction, key and action ratios) as a technician quotes them (rig.model.touch)."""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig.errors import InputError, refuse_existing
from rig.model import touch as tm
from rig.model.action import ActionModel

if TYPE_CHECKING:
    from rig.calibration.touch import Ramps
    from rig.inputs.config import RigConfig

ACCEL = 10.0  # m/s^2: the key-front acceleration whose force rig touch prints by default


def touch(model_file: Path | None, effects: Sequence[str] = ()) -> tuple[ActionModel, tm.Touch]:
    """The model from its YAML (the base model without one) and its touch figures."""
    model = ActionModel.from_yaml(model_file, effects=effects)
    return model, tm.measure(model)


def presses(model: ActionModel, cfg: RigConfig, ramps: Ramps, trials: int,
            rig: str) -> dict[str, Any]:
    """`rig touch --presses N`: the up-weight `rig measure touch` with ``ramps`` and
    ``trials`` on the rig ``cfg`` (its loop timing) reads from this model, and where each
    press stops the key (rig.services.measure_touch.model_returns and ``returns_summary``:
    the presses simulated in time with every friction sticking, then a slow return from
    each stop; docs/touch.md, "The up-weight after a press in time"); ``rig`` says which
    rig's timing. The settings are checked as `rig measure touch` checks them."""
    from rig.services import measure_touch as mt

    if isinstance(trials, bool) or trials < 1:
        raise InputError(f"--presses: expected 1 or more presses, got {trials}")
    ramps.check(cfg.limits.max_force_n)
    out = mt.returns_summary(mt.model_returns(model, cfg, ramps, trials=trials))
    return {**out, "presses": trials, "conditioning_presses": ramps.condition,
            "ramps_g": {"from": ramps.from_g, "to": ramps.to_g, "low": ramps.low_g,
                        "rate_g_s": ramps.rate_g_s},
            "threshold_m": ramps.threshold_mm * 1e-3,
            "settle_s": cfg.loop.settle_s, "rest_s": cfg.loop.rest_s, "rig": rig}


def presses_line(p: dict[str, Any]) -> str:
    """``presses``' figures in one line for the terminal."""
    n = p["presses"]
    spread = f" +- {p['spread_g']:.2f} (2 sd)" if n > 1 else ""
    each = ", ".join(f"{u:.2f}" for u in p["per_press_g"])
    counted: dict[str, int] = {}
    for stop in p["stops"]:
        counted[stop] = counted.get(stop, 0) + 1
    stops = ", ".join(f"{stop} {k} of {n}" for stop, k in counted.items())
    r = p["ramps_g"]
    return (f"after {n} press{'es' if n > 1 else ''} in time: up-weight "
            f"{p['up_weight_g']:.2f} g{spread}, per press {each}; the key stopped: {stops} "
            f"({p['conditioning_presses']} conditioning first; ramps {r['from']:g} -> "
            f"{r['to']:g} -> {r['low']:g} g at {r['rate_g_s']:g} g/s, the loop timing of "
            f"{p['rig']}; every friction sticking, then a slow return from each stop: what "
            f"rig measure touch with these settings reads)")


def document(model: ActionModel, result: tm.Touch, model_file: Path | None,
             accel: float = ACCEL, pressed: dict[str, Any] | None = None) -> dict[str, Any]:
    """`rig touch --json`'s document (schema rig.touch/1, docs/json.md); ``pressed``:
    ``presses``' figures (``--presses``), else null."""
    force = tm.acceleration_force(result, accel)
    return {"schema": "rig.touch/1", "model": str(model_file) if model_file else None,
            "effects": list(model.effect_names), **result.to_json(),
            "acceleration": {"m_s2": accel, "force_N": force, "grams": tm.grams(force)},
            "presses": pressed}


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
