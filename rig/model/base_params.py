"""Base parameters as diagnosis candidates: a short list of scale factors on the base model.

``rig diagnose --base`` proposes, beside the library's effects, that one of these base
parameters is off by a factor: "the hammer head is 6 % heavier" is then a possible answer,
reported as ``base: hammer head mass x1.06 +- 0.02``. Each candidate is one scale factor
(``scale``, 1 = the model's value) on one parameter path or a group of paths scaled
together (a felt's stiffness polynomial a, b, c; the felts' damping factors), with a prior
range around 1 that bounds the fit. It enters the search as an effect would (the same
fit, held-out test, joint refit and written-model check), with ``scale``'s off value 1: a
scale within 1.96 standard errors of 1 explains nothing and is not claimed.

The list (docs/workflow.md "Base parameters as candidates") is short on purpose: every
candidate costs a fit in every round of the search and divides the round's test level
(Bonferroni); each is a quantity a real action is often a few per cent off its thesis
value and that the measured channels see. Contacts a library effect already sets are left
out (4, the back check: ``backcheck_law``; 14, the balance rail: ``key_liftoff``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from rig.errors import InputError
from rig.model.effects import Build, Effect, EffectParameter

PREFIX = "base:"
# felt contacts whose damping the felt-damping candidate scales (not 4 nor 14: their
# effects' own parameters)
FELT_DAMPED = (1, 2, 3, 5, 6, 7, 8, 9, 10, 11, 12, 13)


@dataclass(frozen=True)
class BaseGroup:
    """One base-parameter candidate: the paths scaled together by one factor."""

    key: str                    # the candidate's name after ``base:`` (a dotted path)
    paths: tuple[str, ...]      # the model parameters it scales
    text: str                   # how the report names it ("hammer head mass")
    prior: float                # the scale's range: [1 - prior, 1 + prior]

    @property
    def name(self) -> str:
        return PREFIX + self.key


def _stiffness(cid: int, text: str) -> BaseGroup:
    return BaseGroup(f"contacts.{cid}.stiffness",
                     tuple(f"contacts.{cid}.{c}" for c in ("a", "b", "c")),
                     f"{text} felt stiffness", 0.3)


GROUPS: tuple[BaseGroup, ...] = (
    # masses and inertias: +-15 % (a lead, a heavier head, a thicker whippen)
    BaseGroup("bodies.key.mass", ("bodies.key.mass",), "key mass", 0.15),
    BaseGroup("bodies.whippen.mass", ("bodies.whippen.mass",), "whippen mass", 0.15),
    BaseGroup("bodies.hammer_head.mass", ("bodies.hammer_head.mass",), "hammer head mass",
              0.15),
    BaseGroup("bodies.key.inertia", ("bodies.key.inertia",), "key inertia", 0.15),
    BaseGroup("bodies.hammer_head.inertia", ("bodies.hammer_head.inertia",),
              "hammer head inertia", 0.15),
    # felt stiffness (the polynomial a, b, c together): +-30 % (felt ages and compacts)
    _stiffness(1, "capstan"),
    _stiffness(7, "knuckle"),
    _stiffness(12, "hammer"),
    # the felts' damping factors D together: +-30 %
    BaseGroup("contacts.damping", tuple(f"contacts.{c}.D" for c in FELT_DAMPED),
              "felt damping", 0.3),
    # spring preloads: +-30 %
    BaseGroup("springs.jack_torque", ("springs.jack_torque",), "jack spring torque", 0.3),
    BaseGroup("springs.repetition.k", ("springs.repetition.k",), "repetition spring rate",
              0.3),
    # friction: the hammer flange's pivot friction, +-50 %
    BaseGroup("joint_friction.hammer.E", ("joint_friction.hammer.E",),
              "hammer flange friction", 0.5),
)


class BaseScale(Effect):
    """A scale factor on a group of base-model parameters (a subclass per group)."""

    group: ClassVar[BaseGroup]
    summary = "a base parameter off by a factor"

    def apply(self, build: Build) -> None:
        s = self.values["scale"]
        if s != 1.0:
            for path in self.group.paths:
                build.params.set(path, float(build.params.get(path)) * s)


def _class_of(group: BaseGroup) -> type[BaseScale]:
    param = EffectParameter("scale", "1", 1.0, (1.0 - group.prior, 1.0 + group.prior), True,
                            f"factor on {', '.join(group.paths)}", off=1.0)
    attrs = {"name": group.name, "group": group, "parameters": (param,),
             "summary": f"the base model's {group.text} off by a factor "
                        f"(x{1 - group.prior:g}-{1 + group.prior:g}): "
                        + ", ".join(group.paths)}
    cls = type(f"BaseScale_{group.key.replace('.', '_')}", (BaseScale,), attrs)
    return cls


CANDIDATES: dict[str, type[BaseScale]] = {g.name: _class_of(g) for g in GROUPS}


def is_base(name: str) -> bool:
    """Whether a candidate's name is a base-parameter candidate's."""
    return name.startswith(PREFIX)


def candidate(name: str) -> type[BaseScale]:
    """The base-parameter candidate named ``name`` (``base:<path>``)."""
    cls = CANDIDATES.get(name)
    if cls is None:
        raise InputError(f"candidates: {name!r} is not a base-parameter candidate "
                         f"({sorted(CANDIDATES)})")
    return cls
