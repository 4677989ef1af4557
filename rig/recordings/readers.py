"""Read a source file's columns: delimited text (CSV, TSV, whitespace), NI TDMS (npTDMS) and
datasets of other HDF5 files. A reader returns a ``Table``: named 1-D float columns of one
length, and the sample interval a TDMS file states (else None)."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rig.errors import InputError

NPTDMS_REQUIREMENT = "npTDMS>=1.9"
_SEPARATORS = {"csv": ",", "tsv": "\t", "text": None}


@dataclass
class Table:
    """A source file's columns (name -> samples) in file order."""

    path: Path
    columns: dict[str, np.ndarray]
    order: list[str]
    header: bool = False
    dt: dict[str, float] = field(default_factory=dict)  # TDMS: channel -> wf_increment (s)

    def get(self, ref: str | int, index: int | None = None) -> np.ndarray:
        """A column by name or 1-based number; ``index`` picks a 2-D dataset's column."""
        if isinstance(ref, int):
            if ref > len(self.order):
                raise InputError(f"{self.path}: column {ref}: the file has "
                                 f"{len(self.order)} columns")
            data = self.columns[self.order[ref - 1]]
        else:
            if ref not in self.columns:
                have = ", ".join(self.order[:12]) + (" ..." if len(self.order) > 12 else "")
                raise InputError(f"{self.path}: column {ref!r} not found (it has: {have})")
            data = self.columns[ref]
        if data.ndim == 2:
            if index is None or index > data.shape[1]:
                raise InputError(f"{self.path}: {ref}: a 2-D dataset of {data.shape[1]} "
                                 f"columns needs index: 1..{data.shape[1]}, got {index}")
            return np.asarray(data[:, index - 1], float)
        if index not in (None, 1):
            raise InputError(f"{self.path}: {ref}: index {index} given for a 1-D column")
        return np.asarray(data, float)


def read(path: Path, fmt: str, header: str = "auto", delimiter: str | None = None,
         wanted: list[str | int] | None = None) -> Table:
    """The file's columns (``wanted``: only these, for TDMS and HDF5)."""
    if not path.is_file():
        raise InputError(f"{path}: file not found")
    if fmt in _SEPARATORS:
        return read_text(path, delimiter or _SEPARATORS[fmt], header)
    if fmt == "tdms":
        return read_tdms(path, wanted)
    if fmt == "hdf5":
        return read_hdf5(path, wanted)
    raise InputError(f"{path}: unknown format {fmt!r}")


def _cells(line: str, sep: str | None) -> list[str]:
    return [c.strip() for c in (line.split(sep) if sep else line.split())]


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_text(path: Path, sep: str | None, header: str = "auto") -> Table:
    """Delimited text (``sep`` None: runs of whitespace); lines starting with # are
    comments; ``header`` yes / no / auto (a first line that is not all numbers)."""
    import pandas as pd

    try:
        with path.open(encoding="utf-8", errors="strict") as fh:
            first, skipped = "", 0
            for line in fh:
                if line.strip() and not line.lstrip().startswith("#"):
                    first = line
                    break
                skipped += 1
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file (not UTF-8)") from None
    if not first:
        raise InputError(f"{path}: no data (empty, or only comments)")
    cells = _cells(first, sep)
    has_header = header == "yes" or (header == "auto" and not all(map(_is_number, cells)))
    try:
        df = pd.read_csv(path, sep=r"\s+" if sep is None else sep, comment="#",
                         header=0 if has_header else None, skip_blank_lines=True,
                         skipinitialspace=True, engine="c")
    except pd.errors.ParserError as exc:
        msg = " ".join(str(exc).split())
        m = re.search(r"line (\d+)", msg)
        where = f"line {m.group(1)}: " if m else ""
        raise InputError(f"{path}: {where}{msg.split(': ', 1)[-1]}") from None
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: no data") from None
    names = [str(c).strip() for c in df.columns] if has_header else \
        [str(i + 1) for i in range(df.shape[1])]
    if has_header and len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"{path}: line {skipped + 1}: column {dup!r} named twice")
    cols: dict[str, np.ndarray] = {}
    for name, col in zip(names, df.columns, strict=True):
        s = df[col]
        if s.dtype.kind not in "fiu":
            _bad_cell(path, sep, has_header, name, names.index(name))
        arr = s.to_numpy(dtype=float)
        if np.isnan(arr).any():
            _bad_cell(path, sep, has_header, name, names.index(name))
        cols[name] = arr
    if not cols or len(next(iter(cols.values()))) == 0:
        raise InputError(f"{path}: no data rows")
    return Table(path, cols, names, has_header)


