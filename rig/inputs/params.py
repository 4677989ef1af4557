"""Model parameters: the thesis's values, our chosen ones, and user overrides.

One nested tree (dicts and lists, SI units) loaded from the package's
``data/action-parameters.yaml`` (thesis, verbatim) and
``data/chosen-parameters.yaml`` (values the thesis leaves out). A user file
may override any existing value; unknown names are refused so a typo never
silently leaves a parameter at its default.

Parameters are addressed by dotted paths, e.g. ``contacts.4.D`` (contact by
its id), ``bodies.key.mass``, ``joint_friction.hammer.E``.
"""

from __future__ import annotations

import copy
import functools
import math
import re
from collections.abc import Iterator, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from rig.errors import InputError

# The thesis's time unit of the drive model's Tw and Tp3 (Eq. D.1, Appendix D: the 500 Hz
# loop's 2 ms periods): Eq. D.1's one definition (rig.motor_torque: the learner's and the
# simulated drive's) and the rig config's default (sim.process_time_unit_s).
THESIS_TIME_UNIT_S = 0.002

_DATA = resources.files("rig") / "data"
# libyaml's safe loader where PyYAML was built with it (the wheels are): the same
# documents, parsed about 10x faster than the pure-Python one (the package's two
# parameter files took 20-30 ms of every model built in a fresh process)
_SAFE_BASE: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

# YAML 1.2's core schema (https://yaml.org/spec/1.2.2/#1032-tag-resolution), which people
# write and every current YAML library reads: `9.16e9`, `1e10` and `-3E-4` are floats
# (YAML 1.1, PyYAML's own rules, needs a dot and a signed exponent and reads them as
# strings); `010` is ten, not eight; `yes`, `no`, `on`, `off` and `12:30` are strings.
# PyYAML parses (libyaml, above) and ruamel.yaml's rules are the same (a test checks them
# against it); ruamel.yaml itself parses a parameter file ~15x slower (benchmarks/yaml_load.py).
_CORE_RESOLVERS: list[tuple[str, str, list[str]]] = [  # (tag, pattern, first characters)
    ("tag:yaml.org,2002:null", r"^(?:~|null|Null|NULL|)$", ["~", "n", "N", ""]),
    ("tag:yaml.org,2002:bool", r"^(?:true|True|TRUE|false|False|FALSE)$", list("tTfF")),
    ("tag:yaml.org,2002:int", r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$", list("-+0123456789")),
    ("tag:yaml.org,2002:float",
     r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
     r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$", list("-+0123456789.")),
]


class _CoreLoader(_SAFE_BASE):
    """PyYAML's safe loader with YAML 1.2 core-schema scalars (above); merge keys kept."""

    yaml_implicit_resolvers: dict[str, list[tuple[str, Any]]] = {
        first: [(tag, regexp) for tag, regexp in resolvers
                if tag == "tag:yaml.org,2002:merge"]
        for first, resolvers in _SAFE_BASE.yaml_implicit_resolvers.items()}
    yaml_constructors = dict(_SAFE_BASE.yaml_constructors)

    def construct_core_int(self, node: Any) -> int:
        text = self.construct_scalar(node)
        if text.startswith(("0o", "0x")):
            return int(text[2:], 8 if text[1] == "o" else 16)
        return int(text, 10)

    def construct_core_float(self, node: Any) -> float:
        text = self.construct_scalar(node).lower()
        if text.endswith(".inf"):
            return -math.inf if text.startswith("-") else math.inf
        return math.nan if text == ".nan" else float(text)


for _tag, _pattern, _first in _CORE_RESOLVERS:
    _CoreLoader.add_implicit_resolver(_tag, re.compile(_pattern), list(_first))
_CoreLoader.add_constructor("tag:yaml.org,2002:int", _CoreLoader.construct_core_int)
_CoreLoader.add_constructor("tag:yaml.org,2002:float", _CoreLoader.construct_core_float)
_SAFE_LOADER: Any = _CoreLoader


def _load_yaml_text(text: str, source: str) -> Any:
    try:
        return yaml.load(text, Loader=_SAFE_LOADER)  # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        from rig.errors import InputError

        raise InputError(f"{source}:{where} is not valid YAML ({exc.__class__.__name__})") from None
    except RecursionError:
        from rig.errors import InputError

        raise InputError(f"{source}: nested too deeply to read as YAML") from None


def read_text_file(path: str | Path, max_bytes: int | None = None) -> str:
    """A UTF-8 text file's content; a one-line ``InputError`` naming it when it is missing,
    larger than ``max_bytes``, unreadable or not UTF-8."""
    from rig.errors import InputError, not_a_file

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: {not_a_file(p)}")
    try:
        size = p.stat().st_size
        if max_bytes is not None and size > max_bytes:
            raise InputError(f"{p}: file is {size} bytes, more than the {max_bytes} allowed")
        return p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{p}: not a UTF-8 text file (byte {exc.start} cannot be "
                         f"decoded)") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror or exc})") from None


