"""Rig configuration: defaults, one-line errors naming the field, which rig is used."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.inputs import config


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "rig.yaml"
    p.write_text(text)
    return p


def test_builtin_sim_defaults() -> None:
    cfg = config.builtin_sim()
    assert cfg.backend == "sim" and cfg.drive.port == "sim"
    assert cfg.rates.control_hz == 500 and cfg.rates.acquisition_hz == 2000
    assert cfg.loop.advance_s == pytest.approx(0.008)
    assert sorted(e.body for e in cfg.channels.encoders.values()) == ["hammer", "key", "whippen"]
    # 0.1 m arm, 2 N m/A, 0.6 A/V: 120 N -> 10 V
    assert cfg.drive_scaling.volts_per_newton * 120 == pytest.approx(10.0)


@pytest.mark.parametrize(("text", "field"), [
    ("backend: labview\n", "backend"),
    ("backend: sim\nlimits: {max_force_n: -3}\n", "limits.max_force_n"),
    ("backend: sim\nlimits: {max_force_n: 500}\n", "limits.max_force_n"),
    ("backend: sim\nrates: {control_hz: 500, acquisition_hz: 1234}\n", "rates.acquisition_hz"),
    ("backend: sim\nchannels: {encoders: {k: {counter: c0, body: key, kind: angular}}}\n",
     "counts_per_rev"),
    ("backend: sim\nloop: {advnce_s: 0.01}\n", "loop.advnce_s"),
    ("backend: sim\nloop: {cpu: -1}\n", "loop.cpu"),
    ("backend: sim\nloop: {cpu: two}\n", "loop.cpu"),
    ("backend: sim\nacquisition: {flush_period_s: 2}\n", "acquisition.flush_period_s"),
    ("backend: sim\ndrive_scaling: {arm_length_m: zero}\n", "drive_scaling.arm_length_m"),
    ("- a list\n", "expected a mapping"),
    ("backend: sim\n  bad: [\n", "not valid YAML"),
])
def test_bad_configs_get_one_line_errors_naming_the_field(tmp_path: Path, text: str,
                                                          field: str) -> None:
    with pytest.raises(ValueError) as info:
        config.load(write(tmp_path, text))
    msg = str(info.value)
    assert field in msg and "\n" not in msg and "rig.yaml" in msg


def test_resolve_order(tmp_path: Path) -> None:
    cfg, which = config.resolve(None, cwd=tmp_path)
    assert cfg.backend == "sim" and "built-in simulated rig" in which
    write(tmp_path, "backend: ni\n")
    cfg, which = config.resolve(None, cwd=tmp_path)
    assert cfg.backend == "ni" and "./rig.yaml" in which
    other = tmp_path / "other.yaml"
    other.write_text("backend: sim\nname: bench\n")
    cfg, which = config.resolve(other, cwd=tmp_path)
    assert cfg.name == "bench" and str(other) in which


def test_config_round_trips_through_yaml(tmp_path: Path) -> None:
    cfg = config.builtin_sim(limits={"max_force_n": 40})
    again = config.load(write(tmp_path, cfg.to_yaml()))
    assert again == cfg
