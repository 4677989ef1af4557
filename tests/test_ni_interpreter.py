"""rig's NI backend through nidaqmx's own Task, channel, timing, trigger and stream code,
with only the DAQmx interpreter replaced by the recording fake of tests/ni_fake.py: the
DAQmx calls, their values and their order are asserted, so a misspelled property
(``__slots__``), a wrong value or a wrong order fails."""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from typing import Any

import nidaqmx
import nidaqmx.errors
import numpy as np
import pytest
from ni_fake import (
    DIG_EDGE_ARM_START_SRC,
    LOWPASS_CUTOFF,
    LOWPASS_ENABLE,
    SHUNT_GAIN_ADJUST,
    TIMEBASE_RATE,
    TIMEBASE_SRC,
    FakeInterpreter,
    UnexpectedCall,
)
from nidaqmx.constants import (
    AcquisitionType,
    AngleUnits,
    BridgeConfiguration,
    EncoderType,
    LengthUnits,
    OverwriteMode,
    TriggerType,
)

from rig.daq import DaqFault
from rig.errors import InputError
from rig.inputs import config
from rig.loop import backends
from rig.ni_backend.daq import bridge_calibration
from rig.services import run as run_service

ARM_TRIG_TYPE = 0x1414
COUNT_EDGES_TERM = 0x18C7


def ni_config(**kw: Any) -> config.RigConfig:
    return config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"}, **kw})


@pytest.fixture
def fake() -> Iterator[Any]:
    f = FakeInterpreter()
    with f.installed():
        yield f
    left = [t.name for t in f.tasks.values() if not t.closed]
    assert not left, f"tasks left open: {left}"


class Rig:
    """The loop side and the acquisition side on the fake cards, closed at the end."""

    def __init__(self, cfg: config.RigConfig, bridge_cal: dict[str, Any] | None = None) -> None:
        self.daq: Any = backends.open_daq(cfg)
        spec = self.daq.reader_spec()
        if bridge_cal is not None:
            spec["bridge_cal"] = bridge_cal
        self.reader: Any = backends.open_reader(spec)

    def start(self) -> None:
        self.daq.zero_output()
        self.daq.arm()
        self.reader.start()

    def close(self) -> None:
        try:
            self.reader.close()
        finally:
            self.daq.close()


@pytest.fixture
def rig(fake: Any) -> Iterator[Rig]:
    r = Rig(ni_config())
    yield r
    r.close()


def names(fake: Any, task: str | None = None) -> list[str]:
    return [c.name for c in fake.calls if task is None or c.task == task]


# ---- the seam itself ----
def test_the_fake_refuses_what_it_does_not_model_and_slots_refuse_misspellings(fake) -> None:
    task = nidaqmx.Task("t")
    try:
        with pytest.raises(UnexpectedCall, match="create_ai_thrmcpl_chan"):
            task.ai_channels.add_ai_thrmcpl_chan("Dev1/ai0")
        with pytest.raises(AttributeError):
            task.in_stream.overwrit = 5  # type: ignore[attr-defined]
        chan = task.ai_channels.add_ai_voltage_chan("Dev1/ai1")
        with pytest.raises(AttributeError):
            chan.ai_lowpass_cutof_freq = 100.0  # type: ignore[attr-defined]
        with pytest.raises(UnexpectedCall, match="never set"):
            _ = chan.ai_lowpass_cutoff_freq   # a read of a value nobody wrote
    finally:
        task.close()


# ---- safety order ----
class RecordingDrive:
    def __init__(self, fake: Any) -> None:
        self.fake = fake
        self.enabled = False

    def enable(self) -> None:
        self.fake.events.append(("enable", None))
        self.enabled = True


