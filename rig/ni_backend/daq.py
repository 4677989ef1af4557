"""The NI-DAQmx backend over the real ``nidaqmx`` package.

Loop side (``NiDaq``, PCI-6229): an on-demand analog-output task to the drive
and a hardware-timed single-point (HWTSP) analog-input task on the same card
at 500 Hz. nidaqmx-python has no wait-for-next-sample-clock call, so the loop
is paced by the HWTSP read, which blocks until the card's next sample clock
(NI's control-loop pattern); the analog output is written right after.

One clock: the pacing task's sample clock divides the acquisition card's timebase
(``channels.pacing.timebase_source``, over the RTSI cable), so tick n and the 2 kHz
sample 4n stay together for the whole run; the pacing task starts on the acquisition
card's start trigger. Time on the card: a counter of the pacing card
(``channels.pacing.clock_counter``) counts that timebase's edges from the pacing
start (armed by its start trigger), so sample-clock edge k is k x divisor (timebase
rate / control rate) counts after the first edge (the one the first read returns at,
whether the card puts it at the trigger or a period later), on the same oscillator.
The tick's index is the number of sample-clock edges passed when the read returns
(missed ticks: edges, not reads); a tick's lateness is the count read just after the
write minus the edge's count, in the card's seconds (``write_lateness``;
``Tick.lateness_s`` is the same at the wake-up). No PC clock enters, so a card
running 50-100 ppm off drifts nothing.

Safety: ``zero_output`` opens the drive's task, writes 0 V and reads it back on the
card's internal channel (``channels.drive_output.readback_channel``) before the run
service enables the drive; a failed 0 V write (``write_volts(0)``, ``close``) falls
back to a fresh task on the same channel.

Acquisition side (``NiReader``, PCI-6034E + SCXI-1520, PCI-6602): the sensors
of ``rig.sensors.table.sensors``, each set up by its kind's ``channels.NI_CHANNELS``: one
continuous AI task with the analog ones (the load-cell and strain bridges, V/V,
the SCXI-1520's lowpass set from the config) at 2 kHz, and one counter task per
counter (the encoders: ticks, x4) clocked from the AI sample clock; counters start
before the AI task. Buffer overwrite / overflow errors and a full buffer
(``in_stream.input_buf_size``) stop the run. With the run's calibration
(``spec["bridge_cal"]``), the strain bridge is nulled and shunt-calibrated with the
record's resistor before the run, as its calibration did.
"""

from __future__ import annotations

import contextlib
import time
from multiprocessing import shared_memory
from typing import Any

import nidaqmx
import nidaqmx.errors
import nidaqmx.stream_readers
import nidaqmx.stream_writers
import numpy as np
from nidaqmx.constants import (
    AcquisitionType,
    AOIdleOutputBehavior,
    OverwriteMode,
    TriggerType,
)
from nidaqmx.error_codes import DAQmxErrors

from rig.daq import Daq, DaqFault, Reader, Tick
from rig.errors import InputError
from rig.inputs.config import RigConfig, from_mapping
from rig.ni_backend import channels
from rig.sensors import table as sensor_table

# the DAQmx errors that mean samples were lost (buffer or FIFO overflow, counter overrun)
OVERFLOW_ERRORS = frozenset({
    DAQmxErrors.SAMPLES_NO_LONGER_AVAILABLE,
    DAQmxErrors.ACQ_STOPPED_TO_PREVENT_INPUT_BUFFER_OVERWRITE,
    DAQmxErrors.COUNTER_OVERFLOW, DAQmxErrors.CI_OVERRUN, DAQmxErrors.INPUT_FIFO_OVERFLOW,
    DAQmxErrors.INPUT_FIFO_OVERFLOW_2})


def _error_name(code: int) -> str:
    """DAQmx's name of an error code (its number when nidaqmx does not know it)."""
    try:
        return f"{DAQmxErrors(code).name} ({code})"
    except ValueError:
        return str(code)


