"""The import map (YAML): which source column becomes which run-file channel, in which units,
through which calibration. Format: docs/import.md. Every mistake is refused with one line
naming the map file, the line and the field (``map.yaml: line 12: columns[1].units: ...``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rig.errors import InputError
from rig.recordings import calibration as cal
from rig.recordings.units import LENGTH, UNITS

FORMATS = ("csv", "tsv", "text", "tdms", "hdf5")
SUFFIX_FORMATS = {".csv": "csv", ".tsv": "tsv", ".tab": "tsv", ".txt": "text", ".dat": "text",
                  ".tdms": "tdms", ".h5": "hdf5", ".hdf5": "hdf5", ".hdf": "hdf5"}
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
_TOP = {"format", "header", "delimiter", "sample_rate_hz", "time", "description", "columns",
        "segment"}
_COLUMN = {"column", "index", "channel", "units", "description", "calibration", "geometry"}
_SEGMENT = {"channel", "split_repeats", "on_noise", "off_noise", "on_fraction",
            "off_fraction", "min_stroke_s", "min_rest_s", "pre_s", "post_s",
            "repeat_drop"}


class _Map(dict[Any, Any]):
    line = 0
    lines: dict[Any, int]


class _Seq(list[Any]):
    line = 0
    lines: list[int]


class _Loader(yaml.SafeLoader):
    """YAML with the line of every mapping key and sequence item (for the error messages)."""


def _mapping(loader: _Loader, node: yaml.MappingNode) -> _Map:
    loader.flatten_mapping(node)
    out = _Map()
    out.line, out.lines = node.start_mark.line + 1, {}
    for knode, vnode in node.value:
        key = loader.construct_object(knode, deep=True)
        if key in out:
            raise InputError(f"line {knode.start_mark.line + 1}: {key}: given twice")
        out[key] = loader.construct_object(vnode, deep=True)
        out.lines[key] = knode.start_mark.line + 1
    return out


def _sequence(loader: _Loader, node: yaml.SequenceNode) -> _Seq:
    out = _Seq(loader.construct_object(n, deep=True) for n in node.value)
    out.line, out.lines = node.start_mark.line + 1, [n.start_mark.line + 1 for n in node.value]
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)
_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _sequence)


class Where:
    """A field of the map and its line: ``fail`` makes the one-line error."""

    def __init__(self, path: str, field_: str, line: int) -> None:
        self.path, self.field, self.line = path, field_, line

    def fail(self, msg: str) -> InputError:
        field_ = f"{self.field}: " if self.field else ""
        return InputError(f"{self.path}: line {self.line}: {field_}{msg}")

    def key(self, parent: Any, key: str) -> Where:
        line = parent.lines.get(key, parent.line) if isinstance(parent, _Map) else self.line
        return Where(self.path, f"{self.field}.{key}" if self.field else key, line)

    def item(self, parent: Any, i: int) -> Where:
        line = parent.lines[i] if isinstance(parent, _Seq) else self.line
        return Where(self.path, f"{self.field}[{i}]", line)


_FRACTION = re.compile(r"^\s*([-+]?\d+(?:\.\d*)?)\s*/\s*(\d+(?:\.\d*)?)\s*$")


def number(value: Any, where: Where, *, positive: bool = False) -> float:
    """A number of the map; a fraction written as text ("3/16") is read as its value."""
    if isinstance(value, str) and (m := _FRACTION.match(value)) and float(m.group(2)) != 0:
        value = float(m.group(1)) / float(m.group(2))
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise where.fail(f"expected a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise where.fail(f"expected a finite number, got {value!r}")
    if positive and not x > 0:
        raise where.fail(f"expected a positive number, got {value!r}")
    return x


def mapping(value: Any, where: Where, keys: set[str]) -> _Map:
    if not isinstance(value, _Map):
        raise where.fail(f"expected a mapping, got {value!r}")
    unknown = sorted(str(k) for k in value if k not in keys)
    if unknown:
        raise where.key(value, unknown[0]).fail(
            f"unknown field (expected one of {', '.join(sorted(keys))})")
    return value


@dataclass(frozen=True)
class Geometry:
    """A displacement measured at ``radius`` (m) from a body's pivot, read as its angle:
    ``arc`` (the sensor follows the arc: angle = d / r) or ``sine`` (it reads the
    displacement normal to the body at rest: angle = asin(d / r)). ``radius_m`` None: the
    radius is a fitted unknown (``radius: fit``): the channel is stored as the
    displacement and ``rig compare`` reads it as the angle of the body ``angle_of``
    through the radius (and direction) that best fits the model (arc only)."""

    radius_m: float | None
    model: str = "arc"
    angle_of: str | None = None

    @property
    def fitted(self) -> bool:
        return self.radius_m is None

    def to_dict(self) -> dict[str, Any]:
        if self.radius_m is None:
            return {"radius_m": None, "radius": "fit", "model": self.model,
                    "angle_of": self.angle_of}
        return {"radius_m": self.radius_m, "model": self.model}

    def angle(self, d: Any) -> Any:
        import numpy as np

        if self.radius_m is None:
            raise InputError("geometry: the radius is fitted by rig compare, not known here")
        ratio = np.asarray(d, float) / self.radius_m
        if self.model == "arc":
            return ratio
        if np.any(np.abs(ratio) > 1):
            raise InputError(f"geometry: a displacement exceeds the radius {self.radius_m} m "
                             f"(model sine)")
        return np.arcsin(ratio)


@dataclass
class ColumnMap:
    """One source column's way into the run file."""

    source: str | int          # header name / TDMS "group/channel" / HDF5 dataset, or 1-based
    index: int | None          # the column (1-based) of a 2-D HDF5 dataset
    channel: str
    units: str                 # units the calibration produces (as the map names them)
    stored_units: str          # SI units of the stored channel
    factor: float              # the map's units -> SI
    description: str
    steps: list[cal.Step]
    geometry: Geometry | None
    line: int

    def to_dict(self) -> dict[str, Any]:
        return {"column": self.source, "index": self.index, "channel": self.channel,
                "units": self.units, "stored_units": self.stored_units,
                "calibration": [s.describe() for s in self.steps],
                "geometry": None if self.geometry is None else self.geometry.to_dict()}


