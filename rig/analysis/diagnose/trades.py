"""Exact trades between a dead time and a pure time shift of the input force.

A shift commutes with a linear filter: an effect whose whole transform of the recorded
force is a shift (``Effect.input_shift``; the library's load-cell filter, an advance by the
4-pole Butterworth's group delay) beside an effect with a dead time (``Effect.dead_time``;
the drive) predicts the same force on the key as that effect alone with its dead time moved
by the shift. No data driven by the recorded force can separate them."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

from rig.model.effects import Effect


@dataclass
class Trade:
    """A chosen effect's dead time traded exactly against another effect's time shift."""

    effect: str           # the chosen effect with the dead time
    parameter: str        # its dead-time parameter
    value: float          # its final value (s)
    other: str            # the effect whose whole input transform is a shift
    other_values: dict[str, float]  # that effect's values the shift was taken at
    other_units: dict[str, str]     # and their units
    shift: float          # its shift (s, later positive)
    own: float            # the dead time with the other effect beside it: value - shift (s)
    both_chosen: bool     # both in the set: the data fix only value + shift

    def note(self) -> str:
        key = f"{self.effect}.{self.parameter}"
        units = self.other_units
        at = ", ".join(f"{k} {v:.4g}{(' ' + units[k]) if units.get(k) else ''}"
                       for k, v in self.other_values.items())
        if self.both_chosen:
            return (f"{key} and {self.other} trade exactly: {self.other} ({at}) shifts the "
                    f"force by {self.shift * 1e3:+.2f} ms, so these data fix only the force's "
                    f"whole dead time, {(self.value + self.shift) * 1e3:.2f} ms, not how it "
                    "splits between them")
        return (f"{key} = {self.value * 1e3:.2f} ms is the force's whole dead time as these "
                f"data see it: {self.effect} + {self.other} predicts exactly the same with "
                f"{key} lengthened by {self.other}'s shift (at {at}, "
                f"{self.shift * 1e3:+.2f} ms: {key} = {self.own * 1e3:.2f} ms), so the data "
                f"cannot tell {self.effect} from {self.effect} + {self.other}; a value of "
                "either measured elsewhere settles it")

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def shift_trades(names: Sequence[str], values: Mapping[str, float],
                 by_name: Mapping[str, type[Effect]]) -> list[Trade]:
    """The exact trades between a chosen effect's dead time and a candidate whose whole
    input transform is a time shift (the library's load-cell filter is an advance by its
    group delay): the set with the candidate and the dead time moved by its shift predicts
    the same force on the key, so no data driven by the recorded force can separate them.
    A candidate outside the set is taken at its default values, and only where the moved
    dead time stays within its bounds (values keyed ``effect.param``)."""
    out = []
    for name in names:
        cls = by_name[name]
        key = f"{name}.{cls.dead_time}"
        if cls.dead_time is None or key not in values:
            continue
        spec = next(p for p in cls.parameters if p.name == cls.dead_time)
        delay = values[key]
        for other, ocls in by_name.items():
            if other == name:
                continue
            chosen = other in names
            inst = ocls(**{k[len(other) + 1:]: v for k, v in values.items()
                           if k.startswith(other + ".")}) if chosen else ocls()
            shift = inst.input_shift()
            if not shift or not chosen and not (spec.bounds[0] <= delay - shift
                                                <= spec.bounds[1]):
                continue
            out.append(Trade(name, spec.name, delay, other,
                             {p.name: inst.values[p.name] for p in ocls.parameters},
                             {p.name: p.units for p in ocls.parameters},
                             shift, delay - shift, chosen))
    return out
