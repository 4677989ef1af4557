"""Run files: one HDF5 layout for simulated, synthetic and measured blows.

    /                      attrs: format="rig-run", format_version, kind, status,
                                  created, software_version, git_commit, host, n_trials
    /metadata/<name>       text datasets (YAML or JSON): model, profile, rig_config,
                           calibrations, ... ; attr "format" = yaml | json | text
    /trial_000/            attrs: status, t0 (s, start of this trial on the run clock)
        channels/<name>    on one time base, ``time`` first; attrs units, description;
                           2-D channels (one column per contact) also carry ``columns``
        commands/<name>    the 500 Hz loop's records (measured runs): time, demand, ...
        events/<name>      scalar event times (s), NaN if the event did not happen

Every dataset has a ``units`` attribute (SI). Writers append in chunks and flush,
so a file is readable (with all samples so far) even if the writer dies; the
root ``status`` is ``running`` until the writer closes it as ``complete`` or
``aborted: <reason>``. See docs/run-file.md.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import platform
import subprocess
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from rig.errors import InputError, not_a_file
from rig.version import __version__

FORMAT = "rig-run"
FORMAT_VERSION = 1
KINDS = ("simulated", "synthetic", "measured")


def git_commit() -> str:
    """The source tree's git commit, or 'unknown' outside a checkout."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                             capture_output=True, text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip() or "unknown"


def _text(value: Any) -> tuple[str, str]:
    if isinstance(value, str):
        return value, "text"
    return json.dumps(value, indent=1, default=_json_default), "json"


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot store {type(obj).__name__} in run-file metadata")


metadata_text = _text          # (value -> (text, format)): the journal stores metadata alike
json_default = _json_default   # numpy values in JSON


# names of run files written before the technicians' names (old -> new); old files are
# recognised by their "escapement" event (the old "let_off" was the toe meeting the button)
LEGACY_EVENT_NAMES = {"let_off": "toe_meets_button", "escapement": "let_off",
                      "backcheck_catch": "check"}


def current_event_names(events: Mapping[str, float]) -> dict[str, float]:
    """Events under today's names; an old run file's events (with "escapement") renamed."""
    if "escapement" not in events:
        return dict(events)
    return {LEGACY_EVENT_NAMES.get(n, n): v for n, v in events.items()}

# descriptions of the datasets every section has, when the writer gives none
DEFAULT_DOCS = {"time": "time since the trial's start (0 = profile start)"}
SCALE = "DIMENSION_SCALE"


def _is_scale(ds: h5py.Dataset) -> bool:
    cls = ds.attrs.get("CLASS")
    return (cls.decode() if isinstance(cls, bytes) else str(cls)) == SCALE


def _column_scale(grp: h5py.Group, name: str, columns: Iterable[Any]) -> h5py.Dataset:
    """The dimension scale labelling a 2-D dataset's columns: shared by every dataset with
    the same labels and the same name prefix (``contact_force``, ``contact_slip``, ... share
    ``contact``), else ``<name>_column``."""
    values = np.asarray(list(columns))
    for dim in (name.split("_")[0], f"{name}_column"):
        if dim in grp:
            have = grp[dim]
            if _is_scale(have) and have.shape == values.shape and np.array_equal(
                    have[()].astype(values.dtype) if values.dtype.kind != "U" else
                    np.asarray(have.asstr()[()]), values):
                return have
            continue
        if values.dtype.kind == "U":
            scale = grp.create_dataset(dim, data=values.astype(object),
                                       dtype=h5py.string_dtype())
        else:
            scale = grp.create_dataset(dim, data=values)
        scale.attrs["units"] = "1"
        scale.attrs["long_name"] = f"column label of {name}"
        scale.make_scale(dim)
        return scale
    raise RuntimeError(f"{grp.name}/{name}: no free name for its column scale")