@dataclass
class SegmentSpec:
    """How a recording is split into strokes (rig.recordings.segment)."""

    channel: str
    split_repeats: bool = False
    options: dict[str, float] = field(default_factory=dict)


@dataclass
class ImportMap:
    path: Path
    text: str
    format: str | None
    header: str                # auto | yes | no
    delimiter: str | None
    sample_rate_hz: float | None
    time_column: str | int | None
    time_factor: float
    description: str
    columns: list[ColumnMap]
    segment: SegmentSpec | None

    def format_of(self, source: Path) -> str:
        if self.format is not None:
            return self.format
        fmt = SUFFIX_FORMATS.get(source.suffix.lower())
        if fmt is None:
            raise InputError(f"{self.path}: format: not given and {source.name}'s suffix "
                             f"{source.suffix!r} is not one of {', '.join(SUFFIX_FORMATS)}")
        return fmt


def _column_ref(value: Any, where: Where) -> str | int:
    if isinstance(value, bool) or not isinstance(value, int | str) or value in ("", 0):
        raise where.fail(f"expected a column name or a 1-based column number, got {value!r}")
    if isinstance(value, int) and value < 1:
        raise where.fail(f"expected a 1-based column number, got {value}")
    return value


def _units(value: Any, where: Where) -> str:
    if not isinstance(value, str) or value not in UNITS:
        raise where.fail(f"unknown units {value!r} (expected one of {', '.join(UNITS)})")
    return value


