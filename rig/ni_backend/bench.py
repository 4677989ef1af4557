"""The NI calibration bench: bridge readings through the SCXI-1520 (DAQmx bridge channels,
offset nulling and the driver's shunt calibration), the drive on a static surface, the
encoders while the key moves slowly."""

from __future__ import annotations

from typing import Any

import numpy as np

from rig.daq import Bench, Live, check_bridge
from rig.inputs.config import RigConfig
from rig.ni_backend import channels


class NiBench(Bench):
    """The NI cards through nidaqmx: bridge tasks, shunt and nulling calls, counters."""

    def __init__(self, cfg: RigConfig) -> None:
        super().__init__(cfg)
        self._tasks: dict[str, Any] = {}

    def _task(self, sensor: str) -> Any:
        from rig.ni_backend.daq import new_task

        check_bridge(sensor)
        if sensor not in self._tasks:
            task = new_task(f"rig-cal-{sensor}")
            if sensor == "load_cell":
                channels.add_load_cell(task, self.cfg.channels.load_cell, sensor)
            else:
                channels.add_strain_gauge(task, self.cfg.channels.strain_gauge, sensor)
            self._tasks[sensor] = task
        return self._tasks[sensor]

    def apply_mass(self, mass_kg: float, gravity_m_s2: float) -> None:
        pass  # the operator placed it and confirmed at the prompt

    def read_bridge(self, sensor: str, seconds: float, live: Live = None) -> np.ndarray:
        from nidaqmx.constants import AcquisitionType

        task = self._task(sensor)
        n = max(2, int(round(seconds * self.rate_hz)))
        task.timing.cfg_samp_clk_timing(self.rate_hz, sample_mode=AcquisitionType.FINITE,
                                        samps_per_chan=n)
        task.start()
        try:
            out: list[float] = []
            step = max(1, int(self.rate_hz / 10))
            while len(out) < n:
                got = task.read(number_of_samples_per_channel=min(step, n - len(out)),
                                timeout=10.0)
                out.extend(np.atleast_1d(np.asarray(got, dtype=float)).tolist())
                if live is not None:
                    live(float(np.mean(out)))
        finally:
            task.stop()
        return np.asarray(out, dtype=float)

    def null_offset(self, sensor: str) -> dict[str, Any]:
        task = self._task(sensor)
        task.perform_bridge_offset_nulling_cal(channel=sensor)
        return {"hardware_nulling": True}

    def shunt(self, sensor: str, on: bool, resistor_ohm: float) -> None:
        from nidaqmx.constants import ShuntCalSelect

        chan = self._task(sensor).ai_channels[sensor]
        chan.ai_bridge_shunt_cal_select = ShuntCalSelect.A
        chan.ai_bridge_shunt_cal_shunt_cal_a_resistance = float(resistor_ohm)
        chan.ai_bridge_shunt_cal_enable = bool(on)

    def driver_shunt_cal(self, sensor: str, resistor_ohm: float) -> float | None:
        """NI's shunt calibration (bridge_resistance from the config, not NI's 120 ohm default)."""
        ch = self.cfg.channels
        r_bridge = ch.load_cell.bridge_resistance_ohm if sensor == "load_cell" else \
            ch.strain_gauge.nominal_resistance_ohm
        task = self._task(sensor)
        task.perform_bridge_shunt_cal(channel=sensor, shunt_resistor_value=float(resistor_ohm),
                                      bridge_resistance=float(r_bridge))
        return float(task.ai_channels[sensor].ai_bridge_shunt_cal_gain_adjust)

    def drive_static(self, demand_n: np.ndarray) -> np.ndarray:
        """Buffered AO waveform on the drive card; the load cell on the bridge card, started
        by the AO start trigger (declare the RTSI cable in NI MAX), same number of periods.

        The waveform ends at 0 V. If anything fails before it has been played out, the
        waveform task is stopped and closed and a fresh on-demand task writes 0 V, since an
        analog output holds its last value; a DAQmx error becomes a one-line DaqFault."""
        import nidaqmx.errors
        from nidaqmx.constants import AcquisitionType

        from rig.daq import DaqFault
        from rig.motor_torque import TorqueScaling
        from rig.ni_backend.daq import new_task

        cfg = self.cfg
        out = cfg.channels.drive_output
        scaling = TorqueScaling.from_config(cfg.drive_scaling, out)
        volts = np.array([scaling.volts(float(f)) for f in demand_n] + [0.0])
        spc = cfg.rates.samples_per_cycle
        n_ai = (volts.size - 1) * spc
        ai = self._task("load_cell")
        ai.timing.cfg_samp_clk_timing(self.rate_hz, sample_mode=AcquisitionType.FINITE,
                                      samps_per_chan=n_ai)
        dev = out.physical_channel.split("/")[0]
        ai.triggers.start_trigger.cfg_dig_edge_start_trig(f"/{dev}/ao/StartTrigger")
        ao: Any = None
        done = False
        try:
            ao = new_task("rig-cal-drive")
            ao.ao_channels.add_ao_voltage_chan(out.physical_channel, min_val=out.min_volts,
                                               max_val=out.max_volts)
            ao.timing.cfg_samp_clk_timing(cfg.rates.control_hz,
                                          sample_mode=AcquisitionType.FINITE,
                                          samps_per_chan=volts.size)
            ao.write(volts.tolist(), auto_start=False)
            ai.start()      # armed: it waits for the AO start trigger
            ao.start()
            data = np.asarray(ai.read(number_of_samples_per_channel=n_ai,
                                      timeout=volts.size / cfg.rates.control_hz + 10.0), float)
            ao.wait_until_done(timeout=10.0)
            done = True
        except nidaqmx.errors.DaqError as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            raise DaqFault(f"motor: the drive waveform or its load-cell acquisition failed "
                           f"(DAQmx {exc.error_code}): {first}") from None
        finally:
            try:
                if ao is not None:
                    try:
                        if not done:
                            ao.stop()
                    finally:
                        ao.close()
                if not done:
                    self._zero_drive()
            finally:
                ai.stop()
                ai.triggers.start_trigger.disable_start_trig()
        return data

    def _zero_drive(self) -> None:
        """0 V on the drive output from an on-demand task (after the waveform task closed)."""
        from rig.ni_backend.daq import new_task

        out = self.cfg.channels.drive_output
        task = new_task("rig-cal-drive-zero")
        try:
            task.ao_channels.add_ao_voltage_chan(out.physical_channel, min_val=out.min_volts,
                                                 max_val=out.max_volts)
            task.write(0.0, auto_start=True)
        finally:
            task.close()

    def key_travel(self, force_n: np.ndarray) -> dict[str, np.ndarray]:
        """The operator presses the key slowly by hand for as long as ``force_n`` lasts;
        the counters are read every control period (software timed: only the range and
        the relation between encoders matter here)."""
        import time

        from rig.ni_backend.daq import new_task

        tasks = {}
        try:
            for name, enc in self.cfg.channels.encoders.items():
                t = new_task(f"rig-check-{name}")
                channels.add_encoder(t, enc, name)
                t.start()
                tasks[name] = t
            counts: dict[str, list[float]] = {n: [] for n in tasks}
            dt = 1.0 / self.cfg.rates.control_hz
            for _ in range(len(force_n)):
                for name, t in tasks.items():
                    counts[name].append(float(t.read()))
                time.sleep(dt)
        finally:
            for t in tasks.values():
                t.close()
        return {n: np.asarray(v) for n, v in counts.items()}

    def close(self) -> None:
        for t in self._tasks.values():
            t.close()
        self._tasks.clear()
