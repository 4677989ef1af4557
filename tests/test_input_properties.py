"""Property-based tests (hypothesis) of the rig-config and profile loaders (issue 11).

For generated inputs -- numbers of every kind (negative, zero, huge, inf, nan, bools, text),
missing and extra fields, YAML and CSV profiles -- every input is either refused with one
line (a ValueError, no line break, naming the file) or accepted and then safe: zero demand
gives exactly 0 V through the real motor_torque path, the rates, timeouts and buffers are
finite and bounded, the profile's schedule is finite and within the maximum duration.

A fixed example budget, derandomized: the same examples run in CI every time (< 30 s).
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

from rig import motor_torque
from rig.inputs import config, profiles
from rig.inputs.config import RigConfig

BUDGET = settings(max_examples=250, derandomize=True, deadline=None,
                  suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def folder() -> Iterator[Path]:
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


def _numeric_paths(model: type[BaseModel], prefix: tuple[str, ...] = ()
                   ) -> list[tuple[str, ...]]:
    """Dotted paths of every scalar field of the config (numbers, flags and text alike)."""
    out: list[tuple[str, ...]] = []
    for name, info in model.model_fields.items():
        ann = info.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            out += _numeric_paths(ann, (*prefix, name))
        else:
            out.append((*prefix, name))
    return out


def _annotation(path: tuple[str, ...]) -> Any:
    model: Any = RigConfig
    for name in path[:-1]:
        model = model.model_fields[name].annotation
    return model.model_fields[path[-1]].annotation


PATHS = _numeric_paths(RigConfig)
NUMBER_PATHS = [p for p in PATHS if _annotation(p) in (float, int, float | None, int | None)]
NUMBERS = st.one_of(
    st.floats(0.001, 1), st.floats(0.001, 1), st.integers(1, 100),  # plausible
    st.integers(-3, 3), st.integers(-10**30, 10**30), st.just(10**400),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, 0.05, 0.1, 0.1000001, 2.0, 10.0, 500.0]),
    st.booleans(), st.text(max_size=4), st.none(), st.lists(st.integers(0, 3), max_size=2))


def _set(tree: dict[str, Any], path: tuple[str, ...], value: Any) -> None:
    for key in path[:-1]:
        node = tree.setdefault(key, {})
        if not isinstance(node, dict):
            return
        tree = node
    tree[path[-1]] = value


@st.composite
def rig_mappings(draw: st.DrawFn) -> Any:
    data: dict[str, Any] = {"backend": draw(st.sampled_from(["sim"] * 4 + ["ni"] * 2 +
                                                            ["labview", 1]))}
    if draw(st.integers(0, 9)) == 0:
        del data["backend"]  # a missing required field
    paths = st.one_of(st.sampled_from(NUMBER_PATHS), st.sampled_from(NUMBER_PATHS),
                      st.sampled_from(PATHS))  # mostly the numbers, any field now and then
    for path, value in draw(st.lists(st.tuples(paths, NUMBERS), max_size=3)):
        _set(data, path, value)
    if draw(st.integers(0, 9)) == 0:  # an extra field somewhere
        _set(data, draw(st.sampled_from(PATHS))[:-1] + ("extra_field",), 1)
    if draw(st.integers(0, 5)) == 0:  # an encoder, with a channel name from anywhere
        data.setdefault("channels", {})["encoders"] = {draw(st.sampled_from(
            ["key", "k", "time", "force", "sample", "demand"])): {
            "counter": "c0", "body": "key", "kind": "linear", "metres_per_count": 1e-6,
            "channel": draw(st.sampled_from(["", "force", "sample", "time", "demand", "volts",
                                             "key_dip", "a/b", "x\ny"]))}}
    return data


def _refused_in_one_line(exc: BaseException, path: Path) -> None:
    assert isinstance(exc, ValueError), f"{type(exc).__name__}: {exc}"
    msg = str(exc)
    assert "\n" not in msg and "\r" not in msg, msg
    assert str(path) in msg, msg


def _finite_tree(value: Any, where: str = "") -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _finite_tree(v, f"{where}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _finite_tree(v, f"{where}[{i}]")
    elif isinstance(value, float):
        assert math.isfinite(value), where


def _assert_safe(cfg: RigConfig) -> None:
    # zero demand -> exactly 0 V through the path the loop uses (limiter, then scaling)
    dt = 1.0 / cfg.rates.control_hz
    limiter = motor_torque.Limiter(cfg.limits, dt)
    scaling = motor_torque.TorqueScaling.from_config(cfg.drive_scaling, cfg.channels.drive_output)
    demand, _ = limiter(0.0)
    assert scaling.volts(demand) == 0.0
    assert -10.0 <= scaling.volts(cfg.limits.max_force_n) <= 10.0
    _finite_tree(cfg.model_dump(mode="json"))
    for flag in (cfg.rates.control_hz, cfg.rates.acquisition_hz):
        assert not isinstance(flag, bool) and 10 <= flag <= 250_000
    assert 0 < cfg.drive.poll_period_s <= 0.1
    assert 0 < cfg.drive.timeout_s <= 10 and 0 < cfg.acquisition.start_timeout_s <= 3600
    # the integer schedules the run derives stay small
    assert int(round(cfg.loop.rest_s * cfg.rates.control_hz)) <= 3600 * 10_000
    assert int(round(cfg.acquisition.buffer_s * cfg.rates.acquisition_hz)) <= 60 * 250_000
    names = [e.channel_name for e in cfg.channels.encoders.values()]
    assert not set(names) & config.RESERVED_CHANNELS


@BUDGET
@given(data=rig_mappings())
@pytest.mark.slow
def test_every_rig_config_is_refused_in_one_line_or_safe(folder: Path, data: Any) -> None:
    path = folder / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    try:
        cfg = config.load(path)
    except Exception as exc:  # noqa: BLE001 - the property: only a one-line ValueError
        _refused_in_one_line(exc, path)
        event("refused")
        return
    event("accepted")
    _assert_safe(cfg)


# ---- profiles ----
ODD_NUMBERS = st.one_of(st.floats(-1, 100), st.floats(allow_nan=True, allow_infinity=True),
                        st.integers(-5, 10**7), st.just(10**400), st.booleans(),
                        st.text(max_size=3), st.sampled_from([1.0e6, 59.9, 60.0, 60.1, 0.0]))
# mostly plausible durations and forces (so that many profiles are accepted and checked),
# the odd number about every eighth draw
SEG_NUMBERS = st.one_of(*[st.floats(0.001, 20), st.floats(0, 30), st.integers(1, 30)] * 3,
                        ODD_NUMBERS)


@st.composite
def yaml_profiles(draw: st.DrawFn) -> Any:
    form = draw(st.sampled_from(["segments", "segments", "points", "points", "both", "other"]))
    data: dict[str, Any] = {}
    if form in ("segments", "both"):
        segs = []
        for _ in range(draw(st.integers(0, 5))):
            kind = draw(st.sampled_from(["hold", "ramp"] * 4 + ["start", "bad"]))
            if kind == "hold":
                segs.append({"hold": draw(SEG_NUMBERS)})
            elif kind == "ramp":
                segs.append({"ramp": draw(SEG_NUMBERS), "to": draw(SEG_NUMBERS)})
            elif kind == "start":
                segs.append({"start": draw(SEG_NUMBERS)})
            else:
                segs.append({"hold": 0.1, "to": 3})
        data["segments"] = segs
    if form in ("points", "both"):
        if draw(st.booleans()):  # time increasing by construction
            steps = draw(st.lists(st.tuples(st.floats(0.001, 20), SEG_NUMBERS), max_size=6))
            t, pts = 0.0, [[0, 0]]
            for dt, f in steps:
                t += dt
                pts.append([t, f])
            data["points"] = pts
        else:
            data["points"] = draw(st.lists(st.lists(SEG_NUMBERS, min_size=1, max_size=3),
                                           max_size=6))
    if form == "other":
        data[draw(st.sampled_from(["speed", "name", "csv"]))] = draw(SEG_NUMBERS)
    if draw(st.booleans()):
        data["name"] = draw(st.one_of(st.text(max_size=5), ODD_NUMBERS))
    return data


CELLS = st.one_of(st.sampled_from(["0", "0.01", "1e6", "60.5", "-1", "nan", "inf", "30", "",
                                   "abc", "1e400", "time_s", "force_N", "Force_n", "t"]),
                  st.floats(0, 100).map(repr))


@st.composite
def csv_profiles(draw: st.DrawFn) -> str:
    lines = []
    header = draw(st.sampled_from([None, "time_s,force_N", "force_N,time_s"] * 3 + [
        "t,f", " Time_S , force_n", "time_s,time_s", "time_s,force_N,x"]))
    if header:
        lines.append(header)
    t = 0.0
    for _ in range(draw(st.integers(0, 6))):
        if draw(st.integers(0, 7)) == 0:
            lines.append(",".join(draw(st.lists(CELLS, min_size=1, max_size=3))))
        else:
            t += draw(st.floats(0.001, 12))
            f = draw(st.floats(0, 130))
            lines.append(f"{f!r},{t!r}" if header and header.startswith("force") else
                         f"{t!r},{f!r}")
    return "\n".join(lines) + "\n"


MAX_S = 60.0


def _assert_profile_safe(p: profiles.Profile, limit: float) -> None:
    assert p.time.size >= 2 and np.all(np.isfinite(p.time)) and np.all(np.isfinite(p.force))
    assert p.time[0] >= 0 and np.all(np.diff(p.time) > 0)
    assert 0 < p.duration <= MAX_S
    assert p.force.min() >= 0 and p.peak <= limit


@BUDGET
@given(data=yaml_profiles(), limit=st.sampled_from([35.0, 120.0]))
def test_every_yaml_profile_is_refused_in_one_line_or_finite(folder: Path, data: Any,
                                                             limit: float) -> None:
    path = folder / "p.yaml"
    path.write_text(yaml.safe_dump(data))
    try:
        p = profiles.load(path, force_limit=limit, max_duration=MAX_S)
    except Exception as exc:  # noqa: BLE001
        _refused_in_one_line(exc, path)
        event("refused")
        return
    event("accepted")
    _assert_profile_safe(p, limit)


@BUDGET
@given(text=csv_profiles())
def test_every_csv_profile_is_refused_in_one_line_or_finite(folder: Path, text: str) -> None:
    path = folder / "p.csv"
    path.write_text(text)
    try:
        p = profiles.load(path, max_duration=MAX_S)
    except Exception as exc:  # noqa: BLE001
        _refused_in_one_line(exc, path)
        event("refused")
        return
    event("accepted")
    _assert_profile_safe(p, profiles.DEFAULT_FORCE_LIMIT_N)
    # a header naming the columns is honoured: force_N first means force is column 0
    first = text.splitlines()[0].replace(" ", "").lower()
    if first == "force_n,time_s":
        rows = [r.split(",") for r in text.splitlines()[1:] if r.strip()]
        assert p.time[0] == float(rows[0][1]) and p.force[0] == float(rows[0][0])
