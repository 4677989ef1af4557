"""The NI backend through autospecs of nidaqmx's real classes (a wrong name or keyword fails)."""

from __future__ import annotations

from pathlib import Path
from unittest import mock

import nidaqmx
import nidaqmx.errors
import pytest
from nidaqmx.constants import AcquisitionType, AngleUnits, BridgeConfiguration, LengthUnits
from nidaqmx.stream_readers import (
    AnalogMultiChannelReader,
    AnalogSingleChannelReader,
    CounterReader,
)
from nidaqmx.stream_writers import AnalogSingleChannelWriter
from nidaqmx.task import InStream, OutStream, Timing
from nidaqmx.task.collections import (
    AIChannelCollection,
    AOChannelCollection,
    CIChannelCollection,
)
from nidaqmx.task.triggering import StartTrigger, Triggers

from rig import backends, config
from rig.daq import DaqFault

TASKS: list[mock.MagicMock] = []
REAL_TASK = nidaqmx.Task


def fake_task(*args, **kwargs):
    t = mock.create_autospec(REAL_TASK, instance=True)
    t.ai_channels = mock.create_autospec(AIChannelCollection, instance=True)
    t.ao_channels = mock.create_autospec(AOChannelCollection, instance=True)
    t.ci_channels = mock.create_autospec(CIChannelCollection, instance=True)
    t.timing = mock.create_autospec(Timing, instance=True)
    t.in_stream = mock.create_autospec(InStream, instance=True)
    t.out_stream = mock.create_autospec(OutStream, instance=True)
    t.triggers = mock.create_autospec(Triggers, instance=True)
    t.triggers.start_trigger = mock.create_autospec(StartTrigger, instance=True)
    t.name = args[0] if args else kwargs.get("new_task_name", "")
    TASKS.append(t)
    return t


@pytest.fixture
def ni(monkeypatch):
    TASKS.clear()
    monkeypatch.setattr(nidaqmx, "Task", fake_task)
    readers = {}
    for mod_name, cls in [("AnalogMultiChannelReader", AnalogMultiChannelReader),
                          ("AnalogSingleChannelReader", AnalogSingleChannelReader),
                          ("CounterReader", CounterReader)]:
        m = mock.create_autospec(cls)
        monkeypatch.setattr(nidaqmx.stream_readers, mod_name, m)
        readers[mod_name] = m
    w = mock.create_autospec(AnalogSingleChannelWriter)
    monkeypatch.setattr(nidaqmx.stream_writers, "AnalogSingleChannelWriter", w)
    readers["writer"] = w
    return readers


def ni_config(**kw):
    return config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"}, **kw})


def by_name(name: str) -> mock.MagicMock:
    return next(t for t in TASKS if t.name == name)


def test_loop_side_paces_on_hwtsp_and_writes_the_drive(ni) -> None:
    d = backends.open_daq(ni_config())
    try:
        d.arm()
        pace, ao = by_name("rig-pacing"), by_name("rig-drive")
        ao.ao_channels.add_ao_voltage_chan.assert_called_once_with(
            "Dev1/ao0", min_val=-10.0, max_val=10.0)
        pace.timing.cfg_samp_clk_timing.assert_called_once_with(
            500.0, sample_mode=AcquisitionType.HW_TIMED_SINGLE_POINT)
        pace.triggers.start_trigger.cfg_dig_edge_start_trig.assert_called_once_with(
            "/Dev2/ai/StartTrigger")
        type(pace.in_stream).total_samp_per_chan_acquired = mock.PropertyMock(
            side_effect=[1, 2, 5])
        ticks = [d.wait_for_tick() for _ in range(3)]
        assert [t.index for t in ticks] == [0, 1, 4]
        assert [t.missed for t in ticks] == [0, 0, 2]
        reader = ni["AnalogSingleChannelReader"].return_value
        assert reader.read_one_sample.call_count == 3
        d.write_volts(2.5)
        ni["writer"].return_value.write_one_sample.assert_called_with(2.5, timeout=0.002)
    finally:
        d.close()
    ni["writer"].return_value.write_one_sample.assert_called_with(0.0, timeout=1.0)
    ao.close.assert_called_once_with()