def _attach_scales(grp: h5py.Group, name: str, ds: h5py.Dataset,
                   columns: Iterable[Any] | None) -> None:
    """Time as the HDF5 dimension scale of every dataset's rows (so netCDF readers such as
    xarray see ``time`` as the coordinate), and the column labels of 2-D datasets."""
    if name == "time" and ds.ndim == 1:
        ds.make_scale("time")
        for other in grp.values():
            if other.name != ds.name and not _is_scale(other):
                other.dims[0].attach_scale(ds)
    elif "time" in grp and _is_scale(grp["time"]):
        ds.dims[0].attach_scale(grp["time"])
    if columns is not None and ds.ndim == 2:
        ds.dims[1].attach_scale(_column_scale(grp, name, columns))


class TrialWriter:
    """Channels, commands and events of one trial (appendable)."""

    def __init__(self, group: h5py.Group) -> None:
        self.group = group

    def _dataset(self, section: str, name: str, units: str, description: str,
                 columns: Iterable[Any] | None, width: int | None) -> h5py.Dataset:
        grp = self.group.require_group(section)
        if name in grp:
            return grp[name]
        shape = (0,) if width is None else (0, width)
        maxshape = (None,) if width is None else (None, width)
        chunks = (4096,) if width is None else (1024, width)
        ds = grp.create_dataset(name, shape=shape, maxshape=maxshape, dtype="f8", chunks=chunks)
        ds.attrs["units"] = units
        description = description or DEFAULT_DOCS.get(name, "")
        if description:
            ds.attrs["description"] = description
            ds.attrs["long_name"] = description
        if columns is not None:
            ds.attrs["columns"] = np.asarray(list(columns))
        _attach_scales(grp, name, ds, columns)
        return ds

    def append(self, section: str, data: Mapping[str, np.ndarray], units: Mapping[str, str],
               descriptions: Mapping[str, str] | None = None,
               columns: Mapping[str, Iterable[Any]] | None = None) -> None:
        """Append rows to datasets of ``section`` (channels or commands)."""
        for name, values in data.items():
            arr = np.asarray(values, dtype=float)
            if name not in units:
                raise InputError(f"{section}/{name}: no units given")
            width = arr.shape[1] if arr.ndim == 2 else None
            ds = self._dataset(section, name, units[name], (descriptions or {}).get(name, ""),
                               (columns or {}).get(name), width)
            n0 = ds.shape[0]
            ds.resize(n0 + arr.shape[0], axis=0)
            ds[n0:] = arr

    def write_events(self, events: Mapping[str, float], descriptions: Mapping[str, str]
                     | None = None, *, source: str | None = None,
                     methods: Mapping[str, str] | None = None,
                     intervals: Mapping[str, tuple[float, float]] | None = None) -> None:
        """Scalar event times (s); ``source`` (e.g. found in the measured channels), each
        event's ``method`` and its 95 % interval (``interval_low``/``interval_high``, s)
        go to its attributes."""
        grp = self.group.require_group("events")
        for name, value in events.items():
            if name in grp:
                del grp[name]
            ds = grp.create_dataset(name, data=float(value))
            ds.attrs["units"] = "s"
            if descriptions and name in descriptions:
                ds.attrs["description"] = descriptions[name]
                ds.attrs["long_name"] = descriptions[name]
            if source:
                ds.attrs["source"] = source
            if methods and name in methods:
                ds.attrs["method"] = methods[name]
            if intervals and name in intervals:
                ds.attrs["interval_low"], ds.attrs["interval_high"] = map(
                    float, intervals[name])
                ds.attrs["interval"] = "95 % interval of the time (s)"

    def set_attrs(self, **attrs: Any) -> None:
        for key, value in attrs.items():
            self.group.attrs[key] = value


METADATA_CACHE_BYTES = 256 * 1024