def load_yaml_file(path: str | Path, max_bytes: int | None = None) -> Any:
    """Read a YAML file, raising a one-line ``ValueError`` naming it on failure."""
    p = Path(path)
    return _load_yaml_text(read_text_file(p, max_bytes), str(p))


DEFAULT = "default"  # a value that sets a parameter back to its thesis/chosen default


@functools.cache
def _parsed_defaults() -> dict[str, Any]:
    """The two package YAML files, parsed once per process (callers copy the tree)."""
    base = _load_yaml_text((_DATA / "action-parameters.yaml").read_text("utf-8"), "thesis params")
    chosen = _load_yaml_text((_DATA / "chosen-parameters.yaml").read_text("utf-8"), "chosen")
    for key, value in chosen.items():
        if key in base:
            raise RuntimeError(f"chosen-parameters.yaml redefines thesis key {key!r}")
        base[key] = value
    return base


def _defaults() -> dict[str, Any]:
    return copy.deepcopy(_parsed_defaults())


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


class Parameters:
    """A validated, addressable tree of model parameters."""

    def __init__(self, tree: dict[str, Any] | None = None) -> None:
        self._tree: dict[str, Any] = tree if tree is not None else _defaults()

    # -- construction -------------------------------------------------------
    @classmethod
    def default(cls) -> Parameters:
        return cls()

    @classmethod
    def from_file(cls, path: str | Path | None) -> Parameters:
        """Defaults overridden by the YAML mapping in ``path`` (if given)."""
        params = cls()
        if path is not None:
            params.update_from_file(path)
        return params

    def copy(self) -> Parameters:
        return Parameters(copy.deepcopy(self._tree))

    @property
    def tree(self) -> dict[str, Any]:
        """The underlying nested dict (read it, do not mutate it)."""
        return self._tree

    # -- addressing ---------------------------------------------------------
    def _locate(self, path: str) -> tuple[Any, Any]:
        parts = path.split(".")
        node: Any = self._tree
        for i, part in enumerate(parts[:-1]):
            node = self._child(node, part, ".".join(parts[: i + 1]))
        last = parts[-1]
        if isinstance(node, list) and node and all(_is_number(v) for v in node):
            # a coordinate of a point (points.ground.Pg6.at.1: the let-off button's height)
            if last.isdigit() and int(last) < len(node):
                return node, int(last)
            raise InputError(f"parameter {path!r}: {last} is not an index of "
                             f"{'.'.join(parts[:-1])} (0 to {len(node) - 1})")
        if isinstance(node, list):
            return node, self._contact_index(node, last, path)
        if isinstance(node, dict):
            key = self._dict_key(node, last)
            if key is None:
                raise InputError(f"parameter {path!r}: no such parameter")
            return node, key
        raise InputError(f"parameter {path!r}: no such parameter")

    @staticmethod
    def _dict_key(node: dict[Any, Any], part: str) -> Any:
        if part in node:
            return part
        if part.lstrip("-").isdigit() and int(part) in node:
            return int(part)
        return None

    def _child(self, node: Any, part: str, where: str) -> Any:
        if isinstance(node, list):
            return node[self._contact_index(node, part, where)]
        if isinstance(node, dict):
            key = self._dict_key(node, part)
            if key is not None:
                return node[key]
        raise InputError(f"parameter {where!r}: no such parameter")

    @staticmethod
    def _contact_index(node: list[Any], part: str, where: str) -> int:
        for i, item in enumerate(node):
            if isinstance(item, dict) and str(item.get("id")) == part:
                return i
        raise InputError(f"parameter {where!r}: no list entry with id {part}")

    def get(self, path: str) -> Any:
        node, key = self._locate(path)
        return node[key]

    def set(self, path: str, value: Any) -> Parameters:
        """Set an existing numeric parameter; refuses unknown paths and non-numbers.

        The value ``"default"`` sets the parameter back to its thesis (or chosen)
        default. Returns the parameters, so calls chain.
        """
        node, key = self._locate(path)
        old = node[key]
        if isinstance(value, str) and value.strip().lower() == DEFAULT:
            node[key] = copy.deepcopy(Parameters(_parsed_defaults()).get(path))
            return self
        if _is_number(old):
            if not _is_number(value) or not math.isfinite(float(value)):
                raise InputError(f"parameter {path!r}: expected a finite number, got {value!r}")
            node[key] = float(value)
        elif isinstance(old, list) and all(_is_number(v) for v in old):
            if not isinstance(value, list | tuple) or len(value) != len(old):
                raise InputError(f"parameter {path!r}: expected a list of {len(old)} numbers")
            if not all(_is_number(v) and math.isfinite(float(v)) for v in value):
                raise InputError(f"parameter {path!r}: expected finite numbers, got {value!r}")
            node[key] = [float(v) for v in value]
        elif isinstance(old, str):
            if not isinstance(value, str):
                raise InputError(f"parameter {path!r}: expected text, got {value!r}")
            node[key] = value
        else:
            raise InputError(f"parameter {path!r}: is a group, set its members instead")
        return self

    def update(self, overrides: Mapping[str, Any], source: str = "overrides") -> Parameters:
        """Apply a nested mapping of overrides (contacts keyed by id); returns self."""
        for path, value in _flatten(overrides):
            try:
                self.set(path, value)
            except ValueError as exc:
                raise InputError(f"{source}: {exc}") from None
        return self

    def update_from_file(self, path: str | Path) -> Parameters:
        """Apply the overrides in the YAML file ``path`` to this tree; returns self.

        Only the values the file names change (``default`` restores one); an
        empty file changes nothing.
        """
        data = load_yaml_file(path)
        if data is None:
            return self
        if not isinstance(data, Mapping):
            raise InputError(f"{path}: expected a mapping of parameter overrides")
        return self.update(data, source=str(path))

    def paths(self) -> Iterator[str]:
        """Every numeric leaf's dotted path."""
        yield from _leaf_paths(self._tree, "")

    def to_yaml(self) -> str:
        return yaml.safe_dump(self._tree, sort_keys=False)


def _flatten(mapping: Mapping[Any, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for key, value in mapping.items():
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            yield from _flatten(value, path + ".")
        else:
            yield path, value


def _leaf_paths(node: Any, prefix: str) -> Iterator[str]:
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _leaf_paths(value, f"{prefix}{key}.")
    elif isinstance(node, list) and node and isinstance(node[0], dict) and "id" in node[0]:
        for item in node:
            for key, value in item.items():
                if key != "id" and _is_number(value):
                    yield f"{prefix}{item['id']}.{key}"
    elif _is_number(node) or (isinstance(node, list) and all(_is_number(v) for v in node)):
        yield prefix[:-1]
