"""Force profiles: the force pressing the key top over time (and motion profiles).

A profile file is YAML with exactly one of three forms of the curve:

    segments:                 # a piecewise-linear recipe, starting at 0 N
      - {hold: 0.02}          # stay at the current force for 0.02 s
      - {ramp: 0.03, to: 30}  # go linearly to 30 N in 0.03 s
    points: [[0, 0], [0.03, 30], ...]   # a table of (time s, force N)
    csv: measured-force.csv # two columns, time and force: a header line naming them
                            # with their units (time,force; t,F; time_ms,force_N;
                            # time [s],force [gf]; any order) or none (time in s
                            # first, force in N); path relative to the YAML file

plus optional ``name``, ``description`` and ``kind``. A bare ``.csv`` file is accepted
too. Between points the force is linear. Everything is checked on load:
times must increase, values must be finite, forces must lie in
[0, limit], the profile may last at most ``max_duration`` (the rig's
``limits.max_profile_s``, default 60 s), files may be at most 10 MB and
unknown keys are refused. Every refusal is one line (``InputError``) naming
the file and the field.

``kind: motion`` makes the curve a *displacement* (m, downward) of the
fingertip's last bone instead of a force, from where the fingertip pulp just
touches the key top at rest (negative: above it). Only the model plays it,
through the ``fingertip`` effect (thesis Section 3.8); ``load`` refuses it
unless the caller accepts it (``kinds``), so a motion file cannot be sent to the
rig's force loop by mistake.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.errors import InputError, not_a_file
from rig.inputs.params import load_yaml_file, read_text_file

DEFAULT_FORCE_LIMIT_N = 120.0  # the motor's peak force on the key (thesis, Section 2.1)
DEFAULT_MAX_DURATION_S = 60.0  # the rig config's limits.max_profile_s default
MAX_FILE_BYTES = 10_000_000  # a profile file (YAML or CSV) larger than this is refused
MAX_POINTS = 1_000_000  # knots in one profile (a 60 s table at 2 kHz has 120 001)
CSV_COLUMNS = ("time_s", "force_N")
_KEYS = {"name", "description", "segments", "points", "csv", "kind"}
KINDS = ("force", "motion")
MOTION_LIMIT_M = 0.05  # a fingertip bone travel beyond 50 mm either way is not a key press


@dataclass(frozen=True)
class Profile:
    """A validated profile: knots (s, N), linear in between; for ``kind="motion"`` the
    values in ``force`` are the fingertip bone's displacement (m, downward)."""

    time: np.ndarray
    force: np.ndarray
    name: str = "profile"
    description: str = ""
    source: str = ""
    kind: str = "force"

    @property
    def duration(self) -> float:
        return float(self.time[-1])

    @property
    def peak(self) -> float:
        return float(self.force.max())

    def at(self, t: float | np.ndarray) -> np.ndarray:
        """Force (N) at time(s) t; held at the end values outside the profile."""
        return np.interp(t, self.time, self.force)

    def to_metadata(self) -> dict[str, Any]:
        meta = {"name": self.name, "description": self.description, "source": self.source}
        if self.kind != "force":
            meta["kind"] = self.kind
        return meta


def _fail(source: str, field: str, expected: str) -> InputError:
    """One line naming the file and field (a quoted value's line breaks become spaces)."""
    return InputError(" ".join(f"{source}: {field}: {expected}".splitlines()))


