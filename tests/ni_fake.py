"""A recording fake of nidaqmx's interpreter: rig's NI code runs through nidaqmx's own Task,
channel, timing, trigger and stream classes, and only the DAQmx C calls are replaced.

    fake = FakeInterpreter()
    with fake.installed():          # patches nidaqmx.utils._select_interpreter
        task = nidaqmx.Task("x")    # nidaqmx's real Task, calling ``fake``

``fake.calls`` lists every DAQmx call in order as ``Call(name, task, args)`` (property writes
included: ``set_chan_attribute_double`` with the attribute id and value). Every method of
``nidaqmx._base_interpreter.BaseInterpreter`` that rig's code is not expected to reach raises
``UnexpectedCall`` naming it, so a new DAQmx call shows up as a failing test, not as a mock
that accepts anything. nidaqmx's classes declare ``__slots__``: a misspelled property raises
AttributeError before it reaches here.

The fake cards: true time ``now`` (s) advances only when a pacing read waits for its sample
clock or a test calls ``sleep``. Each device's oscillator runs ``ppm[dev]`` parts per million
fast (card seconds = true seconds x (1 + ppm 1e-6)); a task takes its sample clock from its
``samp_clk_timebase_src`` device when one is set (the shared timebase over RTSI), else its own.
A counter counting a timebase terminal counts that oscillator's edges from its arm-start
trigger (mod 2**32, as the hardware's 32-bit counter). A start trigger ``/DevN/ai/StartTrigger``
fires when a task with analog inputs on DevN starts (and, for a triggered task, when its
own trigger fires). ``skip_ticks(n)`` makes the next hardware-timed single-point read wake
``n`` sample clocks late (the software missed them). The acquisition's reads return
``ai_fill`` (broadcast to the (channels x samples) array, rows in the task's channel order)
and ``ci_fill`` (one value or array for every counter, or a dict by task name), ``avail``
samples being available.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any
from unittest import mock

import nidaqmx.utils
from nidaqmx._base_interpreter import BaseInterpreter
from nidaqmx.errors import DaqError

# DAQmx attribute ids that the fake gives meaning to (from nidaqmx 1.7's generated classes)
TASK_NAME, TASK_CHANNELS = 0x1276, 0x1273
TIMEBASE_SRC, TIMEBASE_RATE = 0x1308, 0x1303
LOWPASS_ENABLE, LOWPASS_CUTOFF = 0x1802, 0x1803
AVAIL_SAMPS, TOTAL_ACQUIRED, INPUT_BUF_SIZE, NUM_CHANS = 0x1223, 0x192A, 0x186C, 0x217B
ARM_START_TRIG_TYPE, DIG_EDGE_ARM_START_SRC = 0x1414, 0x1417
CHAN_TYPE = 0x187F
EXCIT_VAL = 0x17F5
CI_COUNT_EDGES_TERM = 0x18C7
SHUNT_GAIN_ADJUST = 0x193F
TIMEOUT_ERROR = -200284       # DAQmx: samples not yet acquired before the timeout
COUNTER_MOD = 2 ** 32
BASE_RATES = {"20MHzTimebase": 20e6, "100kHzTimebase": 100e3, "80MHzTimebase": 80e6}


class UnexpectedCall(AssertionError):
    """rig's code made a DAQmx call the fake does not model (or a call in a wrong state)."""


@dataclass
class Call:
    name: str
    task: str | None
    args: dict[str, Any]


@dataclass
class Chan:
    name: str
    physical: str
    kind: str
    args: dict[str, Any]
    attrs: dict[int, Any] = field(default_factory=dict)

    @property
    def device(self) -> str:
        return self.physical.strip("/").split("/")[0]


@dataclass
class FakeTask:
    handle: int
    name: str
    chans: list[Chan] = field(default_factory=list)
    timing: dict[str, Any] = field(default_factory=dict)       # cfg_samp_clk_timing's args
    attrs: dict[tuple[str, int], Any] = field(default_factory=dict)  # (scope, id) -> value
    start_trigger: str = ""
    started: bool = False
    closed: bool = False
    t_start: float | None = None    # true time its clock started (trigger fired)
    t_arm: float | None = None      # counters: true time counting began
    last_edge: int = -1             # hardware-timed single point: edge of the last read
    reads: int = 0

    @property
    def kind(self) -> str:
        return self.chans[0].kind[:2] if self.chans else ""

    @property
    def device(self) -> str:
        return self.chans[0].device if self.chans else ""


