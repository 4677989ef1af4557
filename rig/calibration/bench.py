"""What a calibration procedure reads: the simulated rig's sensors or the NI cards.

    bench = open_bench(cfg)                 # SimBench or NiBench, by cfg.backend
    bench.apply_mass(0.5)                   # sim: loads the simulated cell; NI: the user did
    ratios = bench.read_bridge("load_cell", 1.0)      # V/V samples at the acquisition rate
    bench.null_offset("strain_gauge"); bench.shunt("strain_gauge", True, 100e3)
    ratios = bench.drive_static(demand_n)   # motor on a static surface: demand (N, 500 Hz)
    counts = bench.key_travel(force_n)      # encoder counts while the key moves slowly

The simulated bench uses the same seeded sensor models as the simulated rig
(``SensorSet.from_config(cfg)``), so what it calibrates is what ``rig run``
then measures with. A card clips at its input range; so does the simulated one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any

import numpy as np

from rig import strain as strain_mod
from rig.config import RigConfig
from rig.errors import InputError

Live = Callable[[float], None] | None
BRIDGES = ("load_cell", "strain_gauge")


def _check_bridge(sensor: str) -> None:
    if sensor not in BRIDGES:
        raise InputError(f"sensor: expected one of {BRIDGES}, got {sensor!r}")


def bridge_range(cfg: RigConfig, sensor: str) -> float:
    """+- input range of a bridge channel, V/V."""
    _check_bridge(sensor)
    ch = cfg.channels
    mv = ch.load_cell.input_range_mv_per_v if sensor == "load_cell" else \
        ch.strain_gauge.input_range_mv_per_v
    return mv * 1e-3


def shunt_equivalent_strain(gauge_ohm: float, gage_factor: float, shunt_ohm: float) -> float:
    """Equivalent strain (m/m) of a shunt across a quarter-bridge gauge: -Rg/(GF (Rg + Rs))."""
    for name, v in (("gauge_ohm", gauge_ohm), ("gage_factor", gage_factor),
                    ("shunt_ohm", shunt_ohm)):
        if not v > 0:
            raise InputError(f"{name}: expected a positive value, got {v}")
    return -gauge_ohm / (gage_factor * (gauge_ohm + shunt_ohm))


class Bench(ABC):
    """The readings a calibration needs, on one rig."""

    def __init__(self, cfg: RigConfig) -> None:
        self.cfg = cfg
        self.rate_hz = cfg.rates.acquisition_hz

    @abstractmethod
    def apply_mass(self, mass_kg: float, gravity_m_s2: float) -> None:
        """The user placed ``mass_kg`` on the key top (the simulated bench loads its cell)."""

    @abstractmethod
    def read_bridge(self, sensor: str, seconds: float, live: Live = None) -> np.ndarray:
        """Bridge ratio samples (V/V) for ``seconds``; ``live`` gets the running mean."""

    @abstractmethod
    def null_offset(self, sensor: str) -> dict[str, Any]:
        """Bridge offset nulling with the sensor at rest; what the hardware reported."""

    @abstractmethod
    def shunt(self, sensor: str, on: bool, resistor_ohm: float) -> None:
        """Engage or release the shunt-calibration resistor across the gauge arm."""

    def driver_shunt_cal(self, sensor: str, resistor_ohm: float) -> float | None:
        """The card driver's own shunt calibration; its gain adjustment (None if not available)."""
        return None

    @abstractmethod
    def drive_static(self, demand_n: np.ndarray) -> np.ndarray:
        """Hold each demand (N) for one control period with the arm on a static surface;
        load-cell ratios (V/V) at the acquisition rate, ``samples_per_cycle`` per demand."""

    @abstractmethod
    def key_travel(self, force_n: np.ndarray) -> dict[str, np.ndarray]:
        """Press the key with ``force_n`` (N, one per control period); counts per encoder."""

    def truth(self) -> dict[str, dict[str, float]]:
        """True sensor parameters (simulated bench only)."""
        raise RuntimeError("only the simulated bench knows its sensors' true values")

    def close(self) -> None:  # noqa: B027 - nothing to release by default
        """Release cards and tasks."""