def test_the_drive_is_enabled_only_after_0_V_is_written_and_read_back(fake, rig) -> None:
    drive = RecordingDrive(fake)
    said: list[str] = []
    fake.ao["Dev1/ao0"] = 3.0           # a test panel left 3 V on the output
    run_service.enable_at_zero(rig.daq, drive, said.append)  # type: ignore[arg-type]
    assert fake.events[:2] == [("ao", ("Dev1/ao0", 0.0)), ("enable", None)]
    # the read back came between the write and the enable
    order = [c.name for c in fake.calls if c.task in ("rig-drive", "rig-drive-readback")]
    assert order == ["create_task", "create_ao_voltage_chan", "start_task",
                     "write_analog_scalar_f64", "create_task", "create_ai_voltage_chan",
                     "read_analog_scalar_f64", "clear_task"]
    readback = fake.of("create_ai_voltage_chan", "rig-drive-readback")[0]
    assert readback.args["physical_channel"] == "Dev1/_ao0_vs_aognd"
    assert said == ["drive output reads +0.0000 V after writing 0 V: enabling the drive"]
    # and the run service enables the drive only through it
    src = inspect.getsource(run_service._run)
    assert "drive.enable()" not in src and "enable_at_zero(daq, drive, say)" in src


def test_a_drive_output_that_does_not_read_0_V_keeps_the_drive_disabled(fake, rig) -> None:
    drive = RecordingDrive(fake)
    fake.stuck["Dev1/ao0"] = 1.5
    with pytest.raises(DaqFault, match=r"_ao0_vs_aognd reads 1.5000 V .* stays disabled"):
        run_service.enable_at_zero(rig.daq, drive, print)  # type: ignore[arg-type]
    assert not drive.enabled


def test_a_failed_0_V_write_is_redone_through_a_fresh_task(fake) -> None:
    r = Rig(ni_config())
    try:
        r.start()
        r.daq.wait_for_tick()
        r.daq.write_volts(4.0)
        fake.fail["write_analog_scalar_f64"] = nidaqmx.errors.DaqError("device gone", -50103)
        with pytest.raises(DaqFault, match="drive output write failed"):
            r.daq.write_volts(0.0)
        assert fake.ao["Dev1/ao0"] == 0.0
        assert fake.task("rig-safe-stop").closed and fake.task("rig-drive").closed
        writes = fake.of("write_analog_scalar_f64", "rig-safe-stop")
        assert [c.args["value"] for c in writes] == [0.0]
    finally:
        r.close()


def test_close_falls_back_to_a_fresh_task_when_the_loop_task_fails(fake) -> None:
    r = Rig(ni_config())
    try:
        r.start()
        r.daq.wait_for_tick()
        r.daq.write_volts(4.0)
        fake.fail["write_analog_scalar_f64"] = nidaqmx.errors.DaqError("device gone", -50103)
    finally:
        r.close()
    assert fake.ao["Dev1/ao0"] == 0.0
    assert [c.task for c in fake.of("write_analog_scalar_f64")][-1] == "rig-safe-stop"


def test_the_supervisor_zeroes_the_drive_output_with_a_new_task(fake, rig) -> None:
    from rig.loop.backends import serial_drive
    from rig.loop.supervisor import make_safe

    rig.start()
    rig.daq.wait_for_tick()
    rig.daq.write_volts(2.0)
    cfg = ni_config(drive={"port": "sim"})
    make_safe(rig.reader, cfg, serial_drive=serial_drive(cfg))
    safe = fake.of("create_ao_voltage_chan", "rig-safe-stop")[0]
    assert safe.args["physical_channel"] == "Dev1/ao0"
    assert fake.ao["Dev1/ao0"] == 0.0 and fake.task("rig-safe-stop").closed


def test_reader_close_closes_the_counters_when_the_ai_stop_raises(fake) -> None:
    r = Rig(ni_config())
    r.start()
    fake.fail["stop_task"] = nidaqmx.errors.DaqError("stop failed", -200010)
    with pytest.raises(nidaqmx.errors.DaqError, match="stop failed"):
        r.reader.close()
    r.daq.close()
    assert all(t.closed for t in fake.tasks.values())


