"""`rig touch`: the action's touch weights (down-, up-, balance, strike and front weight,
friction, key and action ratios) as a technician quotes them (rig.model.touch)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rig.model import touch as tm
from rig.model.action import ActionModel


def touch(model_file: Path | None, effects: Sequence[str] = ()) -> tuple[ActionModel, tm.Touch]:
    """The model from its YAML (the base model without one) and its touch figures."""
    model = ActionModel.from_yaml(model_file, effects=effects)
    return model, tm.measure(model)


def document(model: ActionModel, result: tm.Touch, model_file: Path | None) -> dict[str, Any]:
    """`rig touch --json`'s document (schema rig.touch/1, docs/json.md)."""
    return {"schema": "rig.touch/1", "model": str(model_file) if model_file else None,
            "effects": list(model.effect_names), **result.to_json()}