def new_task(name: str) -> Any:
    """A task, or a one-line error when there is no NI driver (never a simulation)."""
    try:
        return nidaqmx.Task(name)
    except nidaqmx.errors.Error as exc:
        if isinstance(exc, nidaqmx.errors.DaqError):
            raise
        raise DaqFault(f"backend: ni: NI-DAQmx is not available on this machine "
                       f"({type(exc).__name__}); use a sim rig config to simulate") from None


def zero_with_fresh_task(cfg: RigConfig, name: str = "rig-safe-stop") -> None:
    """0 V on the drive's AO channel from a new on-demand task (the loop's task failed or is
    gone; the card holds its last value); on cards with the setting, 0 V whenever no
    generation runs (``ao_idle_output_behavior``; not on the M-series 6229)."""
    out = cfg.channels.drive_output
    task = new_task(name)
    try:
        chan = task.ao_channels.add_ao_voltage_chan(out.physical_channel,
                                                    min_val=out.min_volts,
                                                    max_val=out.max_volts)
        with contextlib.suppress(nidaqmx.errors.DaqError):  # M-series (6229): no setting
            chan.ao_idle_output_behavior = AOIdleOutputBehavior.ZERO_VOLTS
        nidaqmx.stream_writers.AnalogSingleChannelWriter(task.out_stream, auto_start=True) \
            .write_one_sample(0.0, timeout=1.0)
    finally:
        task.close()


COUNTER_MOD = 2 ** 32  # the card's counters are 32 bits wide