def _column(raw: Any, where: Where, vocabulary: Mapping[str, tuple[str, str]]) -> ColumnMap:
    c = mapping(raw, where, _COLUMN)
    for need in ("column", "channel", "units"):
        if need not in c:
            raise where.fail(f"{need}: missing")
    source = _column_ref(c["column"], where.key(c, "column"))
    index = None
    if "index" in c:
        index = int(number(c["index"], where.key(c, "index"), positive=True))
        if index != c["index"]:
            raise where.key(c, "index").fail(f"expected a 1-based integer, got {c['index']!r}")
    w = where.key(c, "channel")
    channel = c["channel"]
    if not isinstance(channel, str) or not _NAME.match(channel) or channel in ("time",
                                                                                "sample"):
        raise w.fail(f"expected a channel name (lower case, digits, _; not time), got "
                     f"{channel!r}")
    units = _units(c["units"], where.key(c, "units"))
    si, factor = UNITS[units]
    geometry = None
    if "geometry" in c:
        wg = where.key(c, "geometry")
        g = mapping(c["geometry"], wg, {"radius", "radius_units", "model", "angle_of"})
        if "radius" not in g:
            raise wg.fail("radius: missing (a length, or fit)")
        fit = g["radius"] == "fit"
        if fit and "angle_of" not in g:
            raise wg.fail("angle_of: missing (radius: fit needs the model's angle channel "
                          "the displacement is read as, e.g. hammer_angle)")
        if not fit and "angle_of" in g:
            raise wg.key(g, "angle_of").fail("only with radius: fit (with a known radius the "
                                             "channel itself is stored as the angle)")
        if fit and (g["angle_of"] not in vocabulary or vocabulary[g["angle_of"]][0] != "rad"):
            angles = sorted(n for n, (u, _) in vocabulary.items() if u == "rad")
            raise wg.key(g, "angle_of").fail(f"expected one of the model's angle channels "
                                             f"({', '.join(angles)}), got {g['angle_of']!r}")
        runits = _units(g.get("radius_units", "m"), wg.key(g, "radius_units"))
        if UNITS[runits][0] != LENGTH:
            raise wg.key(g, "radius_units").fail(f"expected a length, got {runits!r}")
        model = g.get("model", "arc")
        if model not in ("arc", "sine"):
            raise wg.key(g, "model").fail(f"expected arc or sine, got {model!r}")
        if fit and model != "arc":
            raise wg.key(g, "model").fail("radius: fit reads the displacement on the arc "
                                          "(model: arc) only")
        if si != LENGTH:
            raise where.key(c, "units").fail(
                f"a geometry reads a displacement as an angle: units must be a length, "
                f"got {units!r}")
        if fit:  # stored as the displacement; rig compare fits the radius
            geometry = Geometry(None, model, str(g["angle_of"]))
        else:
            geometry = Geometry(number(g["radius"], wg.key(g, "radius"), positive=True)
                                * UNITS[runits][1], model)
            si = "rad"
    desc = c.get("description", "")
    if not isinstance(desc, str):
        raise where.key(c, "description").fail(f"expected text, got {desc!r}")
    if channel in vocabulary:
        want, doc = vocabulary[channel]
        if si != want:
            if geometry is not None and geometry.fitted:
                raise w.fail(f"radius: fit stores the displacement under a channel of its "
                             f"own: {channel} is the model's; name the sensor (e.g. "
                             f"{str(geometry.angle_of).replace('_angle', '')}_rise)")
            raise (where.key(c, "units") if geometry is None else where.key(c, "geometry")
                   ).fail(f"channel {channel} is stored in {want}, and {units!r}"
                          f"{' through the geometry' if geometry else ''} gives {si}")
        desc = desc or doc
    elif not desc:
        raise w.fail(f"{channel!r} is not a run-file channel ({', '.join(sorted(vocabulary))}); "
                     f"a new channel needs a description")
    steps: list[cal.Step] = []
    if "calibration" in c:
        wc = where.key(c, "calibration")
        seq = c["calibration"]
        if not isinstance(seq, list):
            seq = _Seq([seq])
            seq.line, seq.lines = wc.line, [wc.line]
        steps = [cal.parse_step(s, wc.item(seq, i), number, mapping)
                 for i, s in enumerate(seq)]
    return ColumnMap(source, index, channel, units, si, factor, desc, steps, geometry,
                     where.line)


