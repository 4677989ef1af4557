"""`rig import`: other labs' recordings (text, TDMS, HDF5) into a run file, through a map.

Each source file is read (rig.recordings.readers), its mapped columns calibrated
(rig.recordings.calibration) into the run file's channels, and -- when the map has a
``segment`` section -- split into one trial per stroke (rig.recordings.segment); without
it every file is one trial. The run file is written to a temporary file beside ``out``
and renamed at the end: a refused or failed import leaves nothing. Format of the map and
the stored provenance: docs/import.md.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig.analysis import events
from rig.errors import InputError, refuse_existing
from rig.recordings import calibration as cal
from rig.recordings import mapfile, readers, runfile
from rig.recordings import segment as sg
from rig.recordings.channels import EVENT_DOCS

SOURCE = "imported"


def vocabulary() -> dict[str, tuple[str, str]]:
    """The run file's channels: name -> (SI units, meaning)."""
    from rig.recordings.channels import CHANNELS

    return dict(CHANNELS)


@dataclass
class Recording:
    """One source file's calibrated channels on its time base."""

    path: Path
    format: str
    sha256: str
    size: int
    time: np.ndarray
    channels: dict[str, np.ndarray]
    clipped: dict[str, int]
    out_of_range: dict[str, np.ndarray] = field(default_factory=dict)  # clipped samples
    segmentation: sg.Segmentation | None = None

    def provenance(self) -> dict[str, Any]:
        return {"file": str(self.path), "name": self.path.name, "format": self.format,
                "sha256": self.sha256, "bytes": self.size, "samples": int(self.time.size),
                "duration_s": float(self.time[-1] - self.time[0]),
                "clipped_samples": dict(self.clipped)}


@dataclass
class TrialRow:
    """One trial of the imported run (the printed and stored table)."""

    trial: int
    file: str
    onset_s: float
    release_s: float
    duration_s: float
    peak: float
    peak_s: float
    presses: int
    samples: int

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class ImportResult:
    out: Path
    recordings: list[Recording]
    trials: list[TrialRow]
    segment_channel: str | None
    segment_units: str = ""
    warnings: list[str] = field(default_factory=list)  # events out of a blow's order


def _sha256(path: Path) -> tuple[str, int]:
    h = hashlib.sha256()
    size = 0
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
            size += len(chunk)
    return h.hexdigest(), size


def _time_base(m: mapfile.ImportMap, table: readers.Table, n: int) -> np.ndarray:
    path = table.path
    if m.time_column is not None:
        t = table.get(m.time_column) * m.time_factor
        if not np.all(np.isfinite(t)):
            raise InputError(f"{path}: time column {m.time_column!r}: not every value is a "
                             f"number")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise InputError(f"{path}: time column {m.time_column!r}: not increasing at "
                             f"sample {int(bad[0]) + 1} ({t[bad[0]]:g} then "
                             f"{t[bad[0] + 1]:g} s)")
        return t - t[0]
    rate = m.sample_rate_hz
    if rate is None:
        dts = {table.dt[str(c.source)] for c in m.columns if str(c.source) in table.dt}
        if len(dts) > 1:
            raise InputError(f"{path}: the mapped TDMS channels state different sample "
                             f"intervals ({sorted(dts)}); map them from separate files")
        if not dts:
            raise InputError(f"{m.path}: sample_rate_hz: missing (give sample_rate_hz or "
                             f"time; {path.name} states no sample interval)")
        return np.arange(n) * dts.pop()
    return np.arange(n) / rate


def read_recording(m: mapfile.ImportMap, path: Path) -> Recording:
    """One source file through the map."""
    fmt = m.format_of(path)
    wanted: list[str | int] = [c.source for c in m.columns]
    if m.time_column is not None:
        wanted.append(m.time_column)
    table = readers.read(path, fmt, m.header, m.delimiter, wanted)
    digest, size = _sha256(path)
    raw = {c.channel: table.get(c.source, c.index) for c in m.columns}
    lengths = {len(v) for v in raw.values()}
    if len(lengths) != 1:
        raise InputError(f"{path}: the mapped columns differ in length "
                         f"({', '.join(f'{k}: {len(v)}' for k, v in raw.items())})")
    n = lengths.pop()
    if n < 2:
        raise InputError(f"{path}: fewer than two samples")
    t = _time_base(m, table, n)
    if t.size != n:
        raise InputError(f"{path}: the time column has {t.size} samples, the data {n}")
    channels: dict[str, np.ndarray] = {}
    clipped: dict[str, int] = {}
    out_of_range: dict[str, np.ndarray] = {}
    for c in m.columns:
        x = raw[c.channel]
        bad = np.flatnonzero(~np.isfinite(x))
        if bad.size:
            raise InputError(f"{path}: column {c.source!r}: sample {int(bad[0])} is not a "
                             f"finite number")
        where = f"{path}: column {c.source!r} ({m.path.name} line {c.line}, {c.channel})"
        y, nclip, oor = cal.apply(c.steps, x, t, where)
        y = y * c.factor
        if c.geometry is not None and not c.geometry.fitted:
            y = c.geometry.angle(y)
        if not np.all(np.isfinite(y)):
            raise InputError(f"{where}: the calibration gives values that are not finite")
        channels[c.channel] = y
        clipped[c.channel] = nclip
        out_of_range[c.channel] = oor
    return Recording(path, fmt, digest, size, t, channels, clipped, out_of_range)