def limit_metadata_cache(f: h5py.File, size: int = METADATA_CACHE_BYTES) -> None:
    """Hold HDF5's metadata cache of ``f`` at ``size`` bytes. Its default adapts up to 2 MB
    as a long run's file grows (object headers and chunk indexes of every trial), and the
    process's memory grew with it (benchmarks/acquisition_memory.py, the acquisition's
    writing path: +11.0 MB over 40 trials of 2 s with HDF5's default, +2.6 MB levelled
    off after 20 trials with 256 KB, the time spent flushing unchanged)."""
    cfg = f.id.get_mdc_config()
    cfg.set_initial_size = True
    cfg.initial_size = size
    cfg.max_size = size
    cfg.min_size = min(cfg.min_size, size // 2)
    f.id.set_mdc_config(cfg)


class RunWriter:
    """Create a run file and fill it; always close it (it is a context manager)."""

    def __init__(self, path: str | Path, kind: str, metadata: Mapping[str, Any] | None = None,
                 *, crash_safe: bool = False) -> None:
        """``crash_safe`` writes the HDF5 1.8 file format, which stays readable (up to the
        last flush) when the writing process is killed; the newer format's consistency
        flags would make it unopenable without h5clear. Measured runs use it."""
        if kind not in KINDS:
            raise InputError(f"kind: expected one of {KINDS}, got {kind!r}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.file = h5py.File(self.path, "w",
                              libver=("earliest", "v108") if crash_safe else "latest")
        if crash_safe:
            limit_metadata_cache(self.file)
        a = self.file.attrs
        a["format"] = FORMAT
        a["format_version"] = FORMAT_VERSION
        a["kind"] = kind
        a["status"] = "running"
        a["created"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        a["software_version"] = __version__
        a["git_commit"] = git_commit()
        a["host"] = platform.node()
        a["n_trials"] = 0
        self.file.require_group("metadata")
        for name, value in (metadata or {}).items():
            self.add_metadata(name, value)
        self.file.flush()

    @classmethod
    def reopen(cls, path: str | Path) -> RunWriter:
        """Open an existing run file to finish it (e.g. after its writer process died)."""
        self = cls.__new__(cls)
        self.path = Path(path)
        self.file = h5py.File(self.path, "a")
        if self.file.attrs.get("format") != FORMAT:
            self.file.close()
            raise InputError(f"{path}: not a rig run file")
        return self

    def add_metadata(self, name: str, value: Any, fmt: str | None = None) -> None:
        text, kind = _text(value)
        grp = self.file["metadata"]
        if name in grp:
            del grp[name]
        ds = grp.create_dataset(name, data=text, dtype=h5py.string_dtype())
        ds.attrs["format"] = fmt or kind

    def trial(self, index: int | None = None) -> TrialWriter:
        """The trial group ``trial_NNN`` (a new one by default)."""
        n = int(self.file.attrs["n_trials"])
        index = n if index is None else index
        grp = self.file.require_group(f"trial_{index:03d}")
        grp.attrs.setdefault("status", "running")
        self.file.attrs["n_trials"] = max(n, index + 1)
        return TrialWriter(grp)

    def flush(self) -> None:
        self.file.flush()

    def close(self, status: str = "complete") -> None:
        """Mark the run ``complete`` or ``aborted: <reason>`` and close the file."""
        if not self.file.id.valid:
            return
        if not (status == "complete" or status.startswith("aborted")):
            raise InputError(f"status: expected 'complete' or 'aborted: <reason>', got {status!r}")
        self.file.attrs["status"] = status
        for name in self.file:
            if name.startswith("trial_") and self.file[name].attrs.get("status") == "running":
                self.file[name].attrs["status"] = status
        self.file.close()

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close("complete")
        elif isinstance(exc, KeyboardInterrupt):
            self.close("aborted: interrupted (Ctrl-C)")
        else:
            self.close(f"aborted: {exc_type.__name__}: {exc}")


@dataclass
class Trial:
    """One trial read back from a run file."""

    channels: dict[str, np.ndarray]
    units: dict[str, str]
    columns: dict[str, np.ndarray]
    events: dict[str, float]
    commands: dict[str, np.ndarray] = field(default_factory=dict)
    attrs: dict[str, Any] = field(default_factory=dict)

    descriptions: dict[str, str] = field(default_factory=dict)
    event_sources: dict[str, str] = field(default_factory=dict)  # event -> its "source" attr
    # event -> its 95 % interval (s), for events found in the channels with one (rig import)
    event_intervals: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def time(self) -> np.ndarray:
        return self.channels["time"]

    def to_xarray(self, section: str = "channels") -> Any:
        """The trial's channels (or ``section="commands"``) as an ``xarray.Dataset`` with time
        as the coordinate (and ``contact`` for per-contact channels); units, long_name and
        description in each variable's attributes, events (s) in the dataset's attributes
        as ``event_<name>``."""
        import xarray as xr

        if section not in ("channels", "commands"):
            raise InputError(f"section: expected 'channels' or 'commands', got {section!r}")
        data = self.channels if section == "channels" else self.commands
        prefix = "" if section == "channels" else "commands/"
        if "time" not in data:
            raise InputError(f"this trial has no {section} (no time base)")
        t = np.asarray(data["time"], float)

        def attrs(name: str) -> dict[str, str]:
            a = {"units": self.units.get(prefix + name, "")}
            doc = self.descriptions.get(prefix + name, "") or DEFAULT_DOCS.get(name, "")
            if doc:
                a.update(long_name=doc, description=doc)
            return a

        coords: dict[str, Any] = {"time": ("time", t, attrs("time"))}
        variables: dict[str, Any] = {}
        for name, v in data.items():
            if name == "time":
                continue
            v = np.asarray(v)
            if v.ndim == 1:
                variables[name] = (("time",), v, attrs(name))
            elif v.ndim == 2:
                cols = np.asarray(self.columns.get(name, np.arange(v.shape[1])))
                dim = name.split("_")[0] if name in self.columns else f"{name}_column"
                if dim in coords and not np.array_equal(coords[dim][1], cols):
                    dim = f"{name}_column"
                coords.setdefault(dim, (dim, cols, {"units": "1"}))
                variables[name] = (("time", dim), v, attrs(name))
        ds_attrs: dict[str, Any] = {k: v for k, v in self.attrs.items()
                                    if isinstance(v, str | int | float | np.generic)}
        ds_attrs.update({f"event_{k}": float(v) for k, v in self.events.items()})
        return xr.Dataset(variables, coords=coords, attrs=ds_attrs)

    def to_dataframe(self, section: str = "channels") -> Any:
        """The trial's 1-D channels (or commands) as a ``pandas.DataFrame`` indexed by time
        (s); per-contact channels as one column per contact (``contact_force[12]``)."""
        import pandas as pd

        data = self.channels if section == "channels" else self.commands
        if section not in ("channels", "commands") or "time" not in data:
            raise InputError(f"section: no {section!r} with a time base in this trial")
        cols: dict[str, np.ndarray] = {}
        for name, v in data.items():
            v = np.asarray(v)
            if name == "time":
                continue
            if v.ndim == 1:
                cols[name] = v
            else:
                labels = self.columns.get(name, np.arange(v.shape[1]))
                cols.update({f"{name}[{c}]": v[:, j] for j, c in enumerate(labels)})
        return pd.DataFrame(cols, index=pd.Index(np.asarray(data["time"], float), name="time"))


@dataclass
class Run:
    """A run file's contents."""

    path: Path
    attrs: dict[str, Any]
    metadata: dict[str, Any]
    trials: list[Trial]

    @property
    def status(self) -> str:
        return str(self.attrs.get("status", "unknown"))

    @property
    def kind(self) -> str:
        return str(self.attrs.get("kind", "unknown"))


def _read_section(grp: h5py.Group | None) -> tuple[dict[str, np.ndarray], dict[str, str],
                                                    dict[str, np.ndarray], dict[str, str]]:
    data: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    cols: dict[str, np.ndarray] = {}
    docs: dict[str, str] = {}
    if grp is None:
        return data, units, cols, docs
    for name, ds in grp.items():
        if name != "time" and _is_scale(ds):  # column labels (also in the "columns" attribute)
            continue
        data[name] = ds[()]
        units[name] = str(ds.attrs.get("units", ""))
        if "description" in ds.attrs:
            docs[name] = str(ds.attrs["description"])
        if "columns" in ds.attrs:
            cols[name] = np.asarray(ds.attrs["columns"])
    return data, units, cols, docs


def read(path: str | Path) -> Run:
    """Read a whole run file (any status), refusing files that are not run files."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: {not_a_file(p)}")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        hint = (f"; its run left a journal: `rig recover {p}` rebuilds it"
                if p.with_name(p.name + ".journal").is_file() else "")
        raise InputError(f"{p}: not a readable HDF5 file ({exc}){hint}") from None
    with f:
        if f.attrs.get("format") != FORMAT:
            raise InputError(f"{p}: not a rig run file (format attribute is "
                             f"{f.attrs.get('format')!r})")
        attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
        meta: dict[str, Any] = {}
        for name, ds in f.get("metadata", {}).items():
            raw = ds[()]
            text = raw.decode() if isinstance(raw, bytes) else str(raw)
            meta[name] = json.loads(text) if ds.attrs.get("format") == "json" else text
        trials = []
        for name in sorted(n for n in f if n.startswith("trial_")):
            g = f[name]
            ch, units, cols, docs = _read_section(g.get("channels"))
            cmd, cunits, _, cdocs = _read_section(g.get("commands"))
            units.update({f"commands/{k}": v for k, v in cunits.items()})
            docs.update({f"commands/{k}": v for k, v in cdocs.items()})
            evg = g.get("events", {})
            ev = current_event_names({k: float(v[()]) for k, v in evg.items()})
            src = {k: str(v.attrs["source"]) for k, v in evg.items() if "source" in v.attrs}
            ivs = {k: (float(v.attrs["interval_low"]), float(v.attrs["interval_high"]))
                   for k, v in evg.items() if "interval_low" in v.attrs
                   and "interval_high" in v.attrs}
            trials.append(Trial(ch, units, cols, ev, cmd, dict(g.attrs), docs, src, ivs))
    return Run(p, attrs, meta, trials)


def write_result(path: str | Path, result: Any, kind: str = "simulated",
                 metadata: Mapping[str, Any] | None = None) -> Path:
    """Write a SimResult (see rig.model.action) as a one-trial run file."""
    from rig.model.action import CHANNEL_DOCS, EVENT_DOCS

    meta = dict(metadata or {})
    model = dict(result.metadata.get("model", {}))
    params_yaml = model.pop("parameters_yaml", None)
    if params_yaml is None and getattr(result, "model", None) is not None:
        params_yaml = result.model.parameters_yaml
    meta.setdefault("model", model)
    if params_yaml is not None:
        meta.setdefault("parameters", params_yaml)
    if "profile" in result.metadata:
        meta.setdefault("profile", result.metadata["profile"])
    meta.setdefault("contacts", {"ids": list(result.contact_ids),
                                 "names": result.metadata.get("contact_names", [])})
    meta.setdefault("stats", {k: float(v) for k, v in result.stats.items()})
    status = "complete" if result.success else f"aborted: {result.message}"
    with RunWriter(path, kind, meta) as w:
        tr = w.trial()
        data = {"time": result.time, **{k: v for k, v in result.channels.items() if k != "time"}}
        cols = {k: result.contact_ids for k, v in data.items() if np.ndim(v) == 2}
        tr.append("channels", data, result.units, CHANNEL_DOCS, cols)
        names = result.metadata.get("contact_names", [])
        if cols and "contact" in tr.group["channels"] and len(names) == len(result.contact_ids):
            tr.group["channels/contact"].attrs.create("names", [str(n) for n in names],
                                                      dtype=h5py.string_dtype())
            tr.group["channels/contact"].attrs["long_name"] = "contact id (names: attribute)"
        tr.write_events({k: (v if math.isfinite(v) else math.nan) for k, v in
                         result.events.items()}, EVENT_DOCS)
        tr.set_attrs(status=status, t0=0.0)
        w.close(status)
    return Path(path)
