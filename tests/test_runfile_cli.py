"""Run files written by `rig simulate`, read back; the CLI's messages."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from rig.cli import app
from rig.model.action import CHANNEL_UNITS, EVENT_ORDER
from rig.recordings import runfile

ROOT_CHANNELS = ("time", "force", "key_angle", "whippen_angle", "jack_angle", "repetition_angle",
                 "hammer_angle", "hammer_head_velocity", "contact_force")


def test_result_round_trip(tmp_path, forte_rigid):
    path = runfile.write_result(tmp_path / "r.h5", forte_rigid)
    run = runfile.read(path)
    assert run.status == "complete" and run.kind == "simulated"
    trial = run.trials[0]
    for name in ROOT_CHANNELS:
        np.testing.assert_array_equal(trial.channels[name], forte_rigid.channels[name])
        assert trial.units[name] == CHANNEL_UNITS[name]
    assert list(trial.columns["contact_force"]) == list(range(1, 15))
    assert trial.events["strike"] == forte_rigid.events["strike"]
    assert "contacts:" in run.metadata["parameters"]  # the full parameter set
    assert run.metadata["profile"]["name"] == "forte"
    assert run.metadata["model"]["effects"] == []
    with h5py.File(path) as f:  # every dataset carries its units
        f.visititems(lambda n, o: isinstance(o, h5py.Dataset) and not n.startswith("metadata")
                     and _has_units(n, o))


def test_old_event_names_read_under_the_technicians_names(tmp_path, forte_rigid):
    """Run files written before issue 12 called the toe meeting the button "let_off", the
    jack's escape "escapement" and the check "backcheck_catch"; they read as today's."""
    path = runfile.write_result(tmp_path / "old.h5", forte_rigid)
    ev = forte_rigid.events
    with h5py.File(path, "r+") as f:
        grp = f["trial_0001/events"] if "trial_0001" in f else f[sorted(
            n for n in f if n.startswith("trial_"))[0]]["events"]
        for new, old in (("let_off", "escapement"), ("toe_meets_button", "let_off"),
                         ("check", "backcheck_catch")):
            del grp[new]
            grp[old] = {"escapement": ev["let_off"], "let_off": ev["toe_meets_button"],
                        "backcheck_catch": ev["check"]}[old]
    old = runfile.read(path).trials[0].events
    for name in EVENT_ORDER:
        assert old[name] == ev[name], name
    assert "escapement" not in old and "backcheck_catch" not in old


def test_let_off_is_the_jack_escaping_with_the_hammer_distance(forte_rigid):
    ev = forte_rigid.events
    # the toe meets the button first; the jack leaves the knuckle (contact 7) later
    assert ev["toe_meets_button"] < ev["let_off"] < ev["strike"]
    jack = forte_rigid.contact("contact_force", 7)  # jack top on the knuckle
    assert np.interp(ev["let_off"] - 2e-4, forte_rigid.time, jack) > 0
    assert np.interp(ev["let_off"] + 2e-4, forte_rigid.time, jack) == 0
    gap = -np.interp(ev["let_off"], forte_rigid.time,
                     forte_rigid.contact("contact_penetration", 12))
    assert forte_rigid.let_off_distance == pytest.approx(gap)
    assert forte_rigid.summary()["let_off_distance_m"] == forte_rigid.let_off_distance
    assert 0 < forte_rigid.let_off_distance < 0.01  # millimetres from the string


def _has_units(name, obj):
    assert "units" in obj.attrs, name


def test_an_aborted_writer_leaves_a_readable_file(tmp_path):
    with pytest.raises(KeyboardInterrupt), runfile.RunWriter(tmp_path / "a.h5", "measured") as w:
        tr = w.trial()
        tr.append("channels", {"time": np.arange(5) / 2000}, {"time": "s"})
        w.flush()
        raise KeyboardInterrupt
    run = runfile.read(tmp_path / "a.h5")
    assert run.status.startswith("aborted: interrupted")
    assert run.trials[0].channels["time"].size == 5


def test_read_refuses_other_files(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        runfile.read(tmp_path / "missing.h5")
    (tmp_path / "x.h5").write_text("not hdf5")
    with pytest.raises(ValueError, match="not a readable HDF5"):
        runfile.read(tmp_path / "x.h5")


def test_cli_simulate_writes_a_run_and_a_summary(tmp_path):
    out = tmp_path / "forte.h5"
    result = CliRunner().invoke(app, ["simulate", "profiles/forte.yaml", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "strike at" in result.output and f"wrote {out}" in result.output
    run = runfile.read(out)
    assert all(math.isfinite(run.trials[0].events[n]) for n in EVENT_ORDER)


def test_cli_refuses_a_bad_profile_in_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("points: [[0, 0], [0.01, 300]]\n")
    result = CliRunner().invoke(app, ["simulate", str(bad), "--out", str(tmp_path / "o.h5")])
    assert result.exit_code == 2
    lines = [ln for ln in result.output.splitlines() if ln.strip() and not ln.startswith("rig: ")]
    assert lines == [f"error: {bad}: points[1] force: 300.0 N is above the force limit of "
                     f"120.0 N"]
    assert not (tmp_path / "o.h5").exists()


def test_cli_info_summarizes_a_run(tmp_path, forte_rigid):
    path = runfile.write_result(tmp_path / "r.h5", forte_rigid)
    result = CliRunner().invoke(app, ["info", str(path)])
    assert result.exit_code == 0, result.output
    assert "simulated run, status complete" in result.output
    assert "hammer_angle" in result.output and "event strike" in result.output
    bad = CliRunner().invoke(app, ["info", str(tmp_path / "none.h5")])
    assert bad.exit_code == 2 and "not found" in bad.output


def test_xarray_opens_a_simulated_run_with_time_and_contact_coordinates(tmp_path, forte_rigid):
    xr = pytest.importorskip("xarray")
    path = runfile.write_result(tmp_path / "sim.h5", forte_rigid)
    with xr.open_dataset(path, group="trial_000/channels", engine="h5netcdf") as ds:
        assert set(ds.dims) == {"time", "contact"}
        assert np.array_equal(ds["time"].values, forte_rigid.time)
        assert list(ds["contact"].values) == list(forte_rigid.contact_ids)
        assert len(ds["contact"].attrs["names"]) == len(forte_rigid.contact_ids)
        assert ds["contact_force"].dims == ("time", "contact")
        assert float(ds["contact_force"].sel(contact=12).max()) == pytest.approx(
            float(forte_rigid.contact("contact_force", 12).max()))
        for name, var in ds.variables.items():
            assert var.attrs.get("units") and var.attrs.get("long_name"), name
    tr = runfile.read(path).trials[0]  # the column scale is not read back as a channel
    assert "contact" not in tr.channels and set(tr.channels) == set(ds.variables) - {"contact"}


def test_a_file_without_dimension_scales_still_reads(tmp_path):
    """Files written before time became a dimension scale (format_version 1 as well)."""
    path = tmp_path / "old.h5"
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "rig-run", "format_version": 1, "kind": "measured",
                        "status": "complete", "n_trials": 1})
        f.create_group("metadata")
        g = f.create_group("trial_000/channels")
        t = np.arange(100) / 2000
        g.create_dataset("time", data=t).attrs["units"] = "s"
        g.create_dataset("force", data=np.sin(t)).attrs["units"] = "N"
        f["trial_000"].attrs["status"] = "complete"
    tr = runfile.read(path).trials[0]
    assert set(tr.channels) == {"time", "force"} and np.array_equal(tr.time, t)
    xr = pytest.importorskip("xarray")
    with xr.open_dataset(path, group="trial_000/channels", engine="h5netcdf",
                         phony_dims="sort") as ds:
        assert np.array_equal(ds["force"].values, np.sin(t))


def test_xarray_opens_a_synthetic_run_with_described_channels(tmp_path):
    xr = pytest.importorskip("xarray")
    from pathlib import Path

    from rig.analysis import synth
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    prof = profiles.load(Path(__file__).resolve().parents[1] / "profiles" / "forte.yaml")
    path = tmp_path / "syn.h5"
    synth.synth(ActionModel(), [prof], path, seed=1, duration=0.03)
    tr = runfile.read(path).trials[0]
    with xr.open_dataset(path, group="trial_000/channels", engine="h5netcdf") as ds:
        assert set(ds.dims) == {"time"} and ds.sizes["time"] == tr.time.size
        assert set(ds.data_vars) == set(tr.channels) - {"time"}
        for name, var in ds.variables.items():
            assert var.attrs.get("units") and var.attrs.get("long_name"), name
    with xr.open_dataset(path, group="trial_000/commands", engine="h5netcdf") as cmd:
        assert set(cmd.dims) == {"time"} and cmd["demand"].attrs["units"] == "N"