# ---- set-up values and the triggered start ----
def test_pacing_shares_the_acquisition_timebase_and_starts_on_its_trigger(fake, rig) -> None:
    rig.daq.zero_output()
    rig.daq.arm()
    timing = fake.of("cfg_samp_clk_timing", "rig-pacing")[0].args
    assert timing["rate"] == 500.0
    assert timing["sample_mode"] == AcquisitionType.HW_TIMED_SINGLE_POINT.value
    assert fake.sets("rig-pacing", TIMEBASE_SRC) == ["/Dev2/20MHzTimebase"]
    assert fake.sets("rig-pacing", TIMEBASE_RATE) == [20e6]
    assert fake.of("cfg_dig_edge_start_trig", "rig-pacing")[0].args["trigger_source"] == \
        "/Dev2/ai/StartTrigger"
    clock = "rig-card-clock"
    assert fake.of("create_ci_count_edges_chan", clock)[0].args["physical_channel"] == \
        "Dev1/ctr0"
    assert fake.sets(clock, COUNT_EDGES_TERM) == ["/Dev1/ai/SampleClockTimebase"]
    assert fake.sets(clock, ARM_TRIG_TYPE) == [TriggerType.DIGITAL_EDGE.value]
    assert fake.sets(clock, DIG_EDGE_ARM_START_SRC) == ["/Dev1/ai/StartTrigger"]
    starts = [c.task for c in fake.of("start_task")]
    assert starts.index(clock) < starts.index("rig-pacing")   # counting from the first edge
    # the pacing card's sample clock runs on the acquisition card's oscillator
    assert fake._clock_device(fake.task("rig-pacing")) == "Dev2"

    # the triggered path: no tick until the acquisition starts (its start trigger)
    with pytest.raises(DaqFault, match="pacing read failed .-200284."):
        rig.daq.wait_for_tick()
    rig.daq.index = -1
    rig.reader.start()
    starts = [c.task for c in fake.of("start_task")]
    assert starts[-4:] == ["rig-encoder-key", "rig-encoder-whippen", "rig-encoder-hammer",
                           "rig-bridges"]  # counters wait for the AI sample clock
    tick = rig.daq.wait_for_tick()
    assert (tick.index, tick.missed) == (0, 0) and 0 <= tick.lateness_s < 1e-4


def test_an_unshared_timebase_leaves_the_pacing_card_on_its_own_clock(fake) -> None:
    r = Rig(ni_config(channels={"pacing": {"timebase_source": ""}}))
    try:
        r.start()
        assert fake.sets("rig-pacing", TIMEBASE_SRC) == []
        assert fake._clock_device(fake.task("rig-pacing")) == "Dev1"
    finally:
        r.close()


def test_bridges_get_the_scxi_lowpass_from_the_config(fake, rig) -> None:
    adds = fake.of("create_ai_bridge_chan", "rig-bridges")
    assert [a.args["bridge_config"] for a in adds] == [BridgeConfiguration.FULL_BRIDGE.value,
                                                       BridgeConfiguration.QUARTER_BRIDGE.value]
    for name in ("load_cell", "strain_gauge"):
        sets = {(c.args["attribute"], c.args["value"]) for c in fake.calls
                if c.name.startswith("set_chan") and c.args.get("channel") == name}
        assert {(LOWPASS_ENABLE, True), (LOWPASS_CUTOFF, 100.0)} <= sets
    seq = names(fake, "rig-bridges")
    assert seq.index("set_chan_attribute_double") < seq.index("cfg_samp_clk_timing")
    assert rig.reader.bridge_settings() == {   # read back through the driver
        "load_cell": {"lowpass_enable": True, "lowpass_cutoff_hz": 100.0,
                      "excitation_volts": 5.0},
        "strain_gauge": {"lowpass_enable": True, "lowpass_cutoff_hz": 100.0,
                         "excitation_volts": 2.5}}


def test_lowpass_other_cutoff_off_and_refused(fake) -> None:
    r = Rig(ni_config(channels={"load_cell": {"lowpass_hz": 1000},
                                "strain_gauge": {"lowpass_hz": None}}))
    r.close()
    assert fake.sets("rig-bridges", LOWPASS_ENABLE) == [True, False]
    assert fake.sets("rig-bridges", LOWPASS_CUTOFF) == [1000.0]
    with pytest.raises(InputError, match=r"channels.load_cell.lowpass_hz: expected one of the "
                                         r"SCXI-1520's cutoffs 10, 100, 1000, 10000 Hz"):
        ni_config(channels={"load_cell": {"lowpass_hz": 50}})


