"""docs/architecture.md's "Add a sensor", followed literally (issue 14).

The guide's example (a thermometer) is added the way the guide says, to the sensor table and
the two backends' tables of a scratch copy of the package (rig/sensors/table.py,
rig/ni_backend/channels.py and rig/sim_backend/sensors.py copied and edited, every other
file linked, so the compiled model's cache is shared), and `rig run` presses the key on the
simulated rig through the real processes (the acquisition process imports the copy too).
The run file must hold the new channel, raw and calibrated, with its units and
descriptions; so must the NI reader's rows. Any place that still wrote the card rows'
columns by position, or kept a list of sensors of its own, fails here, and so does a
guide whose block no longer fits the code."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import yaml
from ni_fake import FakeInterpreter  # nidaqmx's own classes, the DAQmx calls recorded

from rig.inputs import config
from rig.ni_backend import channels as ni_channels
from rig.ni_backend.daq import NiReader
from rig.recordings import runfile
from rig.sensors import table as sensor_table

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "architecture.md"
FORTE = ROOT / "profiles" / "forte.yaml"
TABLE_LINE = re.compile(r"^SENSOR_TABLE: .*$", re.M)


# the files the guide edits, each with the table its block adds to (after the sensor table)
BACKENDS = {"rig/ni_backend/channels.py": "NI_CHANNELS", "rig/sim_backend/sensors.py": "SIM_CHAINS"}


def guide() -> tuple[str, list[str]]:
    """The "Add a sensor" section and its Python blocks."""
    section = GUIDE.read_text().split("\n## Add a sensor\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 3, ("the guide shows three Python blocks: the new sensor's entry, "
                              "its NI channel and its simulated chain")
    return section, blocks


def edited_table_source() -> str:
    """rig/sensors/table.py with the guide's block: its function above the table, the table's
    line as the guide shows it."""
    section, (block, *_) = guide()
    assert "rig/sensors/table.py" in section and "SENSOR_TABLE" in section
    src = (ROOT / "rig" / "sensors" / "table.py").read_text()
    old, new = TABLE_LINE.search(src), TABLE_LINE.search(block)
    assert old and new, "rig/sensors/table.py and the guide both show the SENSOR_TABLE line"
    name = re.search(r"^def (\w+)\(", block, re.M)
    assert name, "the guide's block defines the new sensor's function"
    # the guide's table line is the code's with the new sensor listed last
    assert new.group(0) == old.group(0)[:-1] + f", {name.group(1)}]", (old.group(0),
                                                                       new.group(0))
    return src[:old.start()] + block[:new.start()] + new.group(0) + src[old.end():]


def edited_backend_sources() -> dict[str, str]:
    """The backends' files with the guide's blocks: each adds the new sensor's entry to its
    file's table, appended to the file."""
    section, (_, *blocks) = guide()
    out = {}
    for (path, table), block in zip(BACKENDS.items(), blocks, strict=True):
        assert path in section and table in section
        assert block.startswith(f"{table}["), (path, block)
        out[path] = (ROOT / path).read_text() + "\n\n" + block
    return out


@pytest.fixture(scope="module")
def shadow(tmp_path_factory) -> Path:
    """A package folder whose rig is this one plus the guide's edits."""
    root = tmp_path_factory.mktemp("shadow")
    edited = {"rig/sensors/table.py": edited_table_source(), **edited_backend_sources()}
    folders = {path.rsplit("/", 1)[0] for path in edited}
    for folder in ["rig", *sorted(folders)]:
        (root / folder).mkdir()
        for entry in (ROOT / folder).iterdir():
            rel = f"{folder}/{entry.name}"
            if entry.name != "__pycache__" and rel not in edited and rel not in folders:
                (root / rel).symlink_to(entry)
    for path, text in edited.items():
        (root / path).write_text(text)
    return root


def edited_table(shadow: Path) -> ModuleType:
    """The edited rig/sensors/table.py as a module of its own (importing this rig)."""
    return edited_module(shadow, "rig/sensors/table.py", "edited_sensor_table")