def _bad_cell(path: Path, sep: str | None, has_header: bool, name: str, j: int) -> None:
    """Find and refuse the first cell of column ``j`` that is not a number (a slow pass over
    the raw lines, only on this error path)."""
    seen_header = not has_header
    with path.open(encoding="utf-8") as fh:
        for n, line in enumerate(fh, 1):
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            if not seen_header:
                seen_header = True
                continue
            cells = _cells(line, sep)
            cell = cells[j] if j < len(cells) else ""
            if not _is_number(cell) or math.isnan(float(cell)):
                raise InputError(f"{path}: line {n}: column {name!r}: not a number: {cell!r}")
    raise InputError(f"{path}: column {name!r}: a cell is not a number")


def read_tdms(path: Path, wanted: list[str | int] | None = None) -> Table:
    """An NI TDMS file's channels as ``group/channel`` columns; each channel's
    ``wf_increment`` (s) when it states one."""
    try:
        from nptdms import TdmsFile
    except ImportError:
        raise InputError(f"{path}: reading TDMS needs the npTDMS package, which is not "
                         f"installed (pip install '{NPTDMS_REQUIREMENT}')") from None
    try:
        tdms = TdmsFile.read(str(path))
    except Exception as exc:  # noqa: BLE001 - npTDMS raises many kinds for a bad file
        raise InputError(f"{path}: not a readable TDMS file ({exc})") from None
    cols: dict[str, np.ndarray] = {}
    order: list[str] = []
    dt: dict[str, float] = {}
    for group in tdms.groups():
        for ch in group.channels():
            name = f"{group.name}/{ch.name}"
            order.append(name)
            if wanted is None or name in wanted or len(order) in wanted:
                try:
                    cols[name] = np.asarray(ch[:], dtype=float)
                except (TypeError, ValueError):
                    raise InputError(f"{path}: channel {name!r} is not numeric") from None
            inc = ch.properties.get("wf_increment")
            if inc is not None and float(inc) > 0:
                dt[name] = float(inc)
    if not order:
        raise InputError(f"{path}: the TDMS file holds no channel")
    for name in order:
        cols.setdefault(name, np.empty(0))
    return Table(path, cols, order, True, dt)


def read_hdf5(path: Path, wanted: list[str | int] | None = None) -> Table:
    """Datasets of an HDF5 file by path (``/group/name``); 1-D, or 2-D with a column index."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path}: not a readable HDF5 file ({exc})") from None
    cols: dict[str, np.ndarray] = {}
    with f:
        names: list[str] = []
        f.visititems(lambda n, o: names.append("/" + n) if isinstance(o, h5py.Dataset)
                     else None)
        for ref in wanted or []:
            if isinstance(ref, int):
                raise InputError(f"{path}: HDF5 columns are named by dataset path "
                                 f"(/group/name), got column {ref}")
            key = ref if ref.startswith("/") else "/" + ref
            if key not in names:
                raise InputError(f"{path}: dataset {ref!r} not found")
            ds = f[key]
            if ds.ndim not in (1, 2) or ds.dtype.kind not in "fiub":
                raise InputError(f"{path}: dataset {ref!r} is not a numeric 1-D or 2-D array")
            cols[ref] = np.asarray(ds[()], float)
    return Table(path, cols, list(cols), True)
