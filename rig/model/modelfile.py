"""Model YAML files, read and written in one place.

A model file holds ``parameters`` (a parameter file's path, or a mapping of overrides),
``effects`` (library names, ``{name: {parameter: value}}``, ``module:Class`` or
``file.py:Class``), ``integrator`` (``{name: dopri54, rtol: 1e-6}``) and ``description``.
Paths inside it are relative to the file's own folder; a file written elsewhere gets them
rewritten relative to its new folder (``rebased``). ``ActionModel.from_yaml`` builds the
model from ``read``; ``rig diagnose --write``, ``rig fit --write`` and ``rig regulate
--write`` write through ``write``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rig.errors import InputError
from rig.inputs.params import load_yaml_file

KEYS = ("parameters", "effects", "integrator", "description")


def read(path: str | Path | None) -> tuple[dict[str, Any], Path]:
    """The model file's mapping and the folder its relative paths start from (the current
    folder when ``path`` is None: the base model, an empty mapping)."""
    if path is None:
        return {}, Path.cwd()
    p = Path(path)
    loaded = load_yaml_file(p)
    if loaded is not None and not isinstance(loaded, Mapping):
        raise InputError(f"{p}: expected a mapping with {', '.join(KEYS[:3])}")
    data = dict(loaded or {})
    unknown = sorted(set(map(str, data)) - set(KEYS))
    if unknown:
        raise InputError(f"{p}: {unknown[0]}: unknown key (expected {', '.join(KEYS)})")
    if data.get("effects") is not None and not isinstance(data["effects"], list):
        raise InputError(f"{p}: effects: expected a list")
    return data, p.resolve().parent


def relative(path: Path, start: Path) -> str:
    """``path`` relative to the folder ``start`` (as a model file names it)."""
    return os.path.relpath(path.resolve(), start)


def rebase_effect(spec: Any, base_dir: Path, out_dir: Path) -> Any:
    """An effect entry of a file in ``base_dir`` as a file in ``out_dir`` must name it
    (only ``file.py:Class`` entries change)."""
    name = next(iter(spec)) if isinstance(spec, dict) else spec
    if not isinstance(name, str) or ".py:" not in name:
        return spec
    file, _, cls = name.rpartition(":")
    new = f"{relative(base_dir / file, out_dir)}:{cls}"
    return {new: spec[name]} if isinstance(spec, dict) else new


def rebased(data: Mapping[str, Any], base_dir: Path, out_dir: Path) -> dict[str, Any]:
    """A copy of a model mapping read from ``base_dir`` whose paths hold in ``out_dir``."""
    out = dict(data)
    if isinstance(out.get("parameters"), str):
        out["parameters"] = relative(base_dir / out["parameters"], out_dir)
    if out.get("effects"):
        out["effects"] = [rebase_effect(e, base_dir, out_dir) for e in out["effects"]]
    return out


def write(data: Mapping[str, Any], out: str | Path) -> Path:
    """Write a model mapping as YAML (keys in the order given), creating the folder."""
    import yaml

    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(dict(data), sort_keys=False))
    return path