def load(path: str | Path, vocabulary: Mapping[str, tuple[str, str]]) -> ImportMap:
    """Read and check a map; ``vocabulary``: the run file's channels -> (SI units, meaning)."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: map file not found")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read the map ({exc})") from None
    try:
        raw = yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{p}: {line}not valid YAML ({problem})") from None
    top = Where(str(p), "", 1)
    if not isinstance(raw, _Map):
        raise top.fail("expected a mapping with columns") if raw is not None else \
            InputError(f"{p}: the map is empty")
    m = mapping(raw, top, _TOP)

    def at(key: str) -> Where:
        return Where(str(p), key, m.lines.get(key, 1))

    fmt = m.get("format")
    if fmt is not None and fmt not in FORMATS:
        raise at("format").fail(f"expected one of {', '.join(FORMATS)}, got {fmt!r}")
    header = m.get("header", "auto")
    header = {True: "yes", False: "no", "auto": "auto"}.get(header) \
        if isinstance(header, bool | str) else None
    if header is None:
        raise at("header").fail(f"expected true, false or auto, got {m.get('header')!r}")
    delim = m.get("delimiter")
    if delim is not None and (not isinstance(delim, str) or len(delim) != 1):
        raise at("delimiter").fail(f"expected one character, got {delim!r}")
    rate = None if "sample_rate_hz" not in m else number(m["sample_rate_hz"],
                                                         at("sample_rate_hz"), positive=True)
    tcol: str | int | None = None
    tfactor = 1.0
    if "time" in m:
        wt = at("time")
        t = mapping(m["time"], wt, {"column", "units"})
        if "column" not in t:
            raise wt.fail("column: missing")
        tcol = _column_ref(t["column"], wt.key(t, "column"))
        tu = _units(t.get("units", "s"), wt.key(t, "units"))
        if UNITS[tu][0] != "s":
            raise wt.key(t, "units").fail(f"expected a time unit, got {tu!r}")
        tfactor = UNITS[tu][1]
        if rate is not None:
            raise wt.fail("give either time or sample_rate_hz, not both")
    desc = m.get("description", "")
    if not isinstance(desc, str):
        raise at("description").fail(f"expected text, got {desc!r}")
    if "columns" not in m:
        raise top.fail("columns: missing (a list of the source columns to import)")
    cols_raw = m["columns"]
    wcols = at("columns")
    if not isinstance(cols_raw, list) or not cols_raw:
        raise wcols.fail("expected a non-empty list of columns")
    columns = [_column(c, wcols.item(cols_raw, i), vocabulary) for i, c in enumerate(cols_raw)]
    seen: dict[str, int] = {}
    for i, c in enumerate(columns):
        if c.channel in seen:
            raise wcols.item(cols_raw, i).fail(f"channel {c.channel} is also columns"
                                               f"[{seen[c.channel]}]'s")
        seen[c.channel] = i
    segment = None
    if "segment" in m:
        ws = at("segment")
        s = mapping(m["segment"], ws, _SEGMENT)
        ch = s.get("channel")
        if ch not in seen:
            raise ws.key(s, "channel").fail(f"expected one of the mapped channels "
                                            f"({', '.join(seen)}), got {ch!r}")
        split = s.get("split_repeats", False)
        if not isinstance(split, bool):
            raise ws.key(s, "split_repeats").fail(f"expected true or false, got {split!r}")
        opts = {k: number(v, ws.key(s, k), positive=True) for k, v in s.items()
                if k not in ("channel", "split_repeats")}
        segment = SegmentSpec(str(ch), split, opts)
    return ImportMap(p, text, fmt, header, delim, rate, tcol, tfactor, desc, columns, segment)
