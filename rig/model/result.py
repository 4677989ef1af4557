"""The result of a blow (simulated, or measured in the same layout) and the events found
in it from the model's contact channels (named as docs/run-file.md says)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from rig.model.vocabulary import EVENT_ORDER, KEY_MOVE_THRESHOLD_M

if TYPE_CHECKING:
    from rig.model.action import ActionModel


@dataclass
class SimResult:
    """A simulated (or, with the same layout, measured) blow."""

    time: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str]
    events: dict[str, float]
    status: int = 0
    message: str = "ok"
    stats: dict[str, float] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    contact_ids: tuple[int, ...] = ()
    model: ActionModel | None = field(default=None, repr=False, compare=False)

    @property
    def success(self) -> bool:
        return self.status == 0

    def contact(self, name: str, cid: int) -> np.ndarray:
        """Column of a per-contact channel for contact id ``cid``."""
        return self.channels[name][:, self.contact_ids.index(cid)]

    def at(self, name: str, t: float) -> float:
        return float(np.interp(t, self.time, self.channels[name]))

    @property
    def strike_speed(self) -> float:
        """Hammer-head speed (m/s) at the last sample before it meets the string; NaN
        without a strike. (Interpolating across the impact would mix in the rebound.)"""
        ts = self.events.get("strike", math.nan)
        if not math.isfinite(ts):
            return math.nan
        i = int(np.searchsorted(self.time, ts, side="right")) - 1
        return float(self.channels["hammer_head_velocity"][max(i, 0)])

    @property
    def let_off_distance(self) -> float:
        """Hammer-to-string distance (m) when the jack escapes (``let_off``); NaN without
        a let-off or without contact 12's penetration channel."""
        tl = self.events.get("let_off", math.nan)
        if not math.isfinite(tl) or 12 not in self.contact_ids \
                or "contact_penetration" not in self.channels:
            return math.nan
        return -float(np.interp(tl, self.time, self.contact("contact_penetration", 12)))

    def summary(self) -> dict[str, float]:
        out = {f"{n}_s": self.events.get(n, math.nan) for n in EVENT_ORDER}
        out["let_off_distance_m"] = self.let_off_distance
        out["strike_speed_m_s"] = self.strike_speed
        ts, tr = self.events.get("strike", math.nan), self.events.get("string_release", math.nan)
        out["string_contact_s"] = tr - ts
        return out


def _crossings(t: np.ndarray, x: np.ndarray, rising: bool) -> np.ndarray:
    """Times where x crosses 0 upward (rising) or downward, linearly interpolated."""
    s = x > 0
    idx = np.flatnonzero(~s[:-1] & s[1:]) if rising else np.flatnonzero(s[:-1] & ~s[1:])
    x0, x1 = x[idx], x[idx + 1]
    return t[idx] + (t[idx + 1] - t[idx]) * (-x0) / (x1 - x0)


def _first_after(times: np.ndarray, after: float) -> float:
    later = times[times > after]
    return float(later[0]) if later.size else math.nan


def contact_indicator(result: SimResult, cid: int, damping: float) -> np.ndarray:
    """Positive exactly while contact ``cid`` pushes: penetration > 0 and 1 + D rate > 0.

    A felt that is unloaded faster than it recovers stops pushing before its
    geometric penetration ends (Eq. 3.2 never pulls); the contact has then let go.
    """
    pen = result.contact("contact_penetration", cid)
    if "contact_penetration_rate" not in result.channels or damping <= 0:
        return pen
    rate = result.contact("contact_penetration_rate", cid)
    # both terms in metres: the penetration, and how far it has left to fall at the
    # current rate before the damping factor would turn the force negative
    release = (1.0 / damping + rate) * 1e-3
    return np.minimum(pen, release)


def find_events(result: SimResult, threshold_m: float = KEY_MOVE_THRESHOLD_M,
                damping: Mapping[int, float] | None = None) -> dict[str, float]:
    """Event times (s) of a blow from its channels; NaN where an event did not happen."""
    t = result.time
    ev: dict[str, float] = dict.fromkeys(EVENT_ORDER, math.nan)
    dip = result.channels["key_dip"]
    ev["key_starts"] = _first_after(_crossings(t, dip - threshold_m, True), -1.0)
    damping = damping or {}

    def pen(cid: int) -> np.ndarray:
        return contact_indicator(result, cid, damping.get(cid, 0.0))

    start = ev["key_starts"] if math.isfinite(ev["key_starts"]) else t[0] - 1.0
    ev["toe_meets_button"] = _first_after(_crossings(t, pen(8), True), start)
    toe = ev["toe_meets_button"]
    ev["let_off"] = _first_after(_crossings(t, pen(7), False), toe if math.isfinite(toe) else start)
    ev["strike"] = _first_after(_crossings(t, pen(12), True), start)
    ev["string_release"] = _first_after(_crossings(t, pen(12), False), ev["strike"]) \
        if math.isfinite(ev["strike"]) else math.nan
    ev["check"] = _first_after(_crossings(t, pen(4), True), ev["string_release"]) \
        if math.isfinite(ev["string_release"]) else math.nan
    ev["key_bottom"] = _first_after(_crossings(t, pen(2), True), start)
    leaves = _crossings(t, pen(2), False)
    leaves = leaves[leaves > ev["key_bottom"]] if math.isfinite(ev["key_bottom"]) else leaves[:0]
    ev["key_release"] = float(leaves[-1]) if leaves.size else math.nan
    return ev