def import_files(files: Sequence[Path], map_path: Path, out: Path, *, force: bool = False,
                 split_repeats: bool | None = None, segment: bool = True) -> ImportResult:
    """Import ``files`` through the map at ``map_path`` into the run file ``out``."""
    if not files:
        raise InputError("FILE: give at least one recording to import")
    refuse_existing(out, force, "out")
    m = mapfile.load(map_path, vocabulary())
    for f in files:
        if Path(f).resolve() == Path(out).resolve():
            raise InputError(f"out: {out} is also a source file")
    recs = [read_recording(m, Path(f)) for f in files]
    spec = m.segment if segment else None
    split = spec.split_repeats if spec is not None and split_repeats is None \
        else bool(split_repeats)
    if split_repeats and not segment:
        raise InputError("--split-repeats: not with --whole (which keeps each file whole)")
    if split_repeats and spec is None:
        raise InputError(f"--split-repeats: {m.path} has no segment section (which channel "
                         f"is the key's)")
    rows: list[TrialRow] = []
    pieces: list[tuple[Recording, int, int, sg.Stroke | None]] = []
    for rec in recs:
        if spec is None:
            pieces.append((rec, 0, rec.time.size, None))
            continue
        seg = sg.segment(rec.time, rec.channels[spec.channel], split_repeats=split,
                         options=spec.options)
        rec.segmentation = seg
        if not seg.strokes:
            raise InputError(f"{rec.path}: segment: no stroke found on {spec.channel} (its "
                             f"travel never exceeds {seg.on:.3g} above the rest level "
                             f"{seg.rest:.4g})")
        pieces += [(rec, s.start, s.stop, s) for s in seg.strokes]
    stored_units = {c.channel: c.stored_units for c in m.columns}
    for k, (rec, a, b, s) in enumerate(pieces):
        t0 = float(rec.time[s.i_onset]) if s is not None else float(rec.time[0])
        rows.append(TrialRow(k, rec.path.name, t0, s.release_s if s else float(rec.time[-1]),
                             s.duration_s if s else float(rec.time[-1] - rec.time[0]),
                             s.peak if s else float("nan"), s.peak_s if s else float("nan"),
                             s.presses if s else 0, b - a))
    warnings = _write(out, m, recs, pieces, rows, stored_units, split, force)
    return ImportResult(out, recs, rows, spec.channel if spec else None,
                        stored_units.get(spec.channel, "") if spec else "", warnings)


def _write(out: Path, m: mapfile.ImportMap, recs: list[Recording],
           pieces: list[tuple[Recording, int, int, sg.Stroke | None]], rows: list[TrialRow],
           units: dict[str, str], split: bool, force: bool) -> list[str]:
    """Write the run file; returns the warnings (events found out of the order of a
    blow, per trial: stored as the trial's ``event_order_flags`` too)."""
    warnings: list[str] = []
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    cols = {c.channel: c for c in m.columns}
    meta: dict[str, Any] = {
        "import": {"map_file": str(m.path), "map_sha256": hashlib.sha256(
            m.text.encode()).hexdigest(), "description": m.description,
            "files": [r.provenance() for r in recs],
            "columns": [c.to_dict() for c in m.columns],
            "segmentation": [r.segmentation.describe() if r.segmentation else None
                             for r in recs]},
        "import_map": m.text,
        "segments": [r.as_dict() for r in rows],
    }
    try:
        with runfile.RunWriter(tmp, "measured") as w:
            w.add_metadata("import_map", m.text, "yaml")
            for name, value in meta.items():
                if name != "import_map":
                    w.add_metadata(name, value)
            for k, (rec, a, b, s) in enumerate(pieces):
                tr = w.trial(k)
                t0 = float(rec.time[s.i_onset]) if s is not None else float(rec.time[0])
                data = {"time": rec.time[a:b] - t0,
                        **{n: v[a:b] for n, v in rec.channels.items()}}
                units_k = {"time": "s", **units}
                docs = {"time": "time since the stroke's onset (s; the recording's clock "
                                "minus the trial's t0)" if s is not None else
                                "time since the recording's first sample",
                        **{n: cols[n].description for n in rec.channels}}
                tr.append("channels", data, units_k, docs)
                for n in rec.channels:
                    ds = tr.group["channels"][n]
                    ds.attrs["source"] = f"{rec.path.name}: column {cols[n].source}"
                    ds.attrs["clipped_samples"] = rec.clipped[n]
                found = events.found(data["time"], data, out_of_range={
                    n: v[a:b] for n, v in rec.out_of_range.items()})
                flags = events.order_flags({n: e.time for n, e in found.items()},
                                           0.5 * float(np.median(np.diff(data["time"]))))
                warnings += [f"trial {k}: events out of the order of a blow: {f}"
                             for f in flags]
                if found:
                    tr.write_events({n: e.time for n, e in found.items()}, EVENT_DOCS,
                                    source=events.SOURCE,
                                    methods={n: e.method for n, e in found.items()},
                                    intervals={n: (e.low, e.high) for n, e in found.items()})
                row = rows[k]
                tr.set_attrs(status="complete", t0=t0, source_file=rec.path.name,
                             onset_s=row.onset_s, release_s=row.release_s,
                             presses=row.presses)
                if flags:
                    tr.set_attrs(event_order_flags=flags)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    refuse_existing(out, force, "out")  # appeared while importing
    os.replace(tmp, out)
    return warnings