def edited_module(shadow: Path, path: str, name: str) -> ModuleType:
    """An edited file of the shadow package as a module of its own (importing this rig)."""
    spec = importlib.util.spec_from_file_location(name, shadow / path)
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # for its dataclasses
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_the_guide_s_sensor_arrives_in_a_simulated_run_file(shadow: Path,
                                                            tmp_path: Path) -> None:
    rig_yaml = tmp_path / "rig.yaml"
    rig_yaml.write_text(yaml.safe_dump({
        "name": "add-a-sensor", "backend": "sim", "drive": {"port": "sim"},
        "sim": {"realtime": False}, "loop": {"rest_s": 0.1}, "data_folder": str(tmp_path)}))
    out = tmp_path / "run.h5"
    env = {**os.environ, "PYTHONPATH": str(shadow)}
    proc = subprocess.run([sys.executable, "-m", "rig", "run", str(FORTE), "--rig",
                           str(rig_yaml), "-o", str(out)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    cfg = config.load(rig_yaml)
    new = edited_table(shadow).sensors(cfg)[-1]
    assert new.name not in {s.name for s in sensor_table.sensors(cfg)}  # not in the real table

    run = runfile.read(out)
    assert run.status == "complete"
    tr = run.trials[0]
    for name, units, doc in ((new.raw, new.raw_units, new.raw_doc),
                             (new.channel, new.units, new.doc)):
        assert tr.units[name] == units and tr.descriptions[name] == doc
        assert tr.channels[name].size == tr.channels["sample"].size
    # the guide's simulated thermometer reads 21.5 degC (true calibration within its spread)
    assert np.mean(tr.channels[new.channel]) == pytest.approx(21.5, abs=1.0)
    assert np.all(np.diff(tr.channels["sample"]) == 1)
    assert tr.units["force"] == "N" and tr.units["hammer_angle"] == "rad"  # the others too
    cals = {c["sensor"]: c for c in run.metadata["calibrations"]}
    assert cals[new.name]["nominal"] and cals[new.name]["units"] == new.units


def test_the_guide_s_sensor_is_set_up_and_read_on_ni(shadow: Path, monkeypatch) -> None:
    edited = edited_table(shadow)
    monkeypatch.setattr(sensor_table, "SENSOR_TABLE", edited.SENSOR_TABLE)
    edited_ni = edited_module(shadow, "rig/ni_backend/channels.py", "edited_ni_channels")
    monkeypatch.setattr(ni_channels, "NI_CHANNELS", edited_ni.NI_CHANNELS)
    _, (_, block, _) = guide()
    physical = re.search(r'add_ai_voltage_chan\(\s*"([^"]+)"', block)
    assert physical, "the guide's sensor is an analog input of the bridges' task"
    cfg = config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"}})
    names = sensor_table.raw_names(cfg)
    new = sensor_table.sensors(cfg)[-1]
    assert names[-1] == new.raw
    fake = FakeInterpreter()
    with fake.installed():
        r = NiReader({"config": cfg.model_dump(mode="json")})
        try:
            # its DAQmx channel, on the bridges' task, under its sensor's name
            adds = fake.of("create_ai_voltage_chan", "rig-bridges")
            assert len(adds) == 1
            assert adds[0].args["physical_channel"] == physical.group(1)
            assert adds[0].args["name_to_assign_to_channel"] == new.name
            assert (adds[0].args["min_val"], adds[0].args["max_val"]) == (0.0, 1.0)
            ai_chans = [c.name for c in fake.task("rig-bridges").chans]
            assert ai_chans == ["load_cell", "strain_gauge", new.name]
            r.start()
            # the driver's rows come in the task's channel order, each its own value
            fake.avail = 2
            volts = {"load_cell": 1e-4, "strain_gauge": 2e-5, new.name: 0.215}
            fake.ai_fill = np.array([[volts[c]] for c in ai_chans])
            counts = {"key": [3.0, 4.0], "whippen": [5.0, 6.0], "hammer": [7.0, 8.0]}
            fake.ci_fill = {f"rig-encoder-{k}": np.array(v) for k, v in counts.items()}
            rows = r.read(0.0)
        finally:
            r.close()
    assert all(t.closed for t in fake.tasks.values())
    assert rows.shape == (2, len(names))
    assert list(rows[:, names.index(new.raw)]) == [0.215, 0.215]
    assert list(rows[:, names.index("load_cell_ratio")]) == [1e-4, 1e-4]
    assert list(rows[:, names.index("strain_ratio")]) == [2e-5, 2e-5]
    for k, v in counts.items():
        assert list(rows[:, names.index(f"{k}_counts")]) == v
    out = sensor_table.convert(rows, cfg, sensor_table.nominal(cfg))
    assert out[new.channel] == pytest.approx([21.5, 21.5])
