"""The simulated rig's parts: drive model, sensor models, card buffer."""

from __future__ import annotations

import numpy as np
import pytest

from rig import loadcell, strain
from rig.inputs import config
from rig.sim_backend.fifo import BufferOverflow, SharedFifo
from rig.sim_backend.sensors import SensorSet

DT = 0.0005


def test_sensor_models_differ_from_nominal_and_are_seeded() -> None:
    cfg = config.builtin_sim()
    a, b = SensorSet.from_config(cfg), SensorSet.from_config(cfg)
    assert a.truth() == b.truth()
    nom = loadcell.nominal_sensitivity(cfg.channels.load_cell)
    assert a["load_cell"].sensitivity != nom
    assert abs(a["load_cell"].sensitivity / nom - 1) < 0.1
    assert SensorSet.from_config(cfg, seed=99).truth() != a.truth()


def test_a_noise_stream_is_the_same_rig_with_fresh_noise() -> None:
    # issue 41: every learning trial is a run; on stream 0 each run drew the same noise, so
    # a noise spike stood at the same cycle in every trial and averaging trials learned
    # nothing (seed 106: 3.62, 3.62, 3.64 % with one table)
    from rig.loop.backends import trial_rig

    cfg = config.builtin_sim()
    f = np.full(4000, 10.0)

    def noise(c: config.RigConfig) -> np.ndarray:
        lc = SensorSet.from_config(c)["load_cell"]
        return loadcell.to_newtons(lc.measure(f), lc.sensitivity, lc.offset) - 10.0

    one, two = trial_rig(cfg, 1), trial_rig(cfg, 2)
    assert (one.sim.noise_stream, two.sim.noise_stream) == (1, 2)
    assert SensorSet.from_config(one).truth() == SensorSet.from_config(cfg).truth()
    assert np.array_equal(noise(cfg), noise(cfg))          # a run is reproducible
    a, b = noise(one), noise(two)
    assert np.array_equal(a, noise(trial_rig(cfg, 1)))
    assert abs(np.corrcoef(a, b)[0, 1]) < 0.1 and abs(np.corrcoef(a, noise(cfg))[0, 1]) < 0.1
    assert a.std() == pytest.approx(cfg.sim.load_cell_noise_n, rel=0.1)


def test_load_cell_filter_lags_and_noise_has_the_spec_size() -> None:
    # the built-in rig counts the 100 Hz filter in the drive model; set here, the load cell
    # filters on top (what rig synth --load-cell-filter does)
    cfg = config.builtin_sim(sim={"load_cell_filter_hz": 100.0})
    lc = SensorSet.from_config(cfg)["load_cell"]
    f = np.r_[np.zeros(200), np.full(4000, 20.0)]
    n = loadcell.to_newtons(lc.measure(f), lc.sensitivity, lc.offset)
    settled = n[2000:]
    assert settled.mean() == pytest.approx(20.0, abs=0.05)
    assert settled.std() == pytest.approx(cfg.sim.load_cell_noise_n, rel=0.15)
    assert 3 * settled.std() < 0.8  # the spec's 0.67 N max error
    # 100 Hz 4-pole Butterworth: ~4.2 ms group delay (about 8-9 samples at 2 kHz)
    assert 7 <= np.argmax(n > 10.0) - 200 <= 11


def test_the_built_in_load_cell_does_not_filter_again() -> None:
    lc = SensorSet.from_config(config.builtin_sim(sim={"load_cell_noise_n": 0.0}))["load_cell"]
    assert lc.chain.filter_hz is None
    f = np.r_[np.zeros(200), np.full(50, 20.0)]
    n = loadcell.to_newtons(lc.measure(f), lc.sensitivity, lc.offset)
    assert n == pytest.approx(f, abs=1e-9)  # the force as the drive model gives it


def test_strain_formula_round_trip_and_size() -> None:
    e = np.array([-1e-3, 0.0, 5e-4, 1e-3])
    r = strain.to_ratio(e, 2.0, 1e-4, 0.5, 350.0)
    assert strain.to_strain(r, 2.0, 1e-4, 0.5, 350.0) == pytest.approx(e, abs=1e-12)
    # ~0.5 mV/V at 1000 microstrain for GF 2
    assert abs(strain.to_ratio(1e-3, 2.0, 0.0)) == pytest.approx(0.5e-3, rel=0.01)


def test_encoders_quantise_at_their_resolution() -> None:
    sensors = SensorSet.from_config(config.builtin_sim())
    hammer = sensors["hammer"]
    step = abs(hammer.sensitivity)
    c = hammer.measure(np.array([0.0, 0.4 * step, 0.6 * step, 1.0]))
    assert list(c[:3]) == [0, 0, 1]
    assert c[3] == pytest.approx(1.0 / hammer.sensitivity, abs=0.5)
    assert abs(hammer.spec.sensitivity) == pytest.approx(2 * np.pi / 163840)


def test_fifo_detects_overwritten_samples() -> None:
    w = SharedFifo(8, 2)
    r = SharedFifo.attach(w.spec)
    try:
        w.write(np.arange(12.0).reshape(6, 2))
        assert r.read().shape == (6, 2)
        w.write(np.ones((6, 2)))
        w.write(np.ones((4, 2)))  # 10 unread > 8: overwritten
        with pytest.raises(BufferOverflow, match="overwritten"):
            r.read()
    finally:
        r.close()
        w.close()


def _realtime_cfg(**sections: dict) -> config.RigConfig:
    data: dict[str, dict] = {"sim": {"realtime": True, "effects": []},
                             "channels": {"strain_gauge": {"enabled": False}}}
    for key, value in sections.items():
        data.setdefault(key, {}).update(value)
    return config.builtin_sim(**data)


@pytest.mark.slow
def test_plant_building_its_model_is_reported_and_waited_for(monkeypatch) -> None:
    """Compiling the model on first use takes about a minute: the start must wait for
    it (sim.build_timeout_s, not the acquisition's start timeout) and say why."""
    from rig.sim_backend import daq as simdaq

    monkeypatch.setattr(simdaq, "BUILD_NOTICE_S", 0.0)
    lines: list[str] = []
    cfg = _realtime_cfg(acquisition={"start_timeout_s": 0.01})
    d = simdaq.SimDaq(cfg, on_line=lines.append)
    try:
        assert d.link is not None and d.link.ready
    finally:
        d.close()
    assert len(lines) == 1 and "building the simulated rig's action model" in lines[0]


def test_plant_build_timeout_names_its_setting() -> None:
    from rig.daq import DaqFault
    from rig.sim_backend.daq import SimDaq

    with pytest.raises(DaqFault, match=r"did not start within 0.01 s \(sim.build_timeout_s\)"):
        SimDaq(_realtime_cfg(sim={"build_timeout_s": 0.01}))
