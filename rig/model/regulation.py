"""The action's regulation measured as a technician measures it, from a slow key press.

Figures (all in metres, SI):

- ``key_dip``: key-top (Pk2) travel from rest to the front punching (contact 2 closes);
- ``hammer_rest``: hammer-to-string distance at rest (minus contact 12's penetration);
- ``toe_meets_button``: hammer-to-string distance when the jack's toe meets the let-off
  button (contact 8 closes);
- ``let_off``: hammer-to-string distance when the jack escapes (contact 7 opens);
- ``drop``: hammer-to-string distance where the repetition lever holds the hammer at the
  end of the press with the key held (Section 1.2's "3 mm");
- ``aftertouch``: key-top travel from let-off to the front punching.

The model is driven by force, so the "slow press" is a slow force ramp
(``PRESS_POINTS``); once the key overcomes its friction it accelerates, and the hammer
still reaches the string and rebounds. A technician's slow press never lets the hammer
rebound into the back check; the model's would, and the back check (which sticks,
docs/model.md) would then hold the hammer 15 mm below the string for as long as the key
is held. So the press runs with the back check out of the way (contact 4's felt
stiffness zero, ``press``), as a technician regulates the drop before setting the
checks; every figure before the rebound is the same with or without it. Targets:
Sections 3.6 and 1.2 of the thesis (``THESIS_TARGETS``, rig/data/regulation-targets.yaml).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rig.errors import InputError
from rig.inputs import profiles
from rig.inputs.params import Parameters, load_yaml_file

if TYPE_CHECKING:
    from rig.model.action import ActionModel, SimResult

# (time s, key force N): rest, then 0 -> 4 N in 1 s, held
PRESS_POINTS = ((0.0, 0.0), (0.02, 0.0), (1.02, 4.0), (1.3, 4.0))
FIGURES = ("key_dip", "hammer_rest", "toe_meets_button", "let_off", "drop", "aftertouch")
FIGURE_DOCS = {
    "key_dip": "key-top travel from rest to the front punching",
    "hammer_rest": "hammer to string at rest",
    "toe_meets_button": "hammer to string when the jack's toe meets the let-off button",
    "let_off": "hammer to string when the jack escapes",
    "drop": "hammer to string on the repetition lever, key held",
    "aftertouch": "key-top travel from let-off to the front punching",
}
# thesis: key dip 10.0 mm and hammer rest 48.0 mm (3.6); let-off about 1 mm and the
# repetition lever holding the hammer 3 mm from the string (1.2)
THESIS_TARGETS = {"key_dip": 0.0100, "hammer_rest": 0.0480, "let_off": 0.001, "drop": 0.003}


def slow_press() -> profiles.Profile:
    return profiles.from_points([list(p) for p in PRESS_POINTS], name="slow press",
                                description="0 -> 4 N in 1 s, held (regulation)")


def string_gap(res: SimResult) -> np.ndarray:
    """Hammer-to-string distance (m) per sample: minus contact 12's penetration."""
    return -res.contact("contact_penetration", 12)


def from_press(res: SimResult) -> dict[str, float]:
    """The regulation figures (m) of a slow press's result; NaN where an event is missing."""
    ev, t, gap = res.events, res.time, string_gap(res)

    def gap_at(name: str) -> float:
        te = ev.get(name, math.nan)
        return float(np.interp(te, t, gap)) if math.isfinite(te) else math.nan

    dip = res.at("key_dip", ev["key_bottom"]) if math.isfinite(ev["key_bottom"]) else math.nan
    lo = ev["let_off"]
    return {
        "key_dip": dip,
        "hammer_rest": float(gap[0]),
        "toe_meets_button": gap_at("toe_meets_button"),
        "let_off": res.let_off_distance,
        "drop": float(gap[-1]),
        "aftertouch": dip - res.at("key_dip", lo) if math.isfinite(lo) else math.nan,
    }


def press(model: ActionModel) -> SimResult:
    """``model``'s slow press with its back check out of the way (contact 4 takes no load)."""
    from rig.model.action import ActionModel

    params = model.params.copy()
    for coef in ("a", "b", "c"):
        params.set(f"contacts.4.{coef}", 0.0)
    return ActionModel(params, model.effects, model.integrator).simulate(slow_press())


def measure(model: ActionModel) -> dict[str, float]:
    """Press ``model``'s key slowly and return its regulation figures (m)."""
    return from_press(press(model))