class NiDaq(Daq):
    """Drive output and 500 Hz pacing on the PCI-6229, timed by the acquisition card's clock."""

    def __init__(self, config: RigConfig) -> None:
        super().__init__(config)
        p = config.channels.pacing
        q = p.timebase_rate_hz / config.rates.control_hz
        if abs(q - round(q)) > 1e-9 * q:
            raise InputError(f"rig config: channels.pacing.timebase_rate_hz: expected a whole "
                             f"multiple of rates.control_hz ({config.rates.control_hz:g} Hz), "
                             f"got {p.timebase_rate_hz:g} Hz")
        self.divisor = int(round(q))        # timebase edges per sample-clock period
        new_task("rig-probe").close()  # no driver or cards: fail now, before anything starts
        self.feedback = shared_memory.SharedMemory(create=True, size=16)
        self._fb = np.ndarray((2,), np.float64, self.feedback.buf)
        self._fb[:] = (-1.0, 0.0)
        self.ao: Any = None
        self.writer: Any = None
        self.pace: Any = None
        self.clock: Any = None
        self.index = -1
        self._raw = 0           # last raw 32-bit count
        self._count = 0         # unwrapped count of timebase edges since the pacing start
        self._write_count: int | None = None
        self._edge0 = 0         # timebase periods of the first sample-clock edge
        self._closed = False

    def reader_spec(self) -> dict[str, Any]:
        return {"backend": "ni", "config": self.config.model_dump(mode="json"),
                "feedback": self.feedback.name}

    def zero_output(self) -> float | None:
        """Open the drive's output task, write 0 V and read the pin back: called before the
        drive is enabled, so whatever a test panel or a failed session left on the output
        never reaches the motor. DaqFault if the read back is not 0 V."""
        out = self.config.channels.drive_output
        if self.ao is None:
            self.ao = new_task("rig-drive")
            self.ao.ao_channels.add_ao_voltage_chan(out.physical_channel,
                                                    min_val=out.min_volts,
                                                    max_val=out.max_volts)
            self.writer = nidaqmx.stream_writers.AnalogSingleChannelWriter(self.ao.out_stream)
            self.ao.start()
        self.writer.write_one_sample(0.0, timeout=1.0)
        if not out.readback_channel:
            return None
        task = new_task("rig-drive-readback")
        try:
            task.ai_channels.add_ai_voltage_chan(out.readback_channel, min_val=-10.0,
                                                 max_val=10.0)
            volts = float(nidaqmx.stream_readers.AnalogSingleChannelReader(task.in_stream)
                          .read_one_sample(timeout=1.0))
        finally:
            task.close()
        if abs(volts) > out.zero_tolerance_volts:
            raise DaqFault(f"drive output: {out.readback_channel} reads {volts:.4f} V after "
                           f"0 V was written to {out.physical_channel} (tolerance "
                           f"{out.zero_tolerance_volts:g} V): the drive stays disabled")
        return volts

    def arm(self) -> None:
        cfg = self.config
        p = cfg.channels.pacing
        if self.ao is None:
            self.zero_output()
        self.pace = new_task("rig-pacing")
        self.pace.ai_channels.add_ai_voltage_chan(p.physical_channel, min_val=-10.0,
                                                  max_val=10.0)
        self.pace.timing.cfg_samp_clk_timing(cfg.rates.control_hz,
                                             sample_mode=AcquisitionType.HW_TIMED_SINGLE_POINT)
        if p.timebase_source:
            self.pace.timing.samp_clk_timebase_src = p.timebase_source
            self.pace.timing.samp_clk_timebase_rate = p.timebase_rate_hz
        if p.start_trigger:
            self.pace.triggers.start_trigger.cfg_dig_edge_start_trig(p.start_trigger)
        self.pace_reader = nidaqmx.stream_readers.AnalogSingleChannelReader(self.pace.in_stream)
        self.clock = new_task("rig-card-clock")
        chan = self.clock.ci_channels.add_ci_count_edges_chan(p.clock_counter)
        chan.ci_count_edges_term = p.clock_counter_source
        arm = self.clock.triggers.arm_start_trigger
        arm.trig_type = TriggerType.DIGITAL_EDGE
        arm.dig_edge_src = p.clock_counter_arm
        self.clock_reader = nidaqmx.stream_readers.CounterReader(self.clock.in_stream)
        self.clock.start()      # armed: counts from the pacing task's start trigger
        self.pace.start()

    def _card_count(self) -> int:
        """Timebase edges since the pacing start, unwrapped from the 32-bit counter."""
        raw = int(self.clock_reader.read_one_sample_uint32(timeout=1.0))
        self._count += (raw - self._raw) % COUNTER_MOD
        self._raw = raw
        return self._count

    def wait_for_tick(self) -> Tick:
        if self.pace is None:
            raise RuntimeError("arm() the NI rig before waiting for ticks")
        timeout = self.config.acquisition.start_timeout_s if self.index < 0 else 10 * self.dt
        try:
            self.pace_reader.read_one_sample(timeout=timeout)
            count = self._card_count()
        except nidaqmx.errors.DaqError as exc:
            raise DaqFault(f"pacing read failed ({exc.error_code}): {exc}") from None
        if self.index < 0:  # the first read returns at the first edge, whichever it is
            self._edge0 = count // self.divisor
        index = count // self.divisor - self._edge0    # sample-clock edges since the first
        missed = max(0, index - self.index - 1)
        self.index = index
        self._write_count = None
        return Tick(index, self._seconds_after(count, index), missed)

    def _seconds_after(self, count: int, index: int) -> float:
        """Card seconds from edge ``index``'s timebase count to ``count``."""
        return (count - (index + self._edge0) * self.divisor) * self.dt / self.divisor

    def write_volts(self, volts: float) -> None:
        if self.ao is None or self._closed:
            raise RuntimeError("the NI drive output is not armed")
        try:
            self.writer.write_one_sample(float(volts), timeout=self.dt)
        except nidaqmx.errors.DaqError as exc:
            if volts == 0.0:    # the loop's task cannot zero the drive: a fresh task can
                self._abandon_ao()
                zero_with_fresh_task(self.config)
            raise DaqFault(f"drive output write failed ({exc.error_code}): {exc}") from None
        if self.clock is not None and self.index >= 0:
            with contextlib.suppress(nidaqmx.errors.DaqError):
                self._write_count = self._card_count()

    def write_lateness(self, tick: Tick) -> float:
        """The write's lateness on the card's clock: the count read just after the write
        minus the tick's sample-clock edge (s)."""
        if self._write_count is None or tick.index != self.index:
            return tick.lateness_s
        return self._seconds_after(self._write_count, tick.index)

    def feedback_ratio(self) -> tuple[int, float]:
        return int(self._fb[0]), float(self._fb[1])

    def _abandon_ao(self) -> None:
        ao, self.ao = self.ao, None
        if ao is not None:
            with contextlib.suppress(nidaqmx.errors.Error):
                ao.close()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            if self.ao is not None:
                try:
                    self.writer.write_one_sample(0.0, timeout=1.0)
                except nidaqmx.errors.Error:
                    self._abandon_ao()
                    zero_with_fresh_task(self.config)
                finally:
                    self._abandon_ao()
        finally:
            for task in (self.pace, self.clock):
                if task is not None:
                    with contextlib.suppress(nidaqmx.errors.Error):
                        task.close()
            del self._fb
            self.feedback.close()
            with contextlib.suppress(FileNotFoundError):  # the supervisor may have removed it
                self.feedback.unlink()