class SimBench(Bench):
    """The simulated rig's sensors, drive and action, stepped as fast as possible."""

    def __init__(self, cfg: RigConfig) -> None:
        super().__init__(cfg)
        from rig.sim_backend.sensors import SensorSet

        self.sensors = SensorSet.from_config(cfg)
        self.force_n = 0.0
        self.shunt_on = False
        self._rig: Any = None

    def truth(self) -> dict[str, dict[str, float]]:
        return self.sensors.truth()

    def apply_mass(self, mass_kg: float, gravity_m_s2: float) -> None:
        self.force_n = float(mass_kg) * gravity_m_s2

    def read_bridge(self, sensor: str, seconds: float, live: Live = None) -> np.ndarray:
        _check_bridge(sensor)
        n = max(1, int(round(seconds * self.rate_hz)))
        chunks = []
        total = 0.0
        for i0 in range(0, n, max(1, int(self.rate_hz / 10))):
            m = min(n - i0, max(1, int(self.rate_hz / 10)))
            if sensor == "load_cell":
                r = self.sensors.load_cell.measure(np.full(m, self.force_n))
            else:
                sg = self.sensors.strain_gauge
                if sg is None:
                    raise InputError("channels.strain_gauge.enabled is false on this rig")
                g = self.cfg.channels.strain_gauge
                e = shunt_equivalent_strain(g.nominal_resistance_ohm, g.gage_factor,
                                            self.shunt_resistor) if self.shunt_on else 0.0
                # the shunt's resistance change goes through the same chain as a strain does
                r = sg.measure(np.full(m, e * (1 + g.lead_wire_resistance_ohm
                                               / g.nominal_resistance_ohm)))
            rng = bridge_range(self.cfg, sensor)
            r = np.clip(r, -rng, rng)
            chunks.append(r)
            total += float(r.sum())
            if live is not None:
                live(total / sum(c.size for c in chunks))
        return np.concatenate(chunks)

    def null_offset(self, sensor: str) -> dict[str, Any]:
        _check_bridge(sensor)
        return {"hardware_nulling": False}

    def shunt(self, sensor: str, on: bool, resistor_ohm: float) -> None:
        if sensor != "strain_gauge":
            raise InputError(f"sensor: the simulated bench shunts only the strain gauge, "
                             f"got {sensor!r}")
        self.shunt_on = bool(on)
        self.shunt_resistor = float(resistor_ohm)

    def drive_static(self, demand_n: np.ndarray) -> np.ndarray:
        from rig.sim_backend.drive_model import DriveModel

        cfg = self.cfg
        spc = cfg.rates.samples_per_cycle
        drive = DriveModel(1.0 / self.rate_hz, cfg.sim.drive_model, cfg.sim.process_time_unit_s)
        force = np.concatenate([np.maximum(drive.step(float(u), spc), 0.0)
                                for u in np.asarray(demand_n, float)])
        lc = self.sensors.load_cell
        lc.reset(0.0)
        return np.clip(lc.measure(force), -bridge_range(cfg, "load_cell"),
                       bridge_range(cfg, "load_cell"))

    def key_travel(self, force_n: np.ndarray) -> dict[str, np.ndarray]:
        from rig.sim_backend.rig import SimRig

        if self._rig is None:
            self._rig = SimRig(self.cfg)
        rig = self._rig
        vpn = self.cfg.drive_scaling.volts_per_newton
        rows = np.vstack([rig.cycle(float(f) * vpn) for f in np.asarray(force_n, float)])
        first = 2 + int(rig.strain_on)
        return {name: rows[:, first + j] for j, name in enumerate(self.cfg.channels.encoders)}


class NiBench(Bench):
    """The NI cards through nidaqmx: bridge tasks, shunt and nulling calls, counters."""

    def __init__(self, cfg: RigConfig) -> None:
        super().__init__(cfg)
        self._tasks: dict[str, Any] = {}

    def _task(self, sensor: str) -> Any:
        from rig import loadcell
        from rig.ni_daq import _new_task

        _check_bridge(sensor)
        if sensor not in self._tasks:
            task = _new_task(f"rig-cal-{sensor}")
            if sensor == "load_cell":
                loadcell.add_ni_channel(task, self.cfg.channels.load_cell, sensor)
            else:
                strain_mod.add_ni_channel(task, self.cfg.channels.strain_gauge, sensor)
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
        from rig.ni_daq import _new_task

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
            ao = _new_task("rig-cal-drive")
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
        from rig.ni_daq import _new_task

        out = self.cfg.channels.drive_output
        task = _new_task("rig-cal-drive-zero")
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

        from rig import encoders as enc_mod
        from rig.ni_daq import _new_task

        tasks = {}
        try:
            for name, enc in self.cfg.channels.encoders.items():
                t = _new_task(f"rig-check-{name}")
                enc_mod.add_ni_channel(t, enc, name)
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


def open_bench(cfg: RigConfig) -> Bench:
    """The bench of the configured backend (NI never falls back to simulation)."""
    if cfg.backend == "sim":
        return SimBench(cfg)
    if cfg.backend == "ni":
        return NiBench(cfg)
    raise InputError(f"backend: expected 'ni' or 'sim', got {cfg.backend!r}")
