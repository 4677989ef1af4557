"""Calibration steps of an import map, applied in order to a source column.

    linear:     {scale: a, offset: b}                 y = a x + b
    normalize:  {zero: z, span: s}                    y = (x - z) / s
    polynomial: [c0, c1, c2, ...]                     y = c0 + c1 x + c2 x^2 + ...
    lookup:     {table: [[..], ..], columns: [value, reading],
                 interpolation: linear | pchip, out_of_range: refuse | clip}
                y = the table's value at reading x: piecewise linear, or monotone cubic
                (PCHIP, the curve of scipy's PchipInterpolator: no overshoot)
    tare:       {seconds: T}                          y = x - median(x over the first T s)

A lookup table is a measured calibration: the readings must be strictly monotone. A
sample outside the table's readings is refused (``refuse``, the default) or clipped to
the table's end (``clip``); the number clipped is counted and stored in the run file.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rig.errors import InputError

KINDS = ("linear", "normalize", "polynomial", "lookup", "tare")


@dataclass
class Result:
    values: np.ndarray
    clipped: int = 0
    out_of_range: np.ndarray | None = None  # the samples clipped (a lookup's), if any


class Step(abc.ABC):
    """One calibration step of a column: raw values in, calibrated values out."""

    kind = ""

    @abc.abstractmethod
    def apply(self, x: np.ndarray, t: np.ndarray, where: str) -> Result:
        """The step applied to ``x`` (sampled at ``t``); ``where`` names it in errors."""

    @abc.abstractmethod
    def describe(self) -> dict[str, Any]:
        """The step as the map writes it (stored in the run file's provenance)."""


@dataclass
class Linear(Step):
    scale: float
    offset: float
    kind = "linear"

    def apply(self, x: np.ndarray, t: np.ndarray, where: str) -> Result:
        return Result(self.scale * x + self.offset)

    def describe(self) -> dict[str, Any]:
        return {"linear": {"scale": self.scale, "offset": self.offset}}


@dataclass
class Normalize(Step):
    zero: float
    span: float
    kind = "normalize"

    def apply(self, x: np.ndarray, t: np.ndarray, where: str) -> Result:
        return Result((x - self.zero) / self.span)

    def describe(self) -> dict[str, Any]:
        return {"normalize": {"zero": self.zero, "span": self.span}}


@dataclass
class Polynomial(Step):
    coefficients: list[float]  # ascending powers
    kind = "polynomial"

    def apply(self, x: np.ndarray, t: np.ndarray, where: str) -> Result:
        return Result(np.polynomial.polynomial.polyval(x, self.coefficients))

    def describe(self) -> dict[str, Any]:
        return {"polynomial": list(self.coefficients)}


@dataclass
class Lookup(Step):
    reading: np.ndarray   # strictly increasing
    value: np.ndarray
    interpolation: str = "linear"
    out_of_range: str = "refuse"
    kind = "lookup"

    def apply(self, x: np.ndarray, t: np.ndarray, where: str) -> Result:
        lo, hi = float(self.reading[0]), float(self.reading[-1])
        out = (x < lo) | (x > hi)
        n_out = int(np.count_nonzero(out))
        if n_out and self.out_of_range == "refuse":
            i = int(np.argmax(out))
            raise InputError(f"{where}: {n_out} samples outside the lookup table's readings "
                             f"[{lo:g}, {hi:g}], the first at sample {i} ({x[i]:g}); give "
                             f"out_of_range: clip to clip them")
        xc = np.clip(x, lo, hi)
        if self.interpolation == "linear":
            return Result(np.interp(xc, self.reading, self.value), n_out, out)
        return Result(pchip(self.reading, self.value, xc), n_out, out)

    def describe(self) -> dict[str, Any]:
        return {"lookup": {"reading": self.reading.tolist(), "value": self.value.tolist(),
                           "interpolation": self.interpolation,
                           "out_of_range": self.out_of_range}}


@dataclass
class Tare(Step):
    seconds: float
    kind = "tare"

    def apply(self, x: np.ndarray, t: np.ndarray, where: str) -> Result:
        first = t <= t[0] + self.seconds
        return Result(x - float(np.median(x[first])))

    def describe(self) -> dict[str, Any]:
        return {"tare": {"seconds": self.seconds}}


def pchip_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The Fritsch-Carlson slopes of the monotone cubic through (x, y) (x increasing), as
    scipy's PchipInterpolator takes them: the weighted harmonic mean of the secants where
    they agree in sign, 0 where they do not, and the shape-preserving three-point formula
    at the ends."""
    h = np.diff(x)
    m = np.diff(y) / h
    if x.size == 2:
        return np.array([m[0], m[0]])
    d = np.zeros_like(y)
    w1 = 2 * h[1:] + h[:-1]
    w2 = h[1:] + 2 * h[:-1]
    same = (np.sign(m[1:]) == np.sign(m[:-1])) & (m[1:] != 0) & (m[:-1] != 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        harmonic = (w1 + w2) / (w1 / m[:-1] + w2 / m[1:])
    d[1:-1] = np.where(same, harmonic, 0.0)

    def edge(h0: float, h1: float, m0: float, m1: float) -> float:
        e = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
        if np.sign(e) != np.sign(m0):
            return 0.0
        if np.sign(m0) != np.sign(m1) and abs(e) > 3 * abs(m0):
            return 3 * m0
        return float(e)

    d[0] = edge(h[0], h[1], m[0], m[1])
    d[-1] = edge(h[-1], h[-2], m[-1], m[-2])
    return d


def pchip(x: np.ndarray, y: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """The monotone piecewise cubic (PCHIP) through (x, y) at ``xi`` (inside [x0, xn]):
    the same curve as scipy.interpolate.PchipInterpolator, without importing
    scipy.interpolate (a second of a fresh process)."""
    d = pchip_slopes(x, y)
    k = np.clip(np.searchsorted(x, xi, side="right") - 1, 0, x.size - 2)
    h = x[k + 1] - x[k]
    s = (xi - x[k]) / h
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * y[k] + (s3 - 2 * s2 + s) * h * d[k]
            + (-2 * s3 + 3 * s2) * y[k + 1] + (s3 - s2) * h * d[k + 1])


def parse_step(raw: Any, where: Any, number: Callable[..., float],
               mapping: Callable[..., Any]) -> Step:
    """One step from the map (``where``: rig.recordings.mapfile.Where)."""
    if not isinstance(raw, dict) or len(raw) != 1:
        raise where.fail(f"expected one of {', '.join(KINDS)} (a mapping with one key), "
                         f"got {raw!r}")
    kind, body = next(iter(raw.items()))
    w = where.key(raw, kind)
    if kind == "linear":
        b = mapping(body, w, {"scale", "offset"})
        return Linear(number(b.get("scale", 1.0), w.key(b, "scale")),
                      number(b.get("offset", 0.0), w.key(b, "offset")))
    if kind == "normalize":
        b = mapping(body, w, {"zero", "span"})
        span = number(b.get("span", 1.0), w.key(b, "span"))
        if span == 0:
            raise w.key(b, "span").fail("must not be 0")
        return Normalize(number(b.get("zero", 0.0), w.key(b, "zero")), span)
    if kind == "polynomial":
        if not isinstance(body, list) or not body:
            raise w.fail(f"expected the coefficients [c0, c1, ...] (ascending powers), "
                         f"got {body!r}")
        return Polynomial([number(c, w.item(body, i)) for i, c in enumerate(body)])
    if kind == "tare":
        b = mapping(body, w, {"seconds"})
        return Tare(number(b.get("seconds"), w.key(b, "seconds"), positive=True))
    if kind == "lookup":
        return _lookup(body, w, number, mapping)
    raise where.fail(f"unknown calibration {kind!r} (expected one of {', '.join(KINDS)})")


def _lookup(body: Any, w: Any, number: Callable[..., float], mapping: Callable[..., Any]
            ) -> Lookup:
    b = mapping(body, w, {"table", "columns", "interpolation", "out_of_range"})
    cols = b.get("columns", ["reading", "value"])
    wc = w.key(b, "columns")
    if not isinstance(cols, list) or sorted(map(str, cols)) != ["reading", "value"]:
        raise wc.fail(f"expected [reading, value] or [value, reading], got {cols!r}")
    interp = b.get("interpolation", "linear")
    if interp not in ("linear", "pchip"):
        raise w.key(b, "interpolation").fail(f"expected linear or pchip, got {interp!r}")
    oor = b.get("out_of_range", "refuse")
    if oor not in ("refuse", "clip"):
        raise w.key(b, "out_of_range").fail(f"expected refuse or clip, got {oor!r}")
    wt = w.key(b, "table")
    table = b.get("table")
    if not isinstance(table, list) or len(table) < 2:
        raise wt.fail("expected a list of at least two [reading, value] rows")
    rows = []
    for i, row in enumerate(table):
        wr = wt.item(table, i)
        if not isinstance(row, list) or len(row) != 2:
            raise wr.fail(f"expected a row of two numbers, got {row!r}")
        rows.append((number(row[0], wr), number(row[1], wr)))
    arr = np.asarray(rows)
    ir = cols.index("reading")
    reading, value = arr[:, ir], arr[:, 1 - ir]
    d = np.diff(reading)
    if not (np.all(d > 0) or np.all(d < 0)):
        i = int(np.argmax(d <= 0) if d[0] > 0 else np.argmax(d >= 0)) + 1
        raise wt.item(table, i).fail(
            f"the readings must be strictly increasing or decreasing (row {i}: "
            f"{reading[i]:g} after {reading[i - 1]:g})")
    if d[0] < 0:
        reading, value = reading[::-1], value[::-1]
    return Lookup(np.ascontiguousarray(reading), np.ascontiguousarray(value), interp, oor)


def apply(steps: list[Step], x: np.ndarray, t: np.ndarray, where: str
          ) -> tuple[np.ndarray, int, np.ndarray]:
    """The steps in order; returns the values, the number of samples a lookup clipped and
    which (True: outside the sensor's calibrated range)."""
    clipped = 0
    y = np.asarray(x, float)
    out = np.zeros(y.shape, bool)
    for s in steps:
        r = s.apply(y, t, where)
        y, clipped = r.values, clipped + r.clipped
        if r.out_of_range is not None:
            out |= r.out_of_range
    return y, clipped, out