def test_reader_sets_up_bridges_and_clocked_encoders(ni) -> None:
    d = backends.open_daq(ni_config())
    try:
        r = backends.open_reader(d.reader_spec())
        ai = by_name("rig-bridges")
        calls = ai.ai_channels.add_ai_bridge_chan.call_args_list
        assert calls[0].args == ("SC1Mod1/ai0",)
        assert calls[0].kwargs["bridge_config"] == BridgeConfiguration.FULL_BRIDGE
        assert calls[1].kwargs["bridge_config"] == BridgeConfiguration.QUARTER_BRIDGE
        assert calls[1].kwargs["nominal_bridge_resistance"] == 350.0
        hammer = by_name("rig-encoder-hammer")
        kw = hammer.ci_channels.add_ci_ang_encoder_chan.call_args.kwargs
        assert kw["units"] == AngleUnits.TICKS and kw["pulses_per_rev"] == 163840 // 4
        key = by_name("rig-encoder-key")
        assert key.ci_channels.add_ci_lin_encoder_chan.call_args.kwargs["units"] == \
            LengthUnits.TICKS
        hammer.timing.cfg_samp_clk_timing.assert_called_once_with(
            2000.0, source="/Dev2/ai/SampleClock", sample_mode=AcquisitionType.CONTINUOUS,
            samps_per_chan=4000)
        r.calibrate_bridges()
        # each bridge: offset nulling, then NI's shunt calibration with the bridge's own
        # 350 ohm (nidaqmx's bridge_resistance defaults to 120)
        assert ai.method_calls[-4:] == [
            mock.call.perform_bridge_offset_nulling_cal(channel="load_cell"),
            mock.call.perform_bridge_shunt_cal(channel="load_cell", shunt_resistor_value=100000.0,
                                               bridge_resistance=350.0),
            mock.call.perform_bridge_offset_nulling_cal(channel="strain_gauge"),
            mock.call.perform_bridge_shunt_cal(channel="strain_gauge",
                                               shunt_resistor_value=100000.0,
                                               bridge_resistance=350.0)]
        r.start()
        hammer.start.assert_called_once_with()
        ai.start.assert_called_once_with()

        type(ai.in_stream).avail_samp_per_chan = mock.PropertyMock(return_value=3)

        def fill_ai(data, number_of_samples_per_channel, timeout):
            data[:] = [[1e-4] * 3, [2e-5] * 3]
            return 3

        ni["AnalogMultiChannelReader"].return_value.read_many_sample.side_effect = fill_ai

        def fill_ci(data, number_of_samples_per_channel, timeout):
            data[:] = [10, 11, 12]
            return 3

        ni["CounterReader"].return_value.read_many_sample_double.side_effect = fill_ci
        rows = r.read(0.0)
        assert rows.shape == (3, 6)
        assert list(rows[:, 0]) == [0, 1, 2] and list(r.read(0.0)[:, 0]) == [3, 4, 5]
        assert rows[0, 1] == 1e-4 and list(rows[:, 3]) == [10, 11, 12]
        r.publish_feedback(5, 1e-4)
        assert d.feedback_ratio() == (5, 1e-4)

        err = nidaqmx.errors.DaqError("samples no longer available", -200279)
        ni["AnalogMultiChannelReader"].return_value.read_many_sample.side_effect = err
        named = r"overflow \(DAQmx SAMPLES_NO_LONGER_AVAILABLE \(-200279\)\)"  # nidaqmx's name
        with pytest.raises(DaqFault, match=named):
            r.read(0.0)
        type(ai.in_stream).avail_samp_per_chan = mock.PropertyMock(return_value=4000)
        with pytest.raises(DaqFault, match="buffer full"):
            r.read(0.0)
        r.close()
    finally:
        d.close()


def test_ni_config_never_falls_back_to_simulation() -> None:
    # nidaqmx is not patched here: on a machine without NI-DAQmx this must fail loudly
    try:
        nidaqmx.Task().close()
    except nidaqmx.errors.DaqError:
        pytest.skip("NI-DAQmx present with a device error; this test is for driverless hosts")
    except nidaqmx.errors.Error:
        with pytest.raises(DaqFault, match="not available"):
            backends.open_daq(ni_config())
        with pytest.raises(ValueError, match="lockstep"):
            backends.open_daq(ni_config(), lockstep=True)
        return
    pytest.skip("NI-DAQmx is installed; covered by the hardware test")


@pytest.mark.hardware
def test_ni_hardware_pacing_ticks() -> None:
    try:
        nidaqmx.Task().close()
    except nidaqmx.errors.DaqNotFoundError:
        pytest.skip("no NI-DAQmx driver on this machine (DaqNotFoundError)")
    d = backends.open_daq(ni_config(channels={"pacing": {"start_trigger": ""}}))
    try:
        d.arm()
        ticks = [d.wait_for_tick() for _ in range(50)]
        assert [t.index for t in ticks][-1] >= 49
    finally:
        d.close()


def test_supervisor_zeroes_the_drive_output_with_a_new_task(ni) -> None:
    """The loop's process died (its AO task with it; the card holds the last value): the
    supervisor in the acquisition process writes 0 V on the same channel with a new task."""
    from rig.supervisor import make_safe

    cfg = ni_config(drive={"port": "sim"})  # the serial side is tested in test_supervisor
    d = backends.open_daq(ni_config())
    try:
        r = backends.open_reader(d.reader_spec())
        make_safe(r, cfg)
        task = by_name("rig-safe-stop")
        task.ao_channels.add_ao_voltage_chan.assert_called_once_with(
            "Dev1/ao0", min_val=-10.0, max_val=10.0)
        task.write.assert_called_once_with(0.0, auto_start=True, timeout=1.0)
        task.close.assert_called_once_with()
        r.close()
        r.release_orphaned()  # the dead process's feedback block is removed
        assert not Path(f"/dev/shm/{d.reader_spec()['feedback']}").exists()
    finally:
        d.close()
