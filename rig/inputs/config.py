"""The rig configuration: which cards and channels, drive scaling, limits, rates.

A YAML file (``rig.yaml``) validated by pydantic; every field is documented in
docs/rig-config.md. Bad input raises a one-line ``ValueError`` naming the
field (``rig.yaml: limits.max_force_n: ...``). SI units throughout; field
names carry the unit where it is not obvious.

    cfg = config.load("rig.yaml")           # or config.builtin_sim()
    cfg.backend                              # "ni" or "sim"
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from rig.errors import InputError
from rig.inputs.params import THESIS_TIME_UNIT_S, load_yaml_file

# Strict numbers (no bool, no numeric text) that must be finite: ``control_hz: true`` or
# ``buffer_s: .inf`` are refused rather than read as 1 Hz or an endless buffer.
_STRICT_FINITE = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False)

# The run's own channel names (rig/loop/acquisition.py, rig/sensors/table.py,
# rig/recordings/runfile.py): an encoder channel named like one of them would replace the
# load-cell force, the sample counter or the time base in the run file and blind the
# analysis and the safety checks.
RESERVED_CHANNELS = frozenset({
    "time", "sample", "force", "load_cell_ratio", "strain_ratio", "shank_strain",
    "tick", "target", "feedforward", "demand", "volts", "limited", "measured_force",
    "lateness", "missed", "pace_volts"})
MAX_DRIVE_POLL_PERIOD_S = 0.1  # a slower drive poll would see a drive fault too late
MAX_CONFIG_BYTES = 1_000_000  # a rig config is a few kB; a larger file is refused unread
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class _Strict(BaseModel):
    model_config = _STRICT_FINITE


# ---- the calibration: section (used by rig.calibration) ----
SENSORS = ("load_cell", "strain_gauge", "motor")  # what calibration.required may name


class LoadCellCal(_Strict):
    """Known-mass calibration of the load cell."""

    gravity_m_s2: float = Field(9.80665, gt=9.7, lt=9.9, description="local g; set it for the lab")
    gravity_rel_halfwidth: float = Field(
        0.003, ge=0, le=1, description="0.3 % covers any lab on Earth with standard g; ~1e-5 once "
                                 "the local g is set from a gravity map")
    mass_rel_halfwidth: float = Field(1e-4, ge=0, le=1, description="reference-mass tolerance "
                                                              "(OIML M1 ~ 5e-5 to 1e-4)")
    average_s: float = Field(1.0, gt=0, le=600, description="bridge averaging time per point")
    settle_s: float = Field(0.3, ge=0, le=600, description="discarded after placing a mass")
    min_points: int = Field(5, ge=3, le=1000)
    min_span_fraction: float = Field(0.2, gt=0, le=1, description="points must span this "
                                                                  "fraction of full scale")
    spec_nonlinearity_hysteresis_pct_fs: float = Field(0.5, gt=0, le=100)
    spec_nonrepeatability_pct_fs: float = Field(0.1, gt=0, le=100)
    saturation_fraction: float = Field(0.98, gt=0, le=1, description="a reading beyond this "
                                                                     "fraction of the range is "
                                                                     "saturated")


class StrainCal(_Strict):
    """Offset nulling and shunt calibration of the quarter-bridge gauge."""

    shunt_resistor_ohm: float = Field(100000.0, gt=0, le=1e12)
    shunt_rel_halfwidth: float = Field(0.001, ge=0, le=1, description="shunt resistor tolerance")
    gauge_resistance_rel_halfwidth: float = Field(0.003, ge=0, le=1, description="Rg tolerance")
    gage_factor_rel_halfwidth: float = Field(0.01, ge=0, le=1, description="gauge-factor tolerance "
                                             "(the shunt cannot see it)")
    tolerance: float = Field(0.05, gt=0, lt=1, description="|gain adjustment - 1| allowed")
    average_s: float = Field(1.0, gt=0, le=600)
    settle_s: float = Field(0.05, ge=0, le=600)


class MotorCal(_Strict):
    """Steps and ramps of demanded force with the arm on a static surface."""

    step_levels_n: list[float] = Field(default_factory=lambda: [5.0, 10.0, 15.0, 20.0, 25.0,
                                                                30.0, 35.0, 40.0])
    step_hold_s: float = Field(0.15, gt=0.05, le=60)
    ramp_s: float = Field(0.08, gt=0, le=60)
    max_lag_s: float = Field(0.05, gt=0, le=1)

    @field_validator("step_levels_n")
    @classmethod
    def _levels(cls, v: list[float]) -> list[float]:
        if len(v) > 100 or any(not 0 < x <= 120 for x in v):
            raise InputError("expected at most 100 forces in (0, 120] N")
        return v


class CalibrationSettings(_Strict):
    """The ``calibration:`` section of a rig configuration."""

    records_folder: Path | None = Field(None, strict=False,
                                        description="default <data_folder>/calibrations")
    max_age_days: float = Field(30.0, gt=0, le=36500,
                                description="older records are used with a warning")
    required: list[str] = Field(default_factory=lambda: ["load_cell", "strain_gauge"],
                                description="sensors a real-hardware run refuses to go without")
    use_raw_units: bool = Field(False, description="run on real hardware without records "
                                                   "(data-sheet values, marked nominal)")
    operator: str = Field("", description="default operator name (else the login name)")
    load_cell: LoadCellCal = LoadCellCal()
    strain_gauge: StrainCal = StrainCal()
    motor: MotorCal = MotorCal()

    @field_validator("required")
    @classmethod
    def _known(cls, v: list[str]) -> list[str]:
        unknown = [s for s in v if s not in SENSORS]
        if unknown:
            raise InputError(f"unknown sensor {unknown[0]!r} (expected some of "
                             f"{', '.join(SENSORS)})")
        return v


# ---- the rig ----
class DriveOutput(_Strict):
    """Analog output (PCI-6229) carrying the torque demand to the drive."""

    physical_channel: str = "Dev1/ao0"
    min_volts: float = Field(-10.0, ge=-10, le=0, description="lower clamp of the output "
                             "(V); <= 0 so that zero demand writes exactly 0 V")
    max_volts: float = Field(10.0, gt=0, le=10, description="upper clamp of the output (V)")
    readback_channel: str = Field(
        "Dev1/_ao0_vs_aognd",
        description="analog input that reads the output back (the M-series card's internal "
                    "channel of ao0): 0 V must read back before the drive is enabled; empty = "
                    "no read back")
    zero_tolerance_volts: float = Field(0.02, gt=0, le=0.5, description="largest read back "
                                        "value (V) accepted as 0 V before enabling the drive")

    @model_validator(mode="after")
    def _range(self) -> DriveOutput:
        if not self.min_volts < self.max_volts:
            raise InputError(f"min_volts: expected less than max_volts ({self.max_volts:g} V), "
                             f"got {self.min_volts:g} V")
        return self


class Pacing(_Strict):
    """Hardware-timed single-point analog input that paces the 500 Hz loop on NI.

    It must sit on the same card as the drive output (the PCI-6229); any spare
    input will do: its value is recorded as ``pace_volts`` but not used.
    """

    physical_channel: str = "Dev1/ai0"
    start_trigger: str = Field(
        "/Dev2/ai/StartTrigger",
        description="terminal of the acquisition card's start trigger (over RTSI) so the loop's "
                    "tick 0 and the 2 kHz sample 0 coincide; empty to start untriggered")
    timebase_source: str = Field(
        "/Dev2/20MHzTimebase",
        description="timebase the pacing card's sample clock divides: the acquisition card's "
                    "(over the RTSI cable) so both cards keep one clock; empty = the pacing "
                    "card's own oscillator (the two cards then drift apart)")
    timebase_rate_hz: float = Field(20e6, ge=1e3, le=1e9, description="rate of "
                                    "timebase_source; a whole multiple of rates.control_hz")
    clock_counter: str = Field(
        "Dev1/ctr0", description="counter on the pacing card that counts the pacing clock's "
                                 "timebase from the pacing start: the card's own time of each "
                                 "write (lateness and missed ticks)")
    clock_counter_source: str = Field(
        "/Dev1/ai/SampleClockTimebase",
        description="terminal the clock counter counts: the pacing task's sample-clock timebase")
    clock_counter_arm: str = Field(
        "/Dev1/ai/StartTrigger",
        description="terminal that starts the clock counter: the pacing task's start trigger")

    @model_validator(mode="after")
    def _counter(self) -> Pacing:
        if not self.clock_counter:
            raise InputError("clock_counter: required (the loop's lateness is measured on the "
                             "card's clock)")
        return self


SCXI_1520_LOWPASS_HZ = (10.0, 100.0, 1000.0, 10000.0)


def _scxi_lowpass(v: float | None) -> float | None:
    if v is not None and float(v) not in SCXI_1520_LOWPASS_HZ:
        raise InputError(f"expected one of the SCXI-1520's cutoffs "
                         f"{', '.join(f'{c:g}' for c in SCXI_1520_LOWPASS_HZ)} Hz or null (off), "
                         f"got {v!r}")
    return v


class LoadCell(_Strict):
    """Full-bridge load cell on the key top (Sensotec Model 13, 25 lb) via SCXI-1520."""

    physical_channel: str = "SC1Mod1/ai0"
    excitation_volts: float = Field(5.0, gt=0, le=10)
    bridge_resistance_ohm: float = Field(350.0, gt=0, le=1e6)
    rated_output_mv_per_v: float = Field(2.0, gt=0, le=100,
                                         description="bridge output at full scale")
    full_scale_n: float = Field(111.0, gt=0, le=1e5)
    input_range_mv_per_v: float = Field(3.0, gt=0, le=1000,
                                        description="+- range of the card channel")
    lowpass_hz: float | None = Field(100.0, description="SCXI-1520 4-pole lowpass cutoff "
                                     "(10, 100, 1000 or 10000 Hz; the thesis: 100); null = off")

    @field_validator("lowpass_hz")
    @classmethod
    def _lowpass(cls, v: float | None) -> float | None:
        return _scxi_lowpass(v)


class StrainGauge(_Strict):
    """Quarter-bridge (type I) strain gauge on the hammer shank, 350 ohm, via SCXI-1520."""

    enabled: bool = True
    physical_channel: str = "SC1Mod1/ai1"
    excitation_volts: float = Field(2.5, gt=0, le=10)
    gage_factor: float = Field(2.0, gt=0, le=1000)
    nominal_resistance_ohm: float = Field(350.0, gt=0, le=1e6)
    lead_wire_resistance_ohm: float = Field(0.0, ge=0, le=1e6)
    input_range_mv_per_v: float = Field(2.0, gt=0, le=1000)
    lowpass_hz: float | None = Field(100.0, description="SCXI-1520 4-pole lowpass cutoff "
                                     "(10, 100, 1000 or 10000 Hz; the thesis: 100); null = off")

    @field_validator("lowpass_hz")
    @classmethod
    def _lowpass(cls, v: float | None) -> float | None:
        return _scxi_lowpass(v)


class Encoder(_Strict):
    """One quadrature encoder on a PCI-6602 counter (x4 decoding)."""

    counter: str
    body: Literal["key", "whippen", "hammer", "jack", "repetition"]
    kind: Literal["angular", "linear"]
    counts_per_rev: float | None = Field(None, gt=0, le=1e12,
                                         description="after x4 decoding (angular)")
    metres_per_count: float | None = Field(None, gt=0, le=1,
                                           description="after x4 decoding (linear)")
    sign: Literal[1, -1] = 1
    initial_value: float = Field(0.0, description="rad or m at count 0 (the pose at start)")
    channel: str = Field("", description="calibrated channel name; default <body>_angle or "
                                         "key_dip / <body>_travel")

    @field_validator("sign", mode="before")
    @classmethod
    def _no_bool_sign(cls, v: Any) -> Any:
        if isinstance(v, bool):
            raise InputError(f"expected 1 or -1, got {v}")
        return v

    @model_validator(mode="after")
    def _resolution(self) -> Encoder:
        if self.kind == "angular" and self.counts_per_rev is None:
            raise InputError("counts_per_rev: required for an angular encoder")
        if self.kind == "linear" and self.metres_per_count is None:
            raise InputError("metres_per_count: required for a linear encoder")
        return self

    @property
    def channel_name(self) -> str:
        if self.channel:
            return self.channel
        if self.kind == "angular":
            return f"{self.body}_angle"
        return "key_dip" if self.body == "key" else f"{self.body}_travel"

    @property
    def units(self) -> str:
        return "rad" if self.kind == "angular" else "m"

    @property
    def si_per_count(self) -> float:
        """Nominal rad or m per count (after x4 decoding)."""
        if self.kind == "angular":
            assert self.counts_per_rev is not None
            return 2 * math.pi / self.counts_per_rev
        assert self.metres_per_count is not None
        return self.metres_per_count


def _default_encoders() -> dict[str, Encoder]:
    return {
        "key": Encoder(counter="Dev3/ctr0", body="key", kind="linear", metres_per_count=0.5e-6),
        "whippen": Encoder(counter="Dev3/ctr1", body="whippen", kind="angular",
                           counts_per_rev=327680),
        "hammer": Encoder(counter="Dev3/ctr2", body="hammer", kind="angular",
                          counts_per_rev=163840),
    }


class Channels(_Strict):
    """Physical channels of the three cards."""

    drive_output: DriveOutput = DriveOutput()
    pacing: Pacing = Pacing()
    ai_sample_clock: str = Field("/Dev2/ai/SampleClock",
                                 description="clock source for the encoder counters")
    load_cell: LoadCell = LoadCell()
    strain_gauge: StrainGauge = StrainGauge()
    encoders: dict[str, Encoder] = Field(default_factory=_default_encoders)

    @field_validator("encoders")
    @classmethod
    def _three(cls, v: dict[str, Encoder]) -> dict[str, Encoder]:
        if not v:
            raise InputError("expected at least one encoder")
        for key, enc in v.items():
            if not _NAME.fullmatch(key):
                raise InputError(f"{key!r}: expected an encoder name of letters, digits and _")
            if not _NAME.fullmatch(enc.channel_name):
                raise InputError(f"channel {enc.channel_name!r} of encoder {key}: expected a "
                                 f"name of letters, digits and _")
            for own in (enc.channel_name, f"{key}_counts"):
                if own in RESERVED_CHANNELS:
                    raise InputError(f"encoder {key} would write channel {own!r}, one of the "
                                     f"run's own channels (reserved: "
                                     f"{', '.join(sorted(RESERVED_CHANNELS))})")
        names = [e.channel_name for e in v.values()] + [f"{k}_counts" for k in v]
        if len(set(names)) != len(names):
            raise InputError(f"two encoders write the same channel: {names}")
        return v


class DriveScaling(_Strict):
    """Force on the key -> torque -> current -> volts at the drive's analog input.

    volts = force_n * arm_length_m / torque_constant_nm_per_a * volts_per_amp.
    The torque constant and the drive's input scaling are not in the thesis:
    set them from the motor's and drive's plates.
    """

    arm_length_m: float = Field(0.100, gt=0, le=10)
    torque_constant_nm_per_a: float = Field(2.0, gt=0, le=1000)
    volts_per_amp: float = Field(10.0 / 6.0, gt=0, le=1000)

    @property
    def volts_per_newton(self) -> float:
        return self.arm_length_m / self.torque_constant_nm_per_a * self.volts_per_amp


class Limits(_Strict):
    """Safety limits applied to every demand and checked on every profile."""

    max_force_n: float = Field(50.0, gt=0, le=120, description="pianists stay under 50 N")
    max_rate_n_per_s: float = Field(5000.0, gt=0, le=1e6)
    max_late_cycles_in_a_row: int = Field(5, ge=1, le=1_000_000)
    late_threshold_s: float = Field(0.001, gt=0, le=0.1,
                                    description="a cycle writing later than this "
                                                             "after its tick is late")
    max_profile_s: float = Field(60.0, gt=0, le=3600, description="longest profile a run or "
                                 "simulation accepts (s); longer ones are refused on load")


class DriveLink(_Strict):
    """Serial link to the Kollmorgen ServoStar CE drive; the command set is configurable."""

    port: str = Field("/dev/ttyS0", description="serial device; 'sim' = simulated drive on a pty")
    baudrate: int = Field(9600, gt=0, le=10_000_000)
    timeout_s: float = Field(0.5, gt=0, le=10)
    prompt: str = "-->"
    enable: str = "EN"
    disable: str = "DIS"
    status: str = "DRIVEOK"
    status_ok: str = "1"
    active: str = "ACTIVE"
    fault: str = "ERRCODE"
    no_fault: str = "0"
    setup: list[str] = Field(default_factory=list, description="sent once before enabling")
    poll_period_s: float = Field(0.05, gt=0, le=MAX_DRIVE_POLL_PERIOD_S,
                                 description="a slower poll would see a drive fault too late")
    link_failures: int = Field(3, ge=1, le=20,
                               description="status polls in a row whose link fails (no answer, "
                                           "a write timeout) before the run stops for a lost "
                                           "link; a fault the drive reports stops it at once")


class Rates(_Strict):
    control_hz: float = Field(500.0, ge=10, le=10_000)
    acquisition_hz: float = Field(2000.0, ge=10, le=250_000)

    @model_validator(mode="after")
    def _ratio(self) -> Rates:
        ratio = self.acquisition_hz / self.control_hz
        if abs(ratio - round(ratio)) > 1e-9 or ratio < 1:
            raise InputError("acquisition_hz: expected a whole multiple of control_hz")
        return self

    @property
    def samples_per_cycle(self) -> int:
        return int(round(self.acquisition_hz / self.control_hz))


class Loop(_Strict):
    advance_s: float = Field(0.008, ge=0, le=0.1, description="demand leads the profile by this "
                                                              "(open-loop lag compensation)")
    rest_s: float = Field(1.0, ge=0, le=3600, description="rest between trials")
    settle_s: float = Field(0.1, ge=0, le=60, description="zero demand recorded before each trial")
    controller: str = Field("open_loop", description="open_loop, or module:Class of a controller")
    realtime_priority: int = Field(10, ge=0, le=99, description="SCHED_FIFO priority of the "
                                   "loop's thread where the OS permits it (0 = normal class)")
    cpu: int | None = Field(None, ge=0, description="pin the loop's thread (only it) to this "
                            "CPU (Linux; checked against the machine when the run starts; "
                            "elsewhere ignored with a note); none = the OS chooses")


class Acquisition(_Strict):
    read_period_s: float = Field(0.02, gt=0, le=0.5)
    flush_period_s: float = Field(0.25, gt=0, le=0.5, description="at most 0.5 s: flushed at "
                                                                  "least twice a second")
    buffer_s: float = Field(2.0, ge=0.1, le=60,
                            description="card input buffer / simulated FIFO length")
    start_timeout_s: float = Field(60.0, gt=0, le=3600)


class Sim(_Strict):
    """The simulated rig (backend: sim)."""

    realtime: bool = True
    seed: int = 4
    noise_stream: int = Field(
        0, ge=0, le=2**31, description="which of the seed's noise streams the sensors draw "
        "(the true calibration is the seed's alone: the same rig); 0 for a run; `rig run "
        "--learn` plays trial K on stream K, so each trial's noise is fresh, as a real load "
        "cell's")
    effects: list[str] = Field(default_factory=lambda: ["flexible_shank"])
    friction: Literal["regularised", "stick"] = Field(
        "regularised", description="the simulated action's friction: regularised (the "
                                   "thesis's Eq. 3.6 and 3.8, as every other command's model) "
                                   "or stick (Dahl's law at every pin and contact with "
                                   "friction: the action sticks under a slow press as a real "
                                   "one does; docs/touch.md)")
    drive_model: Literal["single", "asymmetric", "step_size"] = Field(
        "single", description="Appendix D drive model (rig.sim_backend.drive_model): single, "
                              "asymmetric (rise/fall models) or step_size (slew-limited)")
    process_time_unit_s: float = Field(THESIS_TIME_UNIT_S, gt=0, le=1,
                                       description="unit of Tw and Tp3 (Appendix D)")
    load_cell_noise_n: float = Field(0.22, ge=0, le=100,
                                     description="1 sigma; 3 sigma = the 0.67 N spec")
    load_cell_filter_hz: float | None = Field(
        None, gt=0, le=1e5, description="a 4-pole filter in the simulated load cell; none: the "
                                        "100 Hz filter is counted in the drive model, as the "
                                        "thesis identified it")
    strain_noise: float = Field(2e-6, ge=0, le=1, description="1 sigma, m/m")
    sensor_spread: float = Field(0.02, ge=0, le=0.5,
                                 description="relative 1-sigma spread of the true "
                                                         "sensitivities around nominal")
    drive_fault_at_s: float | None = Field(
        None, gt=0, le=86400,
        description="fault drill: the simulated drive faults (and drops its output) this many "
                    "seconds of control periods into the run, to rehearse the safety chain; "
                    "none: never")
    drive_fault_code: int = Field(2, ge=1, le=99, description="the fault code of the drill "
                                                              "(2: over-current)")
    build_timeout_s: float = Field(600.0, gt=0, le=7200,
                                   description="wait for the plant process to build "
                                   "its model (the first use after installing or updating rig "
                                   "compiles it: about a minute)")


class RigConfig(_Strict):
    """A whole rig."""

    name: str = "rig"
    backend: Literal["ni", "sim"]
    channels: Channels = Channels()
    drive_scaling: DriveScaling = DriveScaling()
    limits: Limits = Limits()
    drive: DriveLink = DriveLink()
    rates: Rates = Rates()
    loop: Loop = Loop()
    acquisition: Acquisition = Acquisition()
    data_folder: Path = Field(Path("runs"), strict=False)
    sim: Sim = Sim()
    calibration: CalibrationSettings = CalibrationSettings()

    @model_validator(mode="before")
    @classmethod
    def _sim_drive_port(cls, data: Any) -> Any:
        """``backend: sim`` implies the simulated drive (``drive.port: sim``) unless the file
        names a port (a serial line to a real drive, or a pty in a test)."""
        if isinstance(data, dict) and data.get("backend") == "sim":
            drive = data.get("drive")
            if drive is None or (isinstance(drive, dict) and "port" not in drive):
                data = {**data, "drive": {**(drive or {}), "port": "sim"}}
        return data

    @property
    def simulated(self) -> bool:
        """Whether this is the simulated rig (``backend: sim``): nobody at the rig to
        prompt, no hardware calibration required, the simulation's seed in the identity
        its records carry. The backend itself is chosen in ``rig.loop.backends`` alone."""
        return self.backend == "sim"

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.model_dump(mode="json"), sort_keys=False)


def _one_line(source: str, exc: ValidationError) -> InputError:
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"]) or "(top level)"
    msg = err["msg"].removeprefix("Value error, ")
    if err["type"] == "extra_forbidden":
        msg = "unknown field"
    head, sep, rest = msg.partition(": ")
    if sep and head.isidentifier():  # a model validator naming its field
        where, msg = f"{where}.{head}" if err["loc"] else head, rest
    extra = f" (and {len(exc.errors()) - 1} more)" if len(exc.errors()) > 1 else ""
    return InputError(one_line(f"{source}: {where}: {msg}{extra}"))


def one_line(text: str) -> str:
    """``text`` on one line (a value quoted from the user's file may hold line breaks)."""
    return " ".join(text.split("\n")).replace("\r", " ")


def from_mapping(data: Any, source: str = "rig config") -> RigConfig:
    """Validate a mapping as a rig configuration (one-line ValueError naming the field)."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: expected a mapping of rig settings, got "
                         f"{type(data).__name__}")
    try:
        return RigConfig.model_validate(data)
    except ValidationError as exc:
        raise _one_line(source, exc) from None


def load(path: str | Path) -> RigConfig:
    """Load and validate a rig YAML file."""
    return from_mapping(load_yaml_file(path, MAX_CONFIG_BYTES), str(path))


def builtin_sim(**overrides: Any) -> RigConfig:
    """The built-in simulated rig (used when there is no --rig and no ./rig.yaml)."""
    data: dict[str, Any] = {"name": "built-in simulated rig", "backend": "sim",
                            "drive": {"port": "sim"}}
    data.update(overrides)
    return from_mapping(data, "built-in simulated rig")


def resolve(rig_file: Path | None, cwd: Path | None = None) -> tuple[RigConfig, str]:
    """The rig to use and a sentence saying which: --rig FILE, ./rig.yaml, else built-in sim."""
    if rig_file is not None:
        cfg = load(rig_file)
        return cfg, f"rig config: {rig_file} ({cfg.backend} backend)"
    local = (cwd or Path.cwd()) / "rig.yaml"
    if local.is_file():
        cfg = load(local)
        return cfg, f"rig config: ./rig.yaml ({cfg.backend} backend)"
    return builtin_sim(), "rig config: built-in simulated rig (no --rig and no ./rig.yaml)"
