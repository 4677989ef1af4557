"""The NI backend against the real driver, or its absence. Its DAQmx calls, values and order
are tested through nidaqmx's own classes in tests/test_ni_interpreter.py (a recording fake
interpreter): autospec'd mocks accepted misspelled properties and any values."""

from __future__ import annotations

import nidaqmx
import nidaqmx.errors
import pytest

from rig.daq import DaqFault
from rig.inputs import config
from rig.loop import backends


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
def test_ni_hardware_dry_run_and_soak() -> None:
    """On the lab PC, the drive disabled (docs/running.md, "First day on the lab PC"): the
    rig config of RIG_CONFIG (default: the built-in NI settings); 0 V read back on the drive
    output; the bridges' lowpass and excitation read back from the driver; the pacing card
    started by the acquisition card's start trigger over RTSI and ticking on its timebase for
    RIG_SOAK_S seconds (default 0.1; 600 for the soak) with the acquisition read as a run
    reads it. Prints one line per step (run pytest with -s)."""
    import os

    import numpy as np

    try:
        nidaqmx.Task().close()
    except nidaqmx.errors.DaqNotFoundError:
        pytest.skip("no NI-DAQmx driver on this machine (DaqNotFoundError)")
    path = os.environ.get("RIG_CONFIG")
    cfg = config.load(path) if path else ni_config()
    soak_s = float(os.environ.get("RIG_SOAK_S", "0.1"))
    d = backends.open_daq(cfg)
    try:
        r = backends.open_reader(d.reader_spec())
        try:
            volts = d.zero_output()
            print(f"drive output: {'not read back' if volts is None else f'{volts:+.4f} V'} "
                  f"after writing 0 V")
            for name, got in r.bridge_settings().items():   # type: ignore[attr-defined]
                cut = got["lowpass_cutoff_hz"]
                print(f"{name}: lowpass {'off' if cut is None else f'{cut:g} Hz'}, excitation "
                      f"{got['excitation_volts']:g} V")
                want = getattr(cfg.channels, name)
                assert got["lowpass_cutoff_hz"] == want.lowpass_hz
                assert got["excitation_volts"] == pytest.approx(want.excitation_volts)
            d.arm()
            r.start()
            n = max(50, int(round(soak_s * cfg.rates.control_hz)))
            late = np.empty(n)
            missed = np.empty(n, dtype=int)
            samples = 0
            for k in range(n):
                tick = d.wait_for_tick()
                d.write_volts(0.0)
                late[k], missed[k] = d.write_lateness(tick), tick.missed
                if k % 50 == 49:
                    samples += r.read(0.0).shape[0]
            thr = cfg.limits.late_threshold_s
            print(f"soak: {n} ticks ({n / cfg.rates.control_hz:g} s on the card's clock), "
                  f"missed {int(missed[1:].sum())}, late writes {int((late > thr).sum())} "
                  f"(> {thr * 1e3:g} ms), max write lateness {late.max() * 1e3:.3f} ms, "
                  f"{samples} samples read")
            assert volts is None or abs(volts) <= cfg.channels.drive_output.zero_tolerance_volts
            assert int(missed[1:].sum()) == 0
        finally:
            r.close()
    finally:
        d.close()