def test_the_run_nulls_and_shunt_calibrates_the_strain_bridge_with_the_record_resistor(
        fake) -> None:
    cfg = ni_config()
    records = [{"sensor": "strain_gauge", "fit": {"shunt_resistor_ohm": 59880.0}},
               {"sensor": "load_cell", "fit": {"sensitivity": 1.8e-5}}]
    cal = bridge_calibration(cfg, records)
    r = Rig(cfg, bridge_cal=cal)
    r.close()
    nulls = fake.of("perform_bridge_offset_nulling_cal_ex", "rig-bridges")
    assert [c.args["channel"] for c in nulls] == ["strain_gauge"]  # the load cell: as calibrated
    shunt = fake.of("perform_bridge_shunt_cal_ex", "rig-bridges")
    assert len(shunt) == 1 and shunt[0].args["channel"] == "strain_gauge"
    assert shunt[0].args["shunt_resistor_value"] == 59880.0
    assert shunt[0].args["bridge_resistance"] == 350.0
    assert r.reader.shunt_gain == {"strain_gauge": 1.0021}
    # the record's gage factor holds the shunt correction: the driver's gain is not applied
    assert fake.sets("rig-bridges", SHUNT_GAIN_ADJUST) == [1.0]
    seq = names(fake, "rig-bridges")
    assert seq.index("perform_bridge_offset_nulling_cal_ex") < \
        seq.index("perform_bridge_shunt_cal_ex")
    # no strain record: the config's resistor
    assert bridge_calibration(cfg, [])["strain_gauge"]["shunt_resistor_ohm"] == \
        cfg.calibration.strain_gauge.shunt_resistor_ohm
    off = ni_config(channels={"strain_gauge": {"enabled": False}})
    assert bridge_calibration(off, records)["strain_gauge"]["null"] is False


def test_buffer_full_is_judged_on_the_buffer_daqmx_allocated(fake, rig) -> None:
    assert rig.reader.buffer == 10000  # the fake allocates 10000 (rig asked for 4000)
    rig.start()
    fake.avail = 4000        # the requested 2 s: not full on a 10000-sample buffer
    assert rig.reader.read(0.0).shape == (4000, 6)
    fake.avail = 10000
    with pytest.raises(DaqFault, match=r"buffer full \(10000 samples\)"):
        rig.reader.read(0.0)
    fake.avail = 5
    fake.fail["read_analog_f64"] = nidaqmx.errors.DaqError("gone", -200279)
    with pytest.raises(DaqFault, match=r"overflow \(DAQmx SAMPLES_NO_LONGER_AVAILABLE"):
        rig.reader.read(0.0)


def test_reader_sets_up_clocked_encoders_and_reads_rows(fake, rig) -> None:
    kw = fake.of("create_ci_ang_encoder_chan", "rig-encoder-hammer")[0].args
    assert kw["units"] == AngleUnits.TICKS.value and kw["pulses_per_rev"] == 163840 // 4
    assert kw["decoding_type"] == EncoderType.X_4.value
    key = fake.of("create_ci_lin_encoder_chan", "rig-encoder-key")[0].args
    assert key["units"] == LengthUnits.TICKS.value and key["dist_per_pulse"] == 2e-6
    timing = fake.of("cfg_samp_clk_timing", "rig-encoder-hammer")[0].args
    assert (timing["rate"], timing["source"], timing["samps_per_chan"]) == \
        (2000.0, "/Dev2/ai/SampleClock", 4000)
    assert timing["sample_mode"] == AcquisitionType.CONTINUOUS.value
    assert fake.sets("rig-bridges", 0x1211) == [OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES.value]
    rig.start()
    fake.avail = 3
    fake.ai_fill = np.array([[1e-4], [2e-5]])
    fake.ci_fill = 11.0
    rows = rig.reader.read(0.0)
    assert rows.shape == (3, 6)
    assert list(rows[:, 0]) == [0, 1, 2] and list(rig.reader.read(0.0)[:, 0]) == [3, 4, 5]
    assert rows[0, 1] == 1e-4 and rows[0, 2] == 2e-5 and list(rows[:, 3]) == [11.0] * 3
    rig.reader.publish_feedback(5, 1e-4)
    assert rig.daq.feedback_ratio() == (5, 1e-4)


