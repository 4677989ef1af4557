"""What rig's JSON records share (the calibration records, rig.calibration.records, and the
learned-feedforward records, rig.control.records): a JSON-safe copy (``json_ready``), the
content hash over the canonical JSON (``content_hash``) and the identity of the rig a
record was made on (``rig_identity``: name, backend, simulated seed)."""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

from rig.inputs.config import RigConfig


def json_ready(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_ready(v) for v in obj]
    if hasattr(obj, "tolist"):
        return json_ready(obj.tolist())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def content_hash(record: dict[str, Any]) -> str:
    """sha256 of the canonical JSON of the record without its hash."""
    body = {k: v for k, v in record.items() if k != "content_hash"}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def rig_identity(cfg: RigConfig) -> dict[str, Any]:
    ident: dict[str, Any] = {"name": cfg.name, "backend": cfg.backend}
    if cfg.simulated:
        ident["sim_seed"] = cfg.sim.seed
    return ident
