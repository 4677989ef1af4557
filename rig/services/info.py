"""`rig info`: a run file's summary, as text lines or as one JSON document
(docs/json.md, rig.info/1). Both are built here from one read of the file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from rig.recordings import runfile
from rig.sensors import display


def read(path: Path) -> runfile.Run:
    """The run file (its errors: the file and what is wrong)."""
    return runfile.read(path)


def lines(path: Path, r: Any) -> list[str]:
    """The text summary of a read run file, one line each (`rig info`)."""
    a = r.attrs
    out: list[str] = []
    out.append(f"{path}: {r.kind} run, status {r.status}")
    out.append(f"created {a.get('created')} on {a.get('host')} by rig "
                f"{a.get('software_version')} ({str(a.get('git_commit'))[:12]})")
    imported = r.metadata.get("import")
    if isinstance(imported, dict):
        for f in imported.get("files", []):
            if isinstance(f, dict):
                out.append(f"imported from {f.get('name')} ({f.get('format')}, sha256 "
                            f"{str(f.get('sha256'))[:16]}) through {imported.get('map_file')}")
    model = r.metadata.get("model")
    if isinstance(model, dict):
        names = [e.get("name") for e in model.get("effects", [])]
        out.append(f"model effects: {', '.join(names) or 'none'}")
    cals = r.metadata.get("calibrations")
    if isinstance(cals, list) and cals:
        out.append("calibrations:")
        for c in cals:
            if isinstance(c, dict):
                out.append(f"  {c.get('sensor', '?'):<18} {c.get('sensitivity', math.nan):.6g} "
                            f"{c.get('units', '')} per {c.get('raw_units', '')}, offset "
                            f"{c.get('offset', math.nan):.6g}, "
                            f"{'nominal' if c.get('nominal') else 'measured'} "
                            f"({c.get('source', '')})")
    loop = r.metadata.get("loop_lateness")
    if isinstance(loop, dict) and loop:
        out.append(f"loop: {int(loop.get('cycles', 0))} cycles, lateness median "
                    f"{loop.get('median_s', math.nan) * 1e3:.3f} ms, p99 "
                    f"{loop.get('p99_s', math.nan) * 1e3:.3f} ms, max "
                    f"{loop.get('max_s', math.nan) * 1e3:.3f} ms, missed "
                    f"{int(loop.get('missed', 0))}, late {int(loop.get('late_cycles', 0))}")
    for i, tr in enumerate(r.trials):
        n = tr.time.size if "time" in tr.channels else 0
        span = f"{tr.time[0]:.3f} to {tr.time[-1]:.3f} s" if n > 1 else "-"
        out.append(f"trial {i}: {n} samples, {span}, status {tr.attrs.get('status')}")
        late = tr.commands.get("lateness")
        if late is not None and late.size:
            missed = tr.commands.get("missed")
            out.append(f"  loop: {late.size} cycles, lateness median "
                        f"{np.median(late) * 1e3:.3f} ms, p99 {np.percentile(late, 99) * 1e3:.3f} "
                        f"ms, max {late.max() * 1e3:.3f} ms, missed "
                        f"{int(np.nansum(missed)) if missed is not None else 0}")
        for name, data in tr.channels.items():
            k, u = display.scale(tr.units.get(name, ""))
            arr = np.asarray(data, float)
            rng = (f"{np.nanmin(arr) * k:.5g} .. {np.nanmax(arr) * k:.5g} {u}"
                   if arr.size and np.isfinite(arr).any() else "no finite value")
            shape = "" if arr.ndim == 1 else f" {arr.shape[1]} columns"
            out.append(f"  {name:<24} {tr.units.get(name, ''):<6} {rng}{shape}")
        for name, t in sorted(tr.events.items(), key=lambda x: (not math.isfinite(x[1]),
                                                                 x[1])):
            shown = f"{t * 1e3:.2f} ms" if math.isfinite(t) else "--"
            found = "  (found in the channels)" if name in tr.event_sources else ""
            out.append(f"  event {name:<22} {shown}{found}")
    return out


def document(path: Path, r: Any) -> dict[str, Any]:
    """The JSON document of a read run file (`rig info --json`, schema rig.info/1)."""
    model = r.metadata.get("model")
    trials = []
    for i, tr in enumerate(r.trials):
        t = tr.channels.get("time")
        chans = []
        for name, data in tr.channels.items():
            arr = np.asarray(data, float)
            fin = arr[np.isfinite(arr)]
            chans.append({"name": name, "units": tr.units.get(name, ""),
                          "min": float(fin.min()) if fin.size else None,
                          "max": float(fin.max()) if fin.size else None,
                          "columns": [c.item() if hasattr(c, "item") else c
                                      for c in tr.columns[name]] if name in tr.columns else None})
        ev = sorted(tr.events.items(), key=lambda x: (not math.isfinite(x[1]), x[1]))
        trials.append({"index": i, "status": str(tr.attrs.get("status", "")),
                       "samples": int(t.size) if t is not None else 0,
                       "start_s": float(t[0]) if t is not None and t.size else None,
                       "end_s": float(t[-1]) if t is not None and t.size else None,
                       "channels": chans, "events": [{"name": k, "time_s": v,
                                                   "source": tr.event_sources.get(k)}
                                                  for k, v in ev],
                       "commands": sorted(tr.commands)})
    cals = r.metadata.get("calibrations")
    loop = r.metadata.get("loop_lateness")
    return {"schema": "rig.info/1", "path": str(path), "kind": r.kind, "status": r.status,
            "created": str(r.attrs.get("created", "")), "host": str(r.attrs.get("host", "")),
            "software_version": str(r.attrs.get("software_version", "")),
            "git_commit": str(r.attrs.get("git_commit", "")),
            "model_effects": [e.get("name") for e in model.get("effects", [])]
            if isinstance(model, dict) else None,
            "calibrations": cals if isinstance(cals, list) else [],
            "loop_lateness": loop if isinstance(loop, dict) else None, "trials": trials}