class NiReader(Reader):
    """2 kHz bridges and encoders on one sample clock (runs in the acquisition process)."""

    def __init__(self, spec: dict[str, Any]) -> None:
        cfg = from_mapping(spec["config"])
        self.cfg = cfg
        ch = cfg.channels
        rate = cfg.rates.acquisition_hz
        buf = int(cfg.acquisition.buffer_s * rate)
        self.fb = shared_memory.SharedMemory(name=spec["feedback"]) if spec.get("feedback") \
            else None
        self.names = sensor_table.raw_names(cfg)
        table = sensor_table.sensors(cfg)
        self.ai = new_task("rig-bridges")
        chans = {s.name: channels.channel(cfg, s) for s in table}
        self.ai_names = [s.raw for s in table if not chans[s.name].counter]
        self.ai_sensors = [s.name for s in table if not chans[s.name].counter]  # DAQmx names
        for s in table:
            if not chans[s.name].counter:
                chans[s.name].add(self.ai)
        self.ai.timing.cfg_samp_clk_timing(rate, sample_mode=AcquisitionType.CONTINUOUS,
                                           samps_per_chan=buf)
        self.ai.in_stream.overwrite = OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES
        self.ai_reader = nidaqmx.stream_readers.AnalogMultiChannelReader(self.ai.in_stream)
        self.ci: list[Any] = []
        self.ci_names = [s.raw for s in table if chans[s.name].counter]
        self.ci_readers: list[Any] = []
        for s in table:
            if not chans[s.name].counter:
                continue
            task = new_task(f"rig-encoder-{s.name}")
            chans[s.name].add(task)
            task.timing.cfg_samp_clk_timing(rate, source=ch.ai_sample_clock,
                                            sample_mode=AcquisitionType.CONTINUOUS,
                                            samps_per_chan=buf)
            self.ci.append(task)
            self.ci_readers.append(nidaqmx.stream_readers.CounterReader(task.in_stream))
        self.count = 0
        self.buffer = int(self.ai.in_stream.input_buf_size)  # what DAQmx allocated
        self.shunt_gain: dict[str, float | None] = {}
        if spec.get("bridge_cal") is not None:
            self.calibrate_bridges(spec["bridge_cal"])

    def calibrate_bridges(self, bridge_cal: dict[str, Any]) -> None:
        """Before the run (key unloaded, drive not enabled): each bridge whose calibration
        nulled it (``bridge_cal[sensor]["null"]``; the strain gauge) is nulled again on the
        run's fresh channel, and shunt-calibrated with the record's resistor
        (``shunt_resistor_ohm``). The record's gage factor already holds the shunt
        correction measured without the driver's gain, so the driver's gain adjustment is
        kept in ``shunt_gain`` (the run file's check) and the channel's set back to 1."""
        ch = self.cfg.channels
        for sensor in ("load_cell", "strain_gauge"):
            how = bridge_cal.get(sensor) or {}
            if sensor not in self.ai_sensors or not how.get("null"):
                continue
            rs = how.get("shunt_resistor_ohm")
            gain = channels.calibrate_load_cell(self.ai, ch.load_cell, sensor, rs) \
                if sensor == "load_cell" else \
                channels.calibrate_strain_gauge(self.ai, ch.strain_gauge, sensor, rs)
            self.shunt_gain[sensor] = gain
            if gain is not None:
                self.ai.ai_channels[sensor].ai_bridge_shunt_cal_gain_adjust = 1.0

    def bridge_settings(self) -> dict[str, dict[str, Any]]:
        """What the driver holds for each bridge channel, read back: the SCXI-1520's lowpass
        (on, cutoff Hz) and the excitation (V)."""
        out: dict[str, dict[str, Any]] = {}
        for name in self.ai_sensors:
            chan = self.ai.ai_channels[name]
            on = bool(chan.ai_lowpass_enable)
            out[name] = {"lowpass_enable": on,
                         "lowpass_cutoff_hz": float(chan.ai_lowpass_cutoff_freq) if on else None,
                         "excitation_volts": float(chan.ai_excit_val)}
        return out

    def start(self) -> None:
        for task in self.ci:  # counters wait for the AI sample clock
            task.start()
        self.ai.start()

    def read(self, timeout_s: float) -> np.ndarray:
        time.sleep(timeout_s)
        try:
            n = int(self.ai.in_stream.avail_samp_per_chan)
            if n >= self.buffer:
                raise DaqFault(f"acquisition buffer full ({n} samples): the next samples would "
                               f"be lost")
            if n == 0:
                return np.empty((0, len(self.names)))
            ai = np.empty((len(self.ai_names), n))
            self.ai_reader.read_many_sample(ai, number_of_samples_per_channel=n, timeout=1.0)
            counts = np.empty((len(self.ci), n))
            for j, r in enumerate(self.ci_readers):
                row = np.empty(n)
                r.read_many_sample_double(row, number_of_samples_per_channel=n, timeout=1.0)
                counts[j] = row
        except nidaqmx.errors.DaqError as exc:
            if exc.error_code in OVERFLOW_ERRORS:
                raise DaqFault(f"acquisition buffer overflow (DAQmx "
                               f"{_error_name(exc.error_code)}): samples were lost") from None
            raise DaqFault(f"acquisition read failed (DAQmx {_error_name(exc.error_code)}): "
                           f"{exc}") from None
        cols = {sensor_table.SAMPLE: self.count + np.arange(n, dtype=float),
                **dict(zip(self.ai_names, ai, strict=True)),
                **dict(zip(self.ci_names, counts, strict=True))}
        self.count += n
        return np.column_stack([cols[name] for name in self.names])

    def publish_feedback(self, sample: int, ratio: float) -> None:
        if self.fb is not None:
            fb = np.ndarray((2,), np.float64, self.fb.buf)
            fb[1] = ratio
            fb[0] = sample
            del fb

    def safe_stop(self) -> None:
        """The loop's process died: its drive task is gone but the card holds the last value,
        so a new task on the same AO channel writes 0 V (``zero_with_fresh_task``)."""
        zero_with_fresh_task(self.cfg)

    def release_orphaned(self) -> None:
        if self.fb is not None:
            with contextlib.suppress(FileNotFoundError):
                self.fb.unlink()

    def close(self) -> None:
        """Stop and close every task, the counters even when the AI task's stop fails; the
        first error is raised after all are closed."""
        first: BaseException | None = None
        for task in [self.ai, *self.ci]:
            for step in (task.stop, task.close):
                try:
                    step()
                except Exception as exc:
                    first = first or exc
        if self.fb is not None:
            self.fb.close()
        if first is not None:
            raise first


def bridge_calibration(cfg: RigConfig, full_records: list[dict[str, Any]]) -> dict[str, Any]:
    """How the run's fresh bridge channels are calibrated before the run (NI), as their
    calibration did: the strain gauge nulled and shunt-calibrated with its record's shunt
    resistor (the config's when the gauge runs on its data sheet); the load cell, whose
    calibration reads its offset with masses, is left as calibrated."""
    rec = next((r for r in full_records if r.get("sensor") == "strain_gauge"), None)
    rs = ((rec or {}).get("fit") or {}).get("shunt_resistor_ohm")
    if rs is None:
        rs = cfg.calibration.strain_gauge.shunt_resistor_ohm
    return {"load_cell": {"null": False, "shunt_resistor_ohm": None},
            "strain_gauge": {"null": cfg.channels.strain_gauge.enabled,
                             "shunt_resistor_ohm": float(rs),
                             "from": "calibration record" if rec else "config"}}
