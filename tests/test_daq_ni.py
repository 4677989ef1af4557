"""The NI backend against the real driver, or its absence. Its DAQmx calls, values and order
are tested through nidaqmx's own classes in tests/test_ni_interpreter.py (a recording fake
interpreter): autospec'd mocks accepted misspelled properties and any values."""

from __future__ import annotations

import nidaqmx
import nidaqmx.errors
import pytest

from rig import backends, config
from rig.daq import DaqFault


def ni_config(**kw):
    return config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"}, **kw})


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
def test_ni_hardware_triggered_pacing_on_the_shared_clock() -> None:
    """On the lab PC (drive disabled): the output reads back 0 V, the pacing card starts on
    the acquisition card's start trigger over RTSI and ticks on its timebase, 50 ticks with
    no missed one."""
    try:
        nidaqmx.Task().close()
    except nidaqmx.errors.DaqNotFoundError:
        pytest.skip("no NI-DAQmx driver on this machine (DaqNotFoundError)")
    cfg = ni_config()
    d = backends.open_daq(cfg)
    try:
        r = backends.open_reader(d.reader_spec())
        try:
            volts = d.zero_output()
            assert volts is None or abs(volts) <= cfg.channels.drive_output.zero_tolerance_volts
            d.arm()
            r.start()
            ticks = []
            for _ in range(50):
                ticks.append(d.wait_for_tick())
                d.write_volts(0.0)
            assert [t.index for t in ticks][-1] >= 49
            assert sum(t.missed for t in ticks[1:]) == 0
        finally:
            r.close()
    finally:
        d.close()
