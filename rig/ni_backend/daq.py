"""The NI-DAQmx backend over the real ``nidaqmx`` package.

Loop side (``NiDaq``, PCI-6229): an on-demand analog-output task to the drive
and a hardware-timed single-point (HWTSP) analog-input task on the same card
at 500 Hz. nidaqmx-python has no wait-for-next-sample-clock call, so the loop
is paced by the HWTSP read, which blocks until the card's next sample clock
(NI's control-loop pattern); the analog output is written right after.
Lateness = wake time minus the tick's expected time (first tick + n periods);
ticks missed while the software was late are counted from
``in_stream.total_samp_per_chan_acquired``. The pacing task starts on the
acquisition card's start trigger (RTSI) so tick n and sample 4n coincide.

Acquisition side (``NiReader``, PCI-6034E + SCXI-1520, PCI-6602): the sensors
of ``rig.calrecords.sensors``, each set up by its own ``ni_channel``: one
continuous AI task with the analog ones (the load-cell and strain bridges, V/V)
at 2 kHz, and one counter task per counter (the encoders: ticks, x4) clocked
from the AI sample clock; counters start before the AI task. Buffer overwrite /
overflow errors and a full buffer stop the run.
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
from nidaqmx.constants import AcquisitionType, AOIdleOutputBehavior, OverwriteMode
from nidaqmx.error_codes import DAQmxErrors

from rig import calrecords, loadcell, strain
from rig.config import RigConfig, from_mapping
from rig.daq import Daq, DaqFault, Reader, Tick

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


class NiDaq(Daq):
    """Drive output and 500 Hz pacing on the PCI-6229."""

    def __init__(self, config: RigConfig) -> None:
        super().__init__(config)
        new_task("rig-probe").close()  # no driver or cards: fail now, before anything starts
        self.feedback = shared_memory.SharedMemory(create=True, size=16)
        self._fb = np.ndarray((2,), np.float64, self.feedback.buf)
        self._fb[:] = (-1.0, 0.0)
        self.ao: Any = None
        self.pace: Any = None
        self.index = -1
        self.t_first = 0.0
        self._closed = False

    def reader_spec(self) -> dict[str, Any]:
        return {"backend": "ni", "config": self.config.model_dump(mode="json"),
                "feedback": self.feedback.name}

    def arm(self) -> None:
        cfg = self.config
        out = cfg.channels.drive_output
        self.ao = new_task("rig-drive")
        self.ao.ao_channels.add_ao_voltage_chan(out.physical_channel, min_val=out.min_volts,
                                                max_val=out.max_volts)
        self.writer = nidaqmx.stream_writers.AnalogSingleChannelWriter(self.ao.out_stream)
        self.ao.start()
        self.writer.write_one_sample(0.0, timeout=1.0)
        self.pace = new_task("rig-pacing")
        self.pace.ai_channels.add_ai_voltage_chan(cfg.channels.pacing.physical_channel,
                                                  min_val=-10.0, max_val=10.0)
        self.pace.timing.cfg_samp_clk_timing(cfg.rates.control_hz,
                                             sample_mode=AcquisitionType.HW_TIMED_SINGLE_POINT)
        if cfg.channels.pacing.start_trigger:
            self.pace.triggers.start_trigger.cfg_dig_edge_start_trig(
                cfg.channels.pacing.start_trigger)
        self.pace_reader = nidaqmx.stream_readers.AnalogSingleChannelReader(self.pace.in_stream)
        self.pace.start()

    def wait_for_tick(self) -> Tick:
        if self.pace is None:
            raise RuntimeError("arm() the NI rig before waiting for ticks")
        timeout = self.config.acquisition.start_timeout_s if self.index < 0 else 10 * self.dt
        try:
            self.pace_reader.read_one_sample(timeout=timeout)
        except nidaqmx.errors.DaqError as exc:
            raise DaqFault(f"pacing read failed ({exc.error_code}): {exc}") from None
        now = time.perf_counter()
        acquired = int(self.pace.in_stream.total_samp_per_chan_acquired)
        index = acquired - 1
        if self.index < 0:
            self.t_first = now - index * self.dt
        missed = max(0, index - self.index - 1)
        self.index = index
        return Tick(index, max(0.0, now - (self.t_first + index * self.dt)), missed)

    def write_volts(self, volts: float) -> None:
        if self.ao is None or self._closed:
            raise RuntimeError("the NI drive output is not armed")
        self.writer.write_one_sample(float(volts), timeout=self.dt)

    def feedback_ratio(self) -> tuple[int, float]:
        return int(self._fb[0]), float(self._fb[1])

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.ao is not None:
            try:
                self.writer.write_one_sample(0.0, timeout=1.0)
            finally:
                self.ao.close()
        if self.pace is not None:
            self.pace.close()
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
        self.names = calrecords.raw_names(cfg)
        table = calrecords.sensors(cfg)
        self.ai = new_task("rig-bridges")
        self.ai_names = [s.raw for s in table if not s.ni_counter]
        for s in table:
            if not s.ni_counter:
                s.ni_channel(self.ai)
        self.ai.timing.cfg_samp_clk_timing(rate, sample_mode=AcquisitionType.CONTINUOUS,
                                           samps_per_chan=buf)
        self.ai.in_stream.overwrite = OverwriteMode.DO_NOT_OVERWRITE_UNREAD_SAMPLES
        self.ai_reader = nidaqmx.stream_readers.AnalogMultiChannelReader(self.ai.in_stream)
        self.ci: list[Any] = []
        self.ci_names = [s.raw for s in table if s.ni_counter]
        self.ci_readers: list[Any] = []
        for s in table:
            if not s.ni_counter:
                continue
            task = new_task(f"rig-encoder-{s.name}")
            s.ni_channel(task)
            task.timing.cfg_samp_clk_timing(rate, source=ch.ai_sample_clock,
                                            sample_mode=AcquisitionType.CONTINUOUS,
                                            samps_per_chan=buf)
            self.ci.append(task)
            self.ci_readers.append(nidaqmx.stream_readers.CounterReader(task.in_stream))
        self.count = 0
        self.buffer = buf

    def calibrate_bridges(self) -> None:
        """Offset nulling and shunt calibration of both bridges (key unloaded)."""
        loadcell.ni_calibrate(self.ai, self.cfg.channels.load_cell)
        if "strain_ratio" in self.ai_names:
            strain.ni_calibrate(self.ai, self.cfg.channels.strain_gauge)

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
        cols = {calrecords.SAMPLE: self.count + np.arange(n, dtype=float),
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
        so a new task on the same AO channel writes 0 V (and, on cards that have the setting,
        asks for 0 V whenever no generation runs: ``ao_idle_output_behavior``)."""
        out = self.cfg.channels.drive_output
        task = new_task("rig-safe-stop")
        try:
            chan = task.ao_channels.add_ao_voltage_chan(out.physical_channel,
                                                        min_val=out.min_volts,
                                                        max_val=out.max_volts)
            with contextlib.suppress(nidaqmx.errors.DaqError):  # M-series (6229): no setting
                chan.ao_idle_output_behavior = AOIdleOutputBehavior.ZERO_VOLTS
            task.write(0.0, auto_start=True, timeout=1.0)
            task.stop()
        finally:
            task.close()

    def release_orphaned(self) -> None:
        if self.fb is not None:
            with contextlib.suppress(FileNotFoundError):
                self.fb.unlink()

    def close(self) -> None:
        for task in [self.ai, *self.ci]:
            try:
                task.stop()
            finally:
                task.close()
        if self.fb is not None:
            self.fb.close()