class _Interpreter:
    """The modelled part of the interpreter (the class below fills in the rest)."""

    def __init__(self, ppm: dict[str, float] | None = None) -> None:
        self.calls: list[Call] = []
        self.tasks: dict[int, FakeTask] = {}
        self.ppm: dict[str, float] = dict(ppm or {})
        self.now = 0.0
        self.read_latency_s = 5e-6   # true time from a sample clock edge to the read's return
        self.ao: dict[str, float] = {}          # physical AO channel -> volts on the pin
        self.stuck: dict[str, float] = {}       # a pin that reads back this whatever is written
        self.events: list[tuple[str, Any]] = []  # ("ao", (channel, volts)) and tests' own
        self.fail: dict[str, DaqError] = {}      # call name -> error raised at its next call
        self._skip = 0
        self._next = 1
        self._last_chan = ""
        self.first_edge_periods = 0   # sample clock's first edge this many periods after start
        self.digitizer = {"SC1Mod1": "Dev2"}   # SCXI module -> the card that digitizes it
        self.ai_fill: Any = 0.0      # what bridge reads return (broadcast to the array)
        self.ci_fill: Any = 0.0      # what encoder reads return (a dict: by task name)
        self.avail = 0

    # ---- helpers for tests ----
    def sleep(self, seconds: float) -> None:
        self.now += seconds

    def skip_ticks(self, n: int = 1) -> None:
        self._skip += n

    def task(self, name: str) -> FakeTask:
        found = [t for t in self.tasks.values() if t.name == name]
        if not found:
            names = [t.name for t in self.tasks.values()]
            raise KeyError(f"no task named {name!r}; tasks: {names}")
        return found[-1]

    def of(self, name: str, task: str | None = None) -> list[Call]:
        return [c for c in self.calls if c.name == name and (task is None or c.task == task)]

    def sets(self, task: str, attribute: int) -> list[Any]:
        """Values written to ``attribute`` on ``task`` (any scope), in order."""
        return [c.args["value"] for c in self.calls if c.name.startswith("set_")
                and c.task == task and c.args.get("attribute") == attribute]

    @contextlib.contextmanager
    def installed(self) -> Iterator[FakeInterpreter]:
        with mock.patch.object(nidaqmx.utils, "_select_interpreter",
                               lambda grpc_options=None, interpreter=None: self):
            yield self  # type: ignore[misc]

    # ---- internals ----
    def _rec(self, name: str, task: int | None, **args: Any) -> FakeTask | None:
        t = self.tasks.get(task) if task is not None else None
        self.calls.append(Call(name, t.name if t else None, args))
        if name in self.fail:
            raise self.fail.pop(name)
        if t is not None and t.closed:
            raise UnexpectedCall(f"{name} on task {t.name!r} after it was cleared")
        return t

    def _t(self, task: int) -> FakeTask:
        t = self.tasks.get(task)
        if t is None:
            raise UnexpectedCall(f"unknown task handle {task!r}")
        return t

    def _clock_device(self, t: FakeTask) -> str:
        src = t.attrs.get(("timing", TIMEBASE_SRC), "")
        return src.strip("/").split("/")[0] if src else self._dev(t)

    def _dev(self, t: FakeTask) -> str:
        return self.digitizer.get(t.device, t.device)

    def _factor(self, device: str) -> float:
        return 1.0 + self.ppm.get(device, 0.0) * 1e-6

    def _fire_triggers(self) -> None:
        """Start the clocks of started tasks whose start trigger has fired."""
        changed = True
        while changed:
            changed = False
            for t in self.tasks.values():
                if t.closed or not t.started or t.t_start is not None:
                    continue
                src = t.start_trigger
                if not src:
                    t.t_start = self.now
                    changed = True
                    continue
                fired = self._terminal_time(src)
                if fired is not None:
                    t.t_start = fired
                    changed = True

    def _terminal_time(self, terminal: str) -> float | None:
        """When a start-trigger terminal fired (None: not yet)."""
        m = re.fullmatch(r"/?(\w+)/ai/StartTrigger", terminal)
        if not m:
            raise UnexpectedCall(f"the fake models only /DevN/ai/StartTrigger, not {terminal!r}")
        for t in self.tasks.values():
            if self._dev(t) == m.group(1) and t.kind == "ai" and t.t_start is not None:
                return t.t_start
        return None

    def _counted_rate(self, term: str) -> tuple[float, str]:
        """(edges per card second, clock device) of a counted terminal."""
        m = re.fullmatch(r"/?(\w+)/(\w+)", term)
        m2 = re.fullmatch(r"/?(\w+)/ai/SampleClockTimebase", term)
        if m2:
            ai = [t for t in self.tasks.values() if self._dev(t) == m2.group(1) and t.kind == "ai"
                  and not t.closed and t.timing]
            if not ai:
                raise UnexpectedCall(f"{term}: no timed analog-input task on {m2.group(1)}")
            t = ai[-1]
            src = t.attrs.get(("timing", TIMEBASE_SRC), "")
            rate = t.attrs.get(("timing", TIMEBASE_RATE))
            if rate is None:
                rate = BASE_RATES[src.rsplit("/", 1)[1]] if src else 20e6
            return float(rate), self._clock_device(t)
        if m and m.group(2) in BASE_RATES:
            return BASE_RATES[m.group(2)], m.group(1)
        raise UnexpectedCall(f"the fake cannot count edges of terminal {term!r}")

    def _count(self, t: FakeTask) -> int:
        ch = t.chans[0]
        term = ch.attrs.get(CI_COUNT_EDGES_TERM)
        if term is None:
            raise UnexpectedCall(f"counter {ch.physical}: ci_count_edges_term was never set")
        if t.attrs.get(("trig", ARM_START_TRIG_TYPE)) is not None and t.t_arm is None:
            src = t.attrs.get(("trig", DIG_EDGE_ARM_START_SRC), "")
            t.t_arm = self._terminal_time(src) if src else None
            if t.t_arm is None:
                return 0
        rate, dev = self._counted_rate(term)
        assert t.t_arm is not None
        return int(math.floor((self.now - t.t_arm) * self._factor(dev) * rate + 1e-6)) % COUNTER_MOD

    # ---- tasks ----
    def create_task(self, session_name: str) -> tuple[int, bool]:
        h = self._next
        self._next += 1
        self.tasks[h] = FakeTask(h, session_name)
        self._rec("create_task", h, session_name=session_name)
        return h, True

    def hash_task_handle(self, task_handle: int) -> int:
        return hash(task_handle)

    def clear_task(self, task: int) -> None:
        t = self._rec("clear_task", task)
        assert t is not None
        t.closed = True

    def start_task(self, task: int) -> None:
        t = self._rec("start_task", task)
        assert t is not None
        t.started = True
        if t.kind == "ci" and t.attrs.get(("trig", ARM_START_TRIG_TYPE)) is None:
            t.t_arm = self.now
        self._fire_triggers()

    def stop_task(self, task: int) -> None:
        t = self._rec("stop_task", task)
        assert t is not None
        t.started = False
        t.t_start = None

    def get_task_attribute_string(self, task: int, attribute: int) -> str:
        t = self._t(task)
        if attribute == TASK_NAME:
            return t.name
        if attribute == TASK_CHANNELS:
            return ", ".join(c.name for c in t.chans)
        raise UnexpectedCall(f"get_task_attribute_string 0x{attribute:X}")

    # ---- channels ----
    def _chan(self, kind: str, task: int, physical: str, name: str, **args: Any) -> None:
        t = self._rec(f"create_{kind}_chan", task, physical_channel=physical,
                      name_to_assign_to_channel=name, **args)
        assert t is not None
        if t.chans and t.chans[0].kind[:2] != kind[:2]:
            raise UnexpectedCall(f"task {t.name}: {kind} channel added to a {t.kind} task")
        t.chans.append(Chan(name or physical, physical, kind, args))
        self._last_chan = name or physical

    def internal_get_last_created_chan(self) -> str:
        return self._last_chan

    def create_ai_voltage_chan(self, task, physical_channel, name_to_assign_to_channel,
                               terminal_config, min_val, max_val, units, custom_scale_name):
        self._chan("ai_voltage", task, physical_channel, name_to_assign_to_channel,
                   terminal_config=terminal_config, min_val=min_val, max_val=max_val,
                   units=units, custom_scale_name=custom_scale_name)

    def create_ai_bridge_chan(self, task, physical_channel, name_to_assign_to_channel, min_val,
                              max_val, units, bridge_config, voltage_excit_source,
                              voltage_excit_val, nominal_bridge_resistance, custom_scale_name):
        self._excitation = voltage_excit_val
        self._chan("ai_bridge", task, physical_channel, name_to_assign_to_channel,
                   min_val=min_val, max_val=max_val, units=units, bridge_config=bridge_config,
                   voltage_excit_source=voltage_excit_source,
                   voltage_excit_val=voltage_excit_val,
                   nominal_bridge_resistance=nominal_bridge_resistance,
                   custom_scale_name=custom_scale_name)
        self._t(task).chans[-1].attrs[EXCIT_VAL] = float(self._excitation)

    def create_ao_voltage_chan(self, task, physical_channel, name_to_assign_to_channel, min_val,
                               max_val, units, custom_scale_name):
        self._chan("ao_voltage", task, physical_channel, name_to_assign_to_channel,
                   min_val=min_val, max_val=max_val, units=units,
                   custom_scale_name=custom_scale_name)

    def create_ci_ang_encoder_chan(self, task, counter, name_to_assign_to_channel,
                                   decoding_type, zidx_enable, zidx_val, zidx_phase, units,
                                   pulses_per_rev, initial_angle, custom_scale_name):
        self._chan("ci_ang_encoder", task, counter, name_to_assign_to_channel,
                   decoding_type=decoding_type, zidx_enable=zidx_enable, units=units,
                   pulses_per_rev=pulses_per_rev, initial_angle=initial_angle)

    def create_ci_lin_encoder_chan(self, task, counter, name_to_assign_to_channel,
                                   decoding_type, zidx_enable, zidx_val, zidx_phase, units,
                                   dist_per_pulse, initial_pos, custom_scale_name):
        self._chan("ci_lin_encoder", task, counter, name_to_assign_to_channel,
                   decoding_type=decoding_type, zidx_enable=zidx_enable, units=units,
                   dist_per_pulse=dist_per_pulse, initial_pos=initial_pos)

    def create_ci_count_edges_chan(self, task, counter, name_to_assign_to_channel, edge,
                                   initial_count, count_direction):
        self._chan("ci_count_edges", task, counter, name_to_assign_to_channel, edge=edge,
                   initial_count=initial_count, count_direction=count_direction)

    # ---- timing and triggers ----
    def cfg_samp_clk_timing(self, task, rate, source, active_edge, sample_mode, samps_per_chan):
        t = self._rec("cfg_samp_clk_timing", task, rate=rate, source=source,
                      active_edge=active_edge, sample_mode=sample_mode,
                      samps_per_chan=samps_per_chan)
        assert t is not None
        t.timing = {"rate": rate, "source": source, "sample_mode": sample_mode,
                    "samps_per_chan": samps_per_chan}

    def cfg_dig_edge_start_trig(self, task, trigger_source, trigger_edge):
        t = self._rec("cfg_dig_edge_start_trig", task, trigger_source=trigger_source,
                      trigger_edge=trigger_edge)
        assert t is not None
        t.start_trigger = trigger_source

    def disable_start_trig(self, task):
        t = self._rec("disable_start_trig", task)
        assert t is not None
        t.start_trigger = ""

    # ---- calibration ----
    def perform_bridge_offset_nulling_cal_ex(self, task, channel, skip_unsupported_channels):
        self._rec("perform_bridge_offset_nulling_cal_ex", task, channel=channel,
                  skip_unsupported_channels=skip_unsupported_channels)

    def perform_bridge_shunt_cal_ex(self, task, channel, shunt_resistor_value,
                                    shunt_resistor_location, shunt_resistor_select,
                                    shunt_resistor_source, bridge_resistance,
                                    skip_unsupported_channels):
        t = self._rec("perform_bridge_shunt_cal_ex", task, channel=channel,
                      shunt_resistor_value=shunt_resistor_value,
                      shunt_resistor_location=shunt_resistor_location,
                      shunt_resistor_select=shunt_resistor_select,
                      shunt_resistor_source=shunt_resistor_source,
                      bridge_resistance=bridge_resistance)
        assert t is not None
        for c in t.chans:
            if c.name == channel:
                c.attrs[SHUNT_GAIN_ADJUST] = 1.0021

    # ---- reads and writes ----
    def read_analog_scalar_f64(self, task, timeout):
        t = self._rec("read_analog_scalar_f64", task, timeout=timeout)
        assert t is not None
        if not t.timing:   # on demand: an internal channel reading back an analog output
            phys = t.chans[0].physical
            m = re.fullmatch(r"(\w+)/_(ao\d+)_vs_aognd", phys)
            if not m:
                raise UnexpectedCall(f"on-demand read of {phys}")
            pin = f"{m.group(1)}/{m.group(2)}"
            return self.stuck.get(pin, self.ao.get(pin, 0.0))
        if not t.started:
            raise UnexpectedCall(f"read on task {t.name} before it was started")
        self._fire_triggers()
        if t.t_start is None:   # its start trigger never fired
            self.now += timeout
            raise DaqError("Some or all of the samples requested have not yet been acquired.",
                           TIMEOUT_ERROR, task_name=t.name)
        period = 1.0 / t.timing["rate"]
        f = self._factor(self._clock_device(t))
        # the first edge at or after now, at least one after the last read, plus skipped ones
        elapsed_card = (self.now - t.t_start) * f
        d = self.first_edge_periods   # edge k comes (k + d) periods after the trigger
        k = max(t.last_edge + 1, math.ceil(elapsed_card / period - d - 1e-9)) + self._skip
        self._skip = 0
        t.last_edge = k
        t.reads += 1
        self.now = max(self.now, t.t_start + (k + d) * period / f) + self.read_latency_s
        return 0.0

    def read_counter_scalar_u32(self, task, timeout):
        t = self._rec("read_counter_scalar_u32", task, timeout=timeout)
        assert t is not None
        if not t.started:
            raise UnexpectedCall(f"read on counter task {t.name} before it was started")
        return self._count(t)

    def write_analog_scalar_f64(self, task, auto_start, timeout, value):
        t = self._rec("write_analog_scalar_f64", task, auto_start=auto_start, timeout=timeout,
                      value=value)
        assert t is not None
        if not (t.started or auto_start):
            raise UnexpectedCall(f"write on task {t.name} before it was started")
        self.ao[t.chans[0].physical] = float(value)
        self.events.append(("ao", (t.chans[0].physical, float(value))))
        return 1

    def write_analog_f64(self, task, num_samps_per_chan, auto_start, timeout, data_layout,
                         write_array):
        t = self._rec("write_analog_f64", task, num_samps_per_chan=num_samps_per_chan,
                      auto_start=auto_start, timeout=timeout, values=list(write_array))
        assert t is not None
        if t.timing:
            raise UnexpectedCall("buffered writes are not modelled")
        value = float(write_array[-1])
        self.ao[t.chans[0].physical] = value
        self.events.append(("ao", (t.chans[0].physical, value)))
        return num_samps_per_chan

    def read_analog_f64(self, task, num_samps_per_chan, timeout, fill_mode, read_array):
        self._rec("read_analog_f64", task, num_samps_per_chan=num_samps_per_chan,
                  timeout=timeout, fill_mode=fill_mode)
        read_array[:] = self.ai_fill   # (channels x samples) of the reader's array
        return read_array, num_samps_per_chan

    def read_counter_f64_ex(self, task, num_samps_per_chan, timeout, fill_mode, read_array):
        t = self._rec("read_counter_f64_ex", task, num_samps_per_chan=num_samps_per_chan,
                      timeout=timeout, fill_mode=fill_mode)
        assert t is not None
        fill = self.ci_fill
        read_array[:] = fill[t.name] if isinstance(fill, dict) else fill
        return read_array, num_samps_per_chan

    # ---- properties: every get/set/reset of an attribute, recorded with its id ----
    def _attr(self, op: str, scope: str, typ: str, task: int, args: tuple[Any, ...]) -> Any:
        name = f"{op}_{scope}_attribute_{typ}"
        chan_scoped = scope in ("chan", "physical_chan")
        channel = args[0] if chan_scoped else None
        rest = args[1:] if chan_scoped else args
        attribute = rest[0]
        rec: dict[str, Any] = {"attribute": attribute}
        if channel is not None:
            rec["channel"] = channel
        if op == "set":
            rec["value"] = rest[1]
        t = self._rec(name, task, **rec)
        assert t is not None
        if chan_scoped:
            chans = [c for c in t.chans if channel in ("", c.name, c.physical)]
            if not chans:
                raise UnexpectedCall(f"{name}: no channel {channel!r} in task {t.name}")
            if op == "set":
                for c in chans:
                    c.attrs[attribute] = rest[1]
                return None
            if op == "reset":
                for c in chans:
                    c.attrs.pop(attribute, None)
                return None
            c = chans[0]
            if attribute in c.attrs:
                return c.attrs[attribute]
            if attribute == CHAN_TYPE:
                return {"ai": 10100, "ao": 10102, "ci": 10131}[c.kind[:2]]
            raise UnexpectedCall(f"{name} 0x{attribute:X} on {c.name}: never set, and the "
                                 f"fake has no value for it")
        key = (scope, attribute)
        if op == "set":
            t.attrs[key] = rest[1]
            return None
        if op == "reset":
            t.attrs.pop(key, None)
            return None
        if key in t.attrs:
            return t.attrs[key]
        if scope == "read" and attribute == AVAIL_SAMPS:
            return self.avail
        if scope == "read" and attribute == TOTAL_ACQUIRED:
            return t.reads
        if scope == "read" and attribute == NUM_CHANS:
            return len(t.chans)
        if scope == "buffer" and attribute == INPUT_BUF_SIZE:
            n = int(t.timing.get("samps_per_chan") or 0)
            return max(n, 10000) if t.timing.get("sample_mode") is not None else 0
        raise UnexpectedCall(f"{name} 0x{attribute:X} on task {t.name}: the fake has no value")