def _number(value: Any, source: str, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(source, field, f"expected a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise _fail(source, field, f"expected a finite number, got {value!r}")
    return v


def from_points(points: Sequence[Sequence[Any]], *, name: str = "profile", description: str = "",
                source: str = "profile", force_limit: float = DEFAULT_FORCE_LIMIT_N,
                max_duration: float = DEFAULT_MAX_DURATION_S) -> Profile:
    """Build and validate a profile from (time s, force N) pairs."""
    if len(points) < 2:
        raise _fail(source, "points", "expected at least two (time, force) pairs")
    if len(points) > MAX_POINTS:
        raise _fail(source, "points", f"{len(points)} points, more than the {MAX_POINTS} "
                    f"allowed")
    t = np.empty(len(points))
    f = np.empty(len(points))
    for i, pair in enumerate(points):
        if not isinstance(pair, Sequence) or isinstance(pair, str) or len(pair) != 2:
            raise _fail(source, f"points[{i}]", f"expected [time_s, force_N], got {pair!r}")
        t[i] = _number(pair[0], source, f"points[{i}] time")
        f[i] = _number(pair[1], source, f"points[{i}] force")
    return _validated(t, f, name, description, source, force_limit, max_duration)


def _validated(t: np.ndarray, f: np.ndarray, name: str, description: str, source: str,
               force_limit: float, max_duration: float = DEFAULT_MAX_DURATION_S) -> Profile:
    if t[0] < 0:
        raise _fail(source, "points[0] time", f"expected >= 0 s, got {t[0]}")
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise _fail(source, f"points[{i}] time",
                    f"expected time to increase, got {t[i]} s after {t[i - 1]} s")
    if t[-1] > max_duration:
        i = int(np.flatnonzero(t > max_duration)[0])
        raise _fail(source, f"points[{i}] time", f"{t[i]:g} s is beyond the longest profile "
                    f"allowed, {max_duration:g} s (the rig's limits.max_profile_s)")
    neg = np.flatnonzero(f < 0)
    if neg.size:
        i = int(neg[0])
        raise _fail(source, f"points[{i}] force", f"expected >= 0 N (the motor only presses), "
                    f"got {f[i]}")
    over = np.flatnonzero(f > force_limit)
    if over.size:
        i = int(over[0])
        raise _fail(source, f"points[{i}] force",
                    f"{f[i]} N is above the force limit of {force_limit} N")
    return Profile(t, f, name, description, source)


def _from_segments(segments: Any, source: str,
                   max_duration: float = DEFAULT_MAX_DURATION_S) -> list[list[float]]:
    if not isinstance(segments, list) or not segments:
        raise _fail(source, "segments", "expected a non-empty list of {hold: s} / "
                    "{ramp: s, to: N} items")
    if len(segments) > MAX_POINTS:
        raise _fail(source, "segments", f"{len(segments)} segments, more than the "
                    f"{MAX_POINTS} allowed")
    pts: list[list[float]] = [[0.0, 0.0]]
    for i, seg in enumerate(segments):
        where = f"segments[{i}]"
        if not isinstance(seg, Mapping):
            raise _fail(source, where, f"expected a mapping, got {seg!r}")
        keys = set(seg)
        t, f = pts[-1]
        if keys == {"hold"}:
            dt = _number(seg["hold"], source, f"{where}.hold")
            pts.append([t + dt, f])
        elif keys == {"ramp", "to"}:
            dt = _number(seg["ramp"], source, f"{where}.ramp")
            pts.append([t + dt, _number(seg["to"], source, f"{where}.to")])
        elif keys == {"start"}:
            if i != 0:
                raise _fail(source, where, "start is allowed only as the first segment")
            pts[0][1] = _number(seg["start"], source, f"{where}.start")
        else:
            raise _fail(source, where, f"expected {{hold: s}} or {{ramp: s, to: N}}, got keys "
                        f"{sorted(keys)}")
        if pts[-1][0] <= t:
            raise _fail(source, where, "expected a positive duration")
        if pts[-1][0] > max_duration:
            raise _fail(source, where, f"the profile would last {pts[-1][0]:g} s, longer than "
                        f"the {max_duration:g} s allowed (the rig's limits.max_profile_s)")
    return pts


# A CSV column's header: a name, then its unit as `name_unit`, `name [unit]`,
# `name (unit)`, `name/unit` or `name in unit`, or no unit (SI: s, N).
_HEADER = re.compile(r"^\s*(?P<name>[A-Za-z]+?)\s*(?:(?:_|/|\s+in\s+)\s*(?P<u1>[^\s\[\]()/]+)"
                     r"|[\[(]\s*(?P<u2>[^\]\)]+?)\s*[\])])?\s*$")
_G0 = 9.80665  # standard gravity, m/s^2: grams-force and pounds-force in newtons
CSV_NAMES = {"time": ("time", "t"), "force": ("force", "f")}  # lower case
CSV_UNITS: dict[str, dict[str, float]] = {  # each column's units, factor to SI
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6, "min": 60.0},
    "force": {"N": 1.0, "mN": 1e-3, "kN": 1e3, "gf": _G0 * 1e-3, "g": _G0 * 1e-3,
              "kgf": _G0, "lbf": 0.45359237 * _G0, "ozf": 0.028349523125 * _G0},
}


def _csv_unit(quantity: str, unit: str | None) -> float | None:
    """The factor from ``unit`` to SI for a column of ``quantity``; None if unknown. Case
    is ignored where that leaves one unit (`force_n`, `TIME_MS`)."""
    units = CSV_UNITS[quantity]
    if unit is None:
        return 1.0
    if unit in units:
        return units[unit]
    folded = [f for u, f in units.items() if u.lower() == unit.lower()]
    return folded[0] if len(folded) == 1 else None


def csv_header(cells: Sequence[str], path: Path, n: int) -> tuple[tuple[int, int],
                                                                    tuple[float, float]]:
    """The columns of time and force a header line names, and their factors to s and N:
    `time,force`, `t,F`, `time_s,force_N`, `time [ms],force [gf]`, in any order. An unknown
    column name or unit is one line naming the file, line and column."""
    found: dict[str, tuple[int, float]] = {}
    for i, cell in enumerate(cells):
        m = _HEADER.match(cell)
        quantity = next((q for q, names in CSV_NAMES.items()
                         if m and m["name"].lower() in names), None)
        if m is None or quantity is None:
            raise _fail(str(path), f"line {n} column {i + 1} {cell.strip()!r}",
                        "expected a time column (time, t, time_s, time [ms], ...) and a force "
                        "column (force, F, force_N, force [N], ...)")
        unit = m["u1"] or m["u2"]
        factor = _csv_unit(quantity, unit)
        if factor is None:
            raise _fail(str(path), f"line {n} column {cell.strip()!r}",
                        f"unknown {quantity} unit {unit!r} (known: "
                        f"{', '.join(CSV_UNITS[quantity])})")
        if quantity in found:
            raise _fail(str(path), f"line {n} header", f"two {quantity} columns: {list(cells)}")
        found[quantity] = (i, factor)
    return ((found["time"][0], found["force"][0]), (found["time"][1], found["force"][1]))


def _csv_cell(text: str, path: Path, n: int, column: str, decimal_comma: bool) -> float:
    try:
        return float(text.replace(",", ".") if decimal_comma else text)
    except ValueError:
        raise _fail(str(path), f"line {n} {column}", f"expected a number, got {text.strip()!r}") \
            from None


def _delimiter(lines: list[str]) -> str:
    """`,` unless the file's first lines are separated by `;` (a spreadsheet in a locale
    with a decimal comma) or tabs, and have no commas outside numbers."""
    sample = [line for line in lines[:20] if line.strip() and not line.startswith("#")]
    for sep in (";", "\t"):
        if sample and all(sep in line for line in sample):
            return sep
    return ","


def _read_csv(path: Path, source: str) -> list[list[Any]]:
    """Rows (time s, force N) of a two-column CSV, with a header line naming the columns
    and their units (see `csv_header`; any order) or without one (time s first, force N).
    `;`- or tab-separated files are read too, a `;`-separated one with decimal commas
    (`0,01;3,5`); lines starting with `#` are comments."""
    if not path.is_file():
        raise _fail(source, "csv", f"{path}: {not_a_file(path)}")
    lines = read_text_file(path, MAX_FILE_BYTES).removeprefix("\ufeff").splitlines()
    sep = _delimiter(lines)
    rows: list[list[Any]] = []
    order, factors = (0, 1), (1.0, 1.0)  # columns of time and force; to s and N
    first = True
    reader = csv.reader(lines, delimiter=sep)
    names = CSV_COLUMNS
    try:
        for n, row in enumerate(reader, start=1):
            cells = [c.strip() for c in row]
            while cells and not cells[-1]:
                cells.pop()
            if not cells or cells[0].startswith("#"):
                continue
            if len(cells) != 2:
                raise _fail(str(path), f"line {n}", f"expected two columns, time and force, "
                            f"got {len(cells)}")
            if first:
                first = False
                try:
                    [float(c.replace(",", ".") if sep == ";" else c) for c in cells]
                except ValueError:
                    order, factors = csv_header(cells, path, n)
                    names = (cells[order[0]], cells[order[1]])
                    continue
            rows.append([_csv_cell(cells[order[0]], path, n, names[0], sep == ";") * factors[0],
                         _csv_cell(cells[order[1]], path, n, names[1], sep == ";") * factors[1]])
            if len(rows) > MAX_POINTS:
                raise _fail(str(path), f"line {n}", f"more than the {MAX_POINTS} points "
                            f"allowed")
    except csv.Error as exc:
        raise _fail(str(path), f"line {reader.line_num}", f"not valid CSV ({exc})") from None
    return rows


def motion_from_points(points: Sequence[Sequence[Any]], *, name: str = "motion",
                       description: str = "", source: str = "profile",
                       max_duration: float = DEFAULT_MAX_DURATION_S) -> Profile:
    """A motion profile from (time s, displacement m) pairs of the fingertip's last bone."""
    if len(points) < 2:
        raise _fail(source, "points", "expected at least two (time, displacement) pairs")
    t = np.empty(len(points))
    x = np.empty(len(points))
    for i, pair in enumerate(points):
        if not isinstance(pair, Sequence) or isinstance(pair, str) or len(pair) != 2:
            raise _fail(source, f"points[{i}]", f"expected [time_s, displacement_m], got "
                        f"{pair!r}")
        t[i] = _number(pair[0], source, f"points[{i}] time")
        x[i] = _number(pair[1], source, f"points[{i}] displacement")
    if t[0] < 0:
        raise _fail(source, "points[0] time", f"expected >= 0 s, got {t[0]}")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise _fail(source, f"points[{i}] time",
                    f"expected time to increase, got {t[i]} s after {t[i - 1]} s")
    if t[-1] > max_duration:
        raise _fail(source, f"points[{len(t) - 1}] time", f"{t[-1]:g} s: longer than the "
                    f"{max_duration:g} s allowed (the rig's limits.max_profile_s)")
    far = np.flatnonzero(np.abs(x) > MOTION_LIMIT_M)
    if far.size:
        i = int(far[0])
        raise _fail(source, f"points[{i}] displacement", f"expected within +-{MOTION_LIMIT_M} m "
                    f"(metres, not mm), got {x[i]}")
    return Profile(t, x, name, description, source, "motion")


def load(path: str | Path, force_limit: float = DEFAULT_FORCE_LIMIT_N,
         kinds: Sequence[str] = ("force",),
         max_duration: float = DEFAULT_MAX_DURATION_S) -> Profile:
    """Load and validate a profile file (YAML or CSV) of one of ``kinds``; every refusal is
    a one-line ``InputError`` naming the file."""
    p = Path(path)
    if p.suffix.lower() == ".csv":
        return from_points(_read_csv(p, str(p)), name=p.stem, source=str(p),
                           force_limit=force_limit, max_duration=max_duration)
    data = load_yaml_file(p, MAX_FILE_BYTES)
    if not isinstance(data, Mapping):
        raise InputError(f"{p}: expected a mapping with segments, points or csv")
    unknown = sorted(set(map(str, data)) - _KEYS)
    if unknown:
        raise _fail(str(p), unknown[0], f"unknown key (expected one of {sorted(_KEYS)})")
    forms = [k for k in ("segments", "points", "csv") if k in data]
    if len(forms) != 1:
        raise InputError(f"{p}: expected exactly one of segments, points or csv, got {forms}")
    for key in ("name", "description"):
        if key in data and not isinstance(data[key], str | int | float):
            raise _fail(str(p), key, f"expected text, got {type(data[key]).__name__}")
    name = str(data.get("name", p.stem))
    desc = str(data.get("description", ""))
    kind = data.get("kind", "force")
    if kind not in KINDS:
        raise _fail(str(p), "kind", f"expected one of {', '.join(KINDS)}, got {kind!r}")
    if kind not in kinds:
        raise _fail(str(p), "kind", f"{kind}: this command needs a {' or '.join(kinds)} "
                    f"profile (a motion profile drives the model only: rig simulate PROFILE "
                    f"-e fingertip)")
    if forms[0] == "segments":
        pts: Sequence[Sequence[Any]] = _from_segments(data["segments"], str(p), max_duration)
    elif forms[0] == "points":
        if not isinstance(data["points"], list):
            raise _fail(str(p), "points", "expected a list of [time_s, force_N] pairs")
        pts = data["points"]
    else:
        if not isinstance(data["csv"], str) or not data["csv"].strip():
            raise _fail(str(p), "csv", f"expected a file name, got {data['csv']!r}")
        pts = _read_csv(p.parent / data["csv"], str(p))
    if kind == "motion":
        return motion_from_points(pts, name=name, description=desc, source=str(p),
                                  max_duration=max_duration)
    return from_points(pts, name=name, description=desc, source=str(p), force_limit=force_limit,
                       max_duration=max_duration)