# ---- one clock: lateness and missed ticks on the card's clock ----
def run_loop(daq: Any, fake: Any, ticks: int, work_s: float = 200e-6) -> tuple[Any, Any, Any]:
    index = np.empty(ticks, dtype=np.int64)
    late = np.empty(ticks)
    missed = np.empty(ticks, dtype=np.int64)
    for n in range(ticks):
        tick = daq.wait_for_tick()
        fake.sleep(work_s)                  # the controller's computation
        daq.write_volts(0.0)
        index[n], late[n], missed[n] = tick.index, daq.write_lateness(tick), tick.missed
    return index, late, missed


def drift_check(fake: Any, seconds: float) -> None:
    threshold = config.Limits().late_threshold_s
    for ppm in (+100.0, -100.0):
        f = FakeInterpreter(ppm={"Dev2": ppm, "Dev1": -ppm})
        with f.installed():
            r = Rig(ni_config())
            try:
                r.start()
                ticks = int(seconds * 500)
                index, late, missed = run_loop(r.daq, f, ticks)
            finally:
                r.close()
        assert list(index[:3]) == [0, 1, 2] and index[-1] == ticks - 1
        assert not missed.any()
        assert late.max() < threshold, f"{ppm:+} ppm: false late cycle {late.max()}"
        # the write lateness is the work time on the card's clock, with no drift
        assert abs(late.max() - late.min()) < 1e-7
        assert late.mean() == pytest.approx(205e-6 * (1 + ppm * 1e-6), abs=1e-7)
        # while true (PC) time drifted from the card's ticks by more than the threshold: an
        # estimate anchored on the PC's clock would have called these cycles late (or hidden
        # real lateness)
        assert abs(f.now - 205e-6 - (ticks - 1) / 500) > threshold


def test_a_card_clock_100_ppm_off_gives_no_false_late_cycle_in_12_s(fake) -> None:
    drift_check(fake, 12.0)   # 1.2 ms of drift: past the 1 ms threshold


@pytest.mark.slow
def test_a_card_clock_100_ppm_off_gives_no_false_late_cycle_in_10_minutes(fake) -> None:
    drift_check(fake, 600.0)   # crosses the 32-bit counter's wrap (214.7 s at 20 MHz) twice


def test_a_first_edge_one_period_after_the_trigger_is_tick_0(fake, rig) -> None:
    fake.first_edge_periods = 1
    rig.start()
    ticks = []
    for _ in range(3):
        ticks.append(rig.daq.wait_for_tick())
        rig.daq.write_volts(0.0)
    assert [(t.index, t.missed) for t in ticks] == [(0, 0), (1, 0), (2, 0)]
    assert all(0 < t.lateness_s < 1e-4 for t in ticks)
    assert rig.daq.write_lateness(ticks[-1]) < 1e-4


def test_missed_ticks_are_counted_from_edges_and_late_writes_seen(fake, rig) -> None:
    rig.start()
    first = rig.daq.wait_for_tick()
    rig.daq.write_volts(0.0)
    assert (first.index, first.missed) == (0, 0)
    fake.skip_ticks(1)                      # the software missed one sample clock
    t = rig.daq.wait_for_tick()
    assert (t.index, t.missed) == (2, 1)
    assert fake.task("rig-pacing").reads == 2   # two reads, three edges: edges decide
    fake.sleep(1.5e-3)                       # a late write
    rig.daq.write_volts(0.0)
    assert rig.daq.write_lateness(t) == pytest.approx(1.505e-3, abs=1e-6)
    assert t.lateness_s < 1e-4              # the wake-up was on time
    fake.sleep(100.0)
    t2 = rig.daq.wait_for_tick()
    assert t2.index == 2 + 50001 and t2.missed == 50000
    fake.sleep(150.0)                # past the 32-bit counter's wrap (214.7 s at 20 MHz)
    t3 = rig.daq.wait_for_tick()
    assert t3.index == t2.index + 75001 and t3.missed == 75000 and t3.lateness_s < 1e-4