_ATTR = re.compile(r"(get|set|reset)_(chan|timing|trig|read|write|buffer|task)_attribute_(\w+)")


def _make(name: str) -> Any:
    m = _ATTR.fullmatch(name)
    if m:
        op, scope, typ = m.groups()

        def attr(self: _Interpreter, task: int, *args: Any) -> Any:
            return self._attr(op, scope, typ, task, args)

        attr.__name__ = name
        return attr

    def unexpected(self: _Interpreter, *args: Any, **kwargs: Any) -> Any:
        raise UnexpectedCall(f"rig's code called DAQmx {name}{args}: not modelled by the fake "
                             f"interpreter (tests/ni_fake.py); model it or fix the call")

    unexpected.__name__ = name
    return unexpected


def _build() -> type:
    body: dict[str, Any] = {}
    for name in sorted(BaseInterpreter.__abstractmethods__):
        if name in vars(_Interpreter):
            continue
        if name == "driver_version":
            body[name] = property(lambda self: (24, 8, 0))
            continue
        attr = inspect.getattr_static(BaseInterpreter, name)
        if isinstance(attr, property):
            raise RuntimeError(f"unhandled abstract property {name}")
        body[name] = _make(name)
    return type("FakeInterpreter", (_Interpreter, BaseInterpreter), body)


FakeInterpreter: Any = _build()
