"""Rows of the simulated drive and the fingertip for benchmarks/fidelity.py.

Placeholder module of the action_model branch: the drive_finger branch owns this file
and its rows (same dict format as fidelity.py's row functions); until it is merged
there are none.
"""

from __future__ import annotations

from typing import Any


def rows() -> list[dict[str, Any]]:
    return []