# regulating adjustments: figure -> (parameter path, coordinate index), the y (height) of:
# the key-front punching (paper washers under the felt), the capstan on the key, the
# let-off button and the repetition's drop screw (rig/data/action-parameters.yaml)
ADJUSTMENTS = {
    "key_dip": ("points.ground.Pg4.at", 1),
    "hammer_rest": ("points.key.Pk3.at", 1),
    "let_off": ("points.ground.Pg6.at", 1),
    "drop": ("points.ground.Pg7.at", 1),
}
TARGETS_FILE = Path(__file__).resolve().parents[1] / "data" / "regulation-targets.yaml"
TOLERANCE_M = 1e-4


def load_targets(path: str | Path) -> dict[str, float]:
    """Targets (m) from a YAML mapping figure -> metres; one clear error per bad field."""
    p = Path(path)
    data = load_yaml_file(p)
    if not isinstance(data, Mapping) or not data:
        raise InputError(f"{p}: expected a mapping of {', '.join(ADJUSTMENTS)} to metres")
    out = {}
    for name, value in data.items():
        if name not in ADJUSTMENTS:
            raise InputError(f"{p}: {name}: unknown target (expected {', '.join(ADJUSTMENTS)})")
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value) or not 0 < value < 0.1:
            raise InputError(f"{p}: {name}: expected a distance in metres (0 < x < 0.1), "
                             f"got {value!r}")
        out[str(name)] = float(value)
    return out


def solve(params: Parameters, targets: Mapping[str, float], effects: list[str] | None = None,
          max_iter: int = 12) -> tuple[dict[str, list[float]], dict[str, float]]:
    """Adjust the regulating screws until every target is met within TOLERANCE_M.

    Newton's method on the adjustments' heights with a finite-difference Jacobian (the
    figures are coupled: the drop screw moves the let-off, the capstan the drop).
    Returns the adjusted points (path -> [x, y]) and the figures reached (m); raises
    ValueError when the targets cannot be met.
    """
    from rig.model.action import ActionModel

    names = list(targets)
    paths = [ADJUSTMENTS[n] for n in names]
    x = np.array([params.get(path)[i] for path, i in paths])

    def figures(xs: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
        p = params.copy()
        for (path, i), v in zip(paths, xs, strict=True):
            at = list(p.get(path))
            at[i] = float(v)
            p.set(path, at)
        fig = measure(ActionModel(params=p, effects=effects or []))
        return np.array([fig[n] - targets[n] for n in names]), fig

    r, fig = figures(x)
    for _ in range(max_iter):
        if np.all(np.abs(r) < 0.5 * TOLERANCE_M):
            break
        jac = np.empty((len(names), len(names)))
        for j in range(len(names)):
            for h in (1e-4, -1e-4):  # forward, or backward where forward loses an event
                dx = np.zeros_like(x)
                dx[j] = h
                jac[:, j] = (figures(x + dx)[0] - r) / h
                if np.all(np.isfinite(jac[:, j])):
                    break
        if not np.all(np.isfinite(jac)):
            break
        step = np.clip(np.linalg.solve(jac, -r), -0.003, 0.003)  # millimetres per step
        for _ in range(6):  # halve the step while it loses an event
            r_new, fig_new = figures(x + step)
            if np.all(np.isfinite(r_new)):
                break
            step = 0.5 * step
        x, r, fig = x + step, r_new, fig_new
    if not np.all(np.isfinite(r)) or np.any(np.abs(r) >= TOLERANCE_M):
        worst = names[int(np.nanargmax(np.abs(r)))]
        raise InputError(f"targets: {worst}: not met within {TOLERANCE_M * 1e3:.1f} mm "
                         f"(reached {fig[worst] * 1e3:.2f} mm)")
    points = {}
    for (path, i), v in zip(paths, x, strict=True):
        at = list(params.get(path))
        at[i] = float(v)
        points[path] = at
    return points, fig


def regulated_model_yaml(base: Mapping[str, Any] | None, points: Mapping[str, list[float]],
                         targets_path: str | Path) -> dict[str, Any]:
    """A model YAML mapping: ``base``'s content with the adjusted points in its parameters."""
    data: dict[str, Any] = dict(base or {})
    pspec = data.get("parameters")
    if pspec is not None and not isinstance(pspec, Mapping):
        raise InputError("model: parameters: --to needs parameters as a mapping of overrides "
                         "(not a file name)")
    params: dict[str, Any] = _deep_copy(pspec or {})
    for path, value in points.items():
        node = params
        parts = path.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = [float(v) for v in value]
    data["parameters"] = params
    data["description"] = (f"{data.get('description', 'shipped model')}; regulated to "
                           f"{Path(targets_path).name} by rig regulate")
    return data


def _deep_copy(node: Any) -> Any:
    if isinstance(node, Mapping):
        return {k: _deep_copy(v) for k, v in node.items()}
    return list(node) if isinstance(node, list) else node
