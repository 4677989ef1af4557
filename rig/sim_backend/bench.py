"""The simulated calibration bench: the simulated rig's sensors, drive and action, stepped as
fast as possible (the same seeded sensor models as the simulated rig, so what it
calibrates is what ``rig run`` then measures with; a card clips at its input range, and
so does the simulated one)."""

from __future__ import annotations

from typing import Any

import numpy as np

from rig import strain as strain_mod
from rig.daq import Bench, Live, bridge_range, check_bridge
from rig.errors import InputError
from rig.inputs.config import RigConfig
from rig.sensors import table as sensor_table


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
        """True sensor parameters (only the simulated bench knows them)."""
        return self.sensors.truth()

    def apply_mass(self, mass_kg: float, gravity_m_s2: float) -> None:
        self.force_n = float(mass_kg) * gravity_m_s2

    def read_bridge(self, sensor: str, seconds: float, live: Live = None) -> np.ndarray:
        check_bridge(sensor)
        n = max(1, int(round(seconds * self.rate_hz)))
        chunks = []
        total = 0.0
        for i0 in range(0, n, max(1, int(self.rate_hz / 10))):
            m = min(n - i0, max(1, int(self.rate_hz / 10)))
            if sensor == "load_cell":
                r = self.sensors["load_cell"].measure(np.full(m, self.force_n))
            else:
                sg = self.sensors.get("strain_gauge")
                if sg is None:
                    raise InputError("channels.strain_gauge.enabled is false on this rig")
                g = self.cfg.channels.strain_gauge
                e = strain_mod.shunt_equivalent_strain(g.nominal_resistance_ohm, g.gage_factor,
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
        check_bridge(sensor)
        return {"hardware_nulling": False}

    def shunt(self, sensor: str, on: bool, resistor_ohm: float) -> None:
        if sensor != "strain_gauge":
            raise InputError(f"sensor: the simulated bench shunts only the strain gauge, "
                             f"got {sensor!r}")
        self.shunt_on = bool(on)
        self.shunt_resistor = float(resistor_ohm)

    def drive_static(self, demand_n: np.ndarray) -> np.ndarray:
        from rig.sim_backend.drive_model import DriveResponse

        cfg = self.cfg
        spc = cfg.rates.samples_per_cycle
        drive = DriveResponse(1.0 / self.rate_hz, cfg.sim.drive_model, cfg.sim.process_time_unit_s)
        force = np.concatenate([np.maximum(drive.step(float(u), spc), 0.0)
                                for u in np.asarray(demand_n, float)])
        lc = self.sensors["load_cell"]
        lc.reset(0.0)
        return np.clip(lc.measure(force), -bridge_range(cfg, "load_cell"),
                       bridge_range(cfg, "load_cell"))

    def key_travel(self, force_n: np.ndarray) -> dict[str, np.ndarray]:
        from rig.sim_backend.simrig import SimRig

        if self._rig is None:
            self._rig = SimRig(self.cfg)
        rig = self._rig
        vpn = self.cfg.drive_scaling.volts_per_newton
        rows = np.vstack([rig.cycle(float(f) * vpn) for f in np.asarray(force_n, float)])
        raw = {s.name: s.raw for s in rig.table}
        return {name: rows[:, sensor_table.column(self.cfg, raw[name])]
                for name in self.cfg.channels.encoders}
