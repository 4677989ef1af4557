"""`rig regulate`: the model's regulation as a technician measures it, and with targets
the regulating adjustments that meet them (rig.model.regulation)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rig.errors import InputError
from rig.model import modelfile, regulation
from rig.model.action import ActionModel


@dataclass
class Regulation:
    """The regulation figures (m), the targets given (m), and with targets the adjusted
    points (path -> (x, y) m) and the regulated model YAML's content."""

    figures: dict[str, float]
    targets: dict[str, float] = field(default_factory=dict)
    points: dict[str, Any] = field(default_factory=dict)
    data: dict[str, Any] | None = None


def regulate(model: Path | None = None, to: Path | None = None, write: Path | None = None,
             force: bool = False) -> Regulation:
    """Measure ``model``'s regulation (the default model without one); with targets ``to``,
    solve for the adjustments and build the regulated model YAML for ``write``. Nothing is
    written here (``save``)."""
    if write is not None and to is None:
        raise InputError("--write: needs --to targets.yaml")
    if write is not None and write.exists() and not force:
        raise InputError(f"{write}: exists (use --force to overwrite)")
    m = ActionModel.from_yaml(model) if model else ActionModel()
    if to is None:
        return Regulation(regulation.measure(m))
    targets = regulation.load_targets(to)
    points, figures = regulation.solve(m.params, targets, m.effect_names)
    base, base_dir = modelfile.read(model)
    out_dir = write.resolve().parent if write is not None else base_dir
    data = regulation.regulated_model_yaml(modelfile.rebased(base, base_dir, out_dir), points, to)
    return Regulation(figures, targets, points, data)


def target_of(name: str, reg: Regulation) -> tuple[float | None, str]:
    """The figure's target (m) and where it comes from ("target" given, else "thesis")."""
    if name in reg.targets:
        return reg.targets[name], "target"
    return regulation.THESIS_TARGETS.get(name), "thesis"


def save(reg: Regulation, write: Path) -> None:
    """Write the regulated model YAML."""
    assert reg.data is not None, "a regulated model needs targets (--to)"
    modelfile.write(reg.data, write)
