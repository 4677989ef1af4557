"""The Python API (rig.load, rig.simulate, rig.diagnose) and the CLI's refusal to replace a
user's file without --force (issue 15)."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import rig
from rig.cli import app
from rig.recordings import runfile

ROOT = Path(__file__).resolve().parents[1]
FORTE = ROOT / "profiles" / "forte.yaml"
runner = CliRunner()


@pytest.mark.slow
def test_load_gives_trials_as_xarray_dataframe_and_plot(tmp_path, forte_rigid) -> None:
    path = runfile.write_result(tmp_path / "sim.h5", forte_rigid)
    run = rig.load(path)
    assert run.kind == "simulated" and len(run.trials) == 1
    tr = run.trials[0]
    ds = tr.to_xarray()
    assert ds["force"].dims == ("time",) and ds["contact_force"].dims == ("time", "contact")
    assert np.array_equal(ds["time"].values, forte_rigid.time)
    assert ds["hammer_angle"].attrs["units"] == "rad" and ds["hammer_angle"].attrs["long_name"]
    assert ds.attrs["event_strike"] == pytest.approx(forte_rigid.events["strike"])
    df = tr.to_dataframe()
    assert df.index.name == "time" and df.shape[0] == forte_rigid.time.size
    assert np.array_equal(df["contact_force[12]"].to_numpy(), forte_rigid.contact(
        "contact_force", 12))
    fig = tr.plot(["hammer_angle", "key_dip"], window=(0.0, 0.1))
    names = {trace.name for trace in fig.data}
    assert {"hammer_angle", "key_dip"} <= names
    x = np.concatenate([np.asarray(t.x, float) for t in fig.data if t.name == "key_dip"])
    assert x.min() >= 0.0 and x.max() <= 100.0  # ms, inside the window
    with pytest.raises(ValueError, match="window"):
        tr.plot(window=(5.0, 6.0))


def test_simulate_returns_a_trial_and_refuses_to_replace_a_file(tmp_path) -> None:
    blow = rig.simulate(FORTE, duration=0.03)
    assert blow.attrs["status"] == "complete" and blow.result is not None
    assert blow.to_xarray().sizes["time"] == blow.time.size
    assert set(blow.summary()) >= {"strike_s", "strike_speed_m_s"}
    out = tmp_path / "kept.h5"
    out.write_bytes(b"a user's file")
    with pytest.raises(ValueError, match="kept.h5 exists"):
        rig.simulate(FORTE, duration=0.03, out=out)
    assert out.read_bytes() == b"a user's file"
    written = rig.simulate(FORTE, duration=0.03, out=out, force=True)
    assert np.array_equal(rig.load(out).trials[0].channels["force"],
                          written.channels["force"])


def test_import_rig_stays_light() -> None:
    code = ("import sys, rig; heavy = [m for m in ('xarray', 'pandas', 'plotly', 'numba', "
            "'rig.api') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"


def _digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.mark.parametrize(("args", "field"), [
    (["simulate", str(FORTE), "--out", "{f}"], "out"),
    (["synth", "-m", "{m}", "--profile", str(FORTE), "--out", "{f}"], "out"),
    (["compare", "{r}", "--report", "{f}"], "report"),
    (["diagnose", "{r}", "--report", "{f}"], "report"),
    (["diagnose", "{r}", "--write", "{f}"], "write"),
    (["fit", "{r}", "--param", "contacts.12.K", "--write", "{f}"], "write"),
])
def test_cli_never_replaces_a_users_file_without_force(tmp_path, args, field) -> None:
    kept = tmp_path / "precious.h5"
    kept.write_bytes(np.random.default_rng(0).bytes(4096))
    before = _digest(kept)
    model = tmp_path / "m.yaml"
    model.write_text("effects: []\n")
    argv = [a.format(f=kept, m=model, r=tmp_path / "run.h5") for a in args]
    res = runner.invoke(app, argv)
    assert res.exit_code == 2, res.output
    assert f"{field}: {kept} exists (use --force" in res.output
    assert _digest(kept) == before


def _schemas() -> dict[str, dict]:
    import json
    import re

    text = (ROOT / "docs" / "json.md").read_text()
    out = {}
    for body in re.findall(r"^```json\n(.*?)^```", text, re.S | re.M):
        schema = json.loads(body)
        out[schema["$id"]] = schema
    return out


def _validated(output: str, schema_id: str) -> dict:
    import json

    jsonschema = pytest.importorskip("jsonschema")
    doc = json.loads(output)
    assert doc["schema"] == schema_id
    jsonschema.validate(doc, _schemas()[schema_id])
    return doc


def test_json_schemas_in_the_docs_are_valid_schemas() -> None:
    jsonschema = pytest.importorskip("jsonschema")
    schemas = _schemas()
    assert set(schemas) == {"rig.info/1", "rig.simulate/1", "rig.effects/1", "rig.fit/1",
                            "rig.compare/1", "rig.diagnose/1", "rig.import/1",
                            "rig.touch/1", "rig.measure-touch/1"}
    for s in schemas.values():
        jsonschema.Draft202012Validator.check_schema(s)
    with pytest.raises(jsonschema.ValidationError):  # the schemas do reject a wrong document
        jsonschema.validate({"schema": "rig.info/1", "kind": "bogus"}, schemas["rig.info/1"])


def test_info_and_simulate_json_validate_and_match_the_file(tmp_path) -> None:
    out = tmp_path / "sim.h5"
    res = subprocess.run([str(Path(sys.executable).with_name("rig")), "simulate", str(FORTE),
                          "--duration", "0.1", "--out", str(out), "--json"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    sim = _validated(res.stdout, "rig.simulate/1")  # stdout is the JSON and nothing else
    assert sim["out"] == str(out) and sim["success"] is True
    run = rig.load(out)
    assert sim["events"]["strike"] == pytest.approx(run.trials[0].events["strike"])
    r = runner.invoke(app, ["info", str(out), "--json"])
    assert r.exit_code == 0
    info = _validated(r.stdout, "rig.info/1")
    tr = info["trials"][0]
    assert info["kind"] == "simulated" and tr["samples"] == run.trials[0].time.size
    times = [e["time_s"] for e in tr["events"] if e["time_s"] is not None]
    assert times == sorted(times) and len(times) >= 3
    assert all(e["source"] is None for e in tr["events"])  # the simulation's own events
    force = next(c for c in tr["channels"] if c["name"] == "force")
    assert force["max"] == pytest.approx(float(run.trials[0].channels["force"].max()))
    cf = next(c for c in tr["channels"] if c["name"] == "contact_force")
    assert cf["columns"] == list(range(1, 15))


def test_effects_json_lists_the_library() -> None:
    from rig.model.effects import BUILTIN

    r = runner.invoke(app, ["effects", "--json"])
    assert r.exit_code == 0
    doc = _validated(r.stdout, "rig.effects/1")
    assert [e["name"] for e in doc["effects"]] == list(BUILTIN)


def test_fit_json_validates(tmp_path) -> None:
    from rig.analysis import synth
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    data = tmp_path / "d.h5"
    synth.synth(ActionModel(), [profiles.load(FORTE)], data, seed=3, duration=0.04)
    r = runner.invoke(app, ["fit", str(data), "--param", "contacts.4.D=0.5:10", "--jobs", "1",
                            "--max-nfev", "3", "--json"])
    assert r.exit_code == 0, r.output
    doc = _validated(r.stdout, "rig.fit/1")
    assert [p["name"] for p in doc["parameters"]] == ["contacts.4.D"]
    assert doc["cost"] <= doc["cost_start"] and doc["write"] is None


def test_an_internal_error_is_exit_1_with_the_traceback_under_v(tmp_path, monkeypatch) -> None:
    """A library's ValueError inside rig is not the user's bad input: exit 1, one line that
    names its type; ``rig -v`` adds the traceback. Bad input stays one line, exit 2."""
    from rig.services import simulate as svc

    def broken(*a, **k):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(svc, "simulate", broken)
    out = tmp_path / "o.h5"
    r = runner.invoke(app, ["simulate", str(FORTE), "--out", str(out), "--duration", "0.01"])
    assert r.exit_code == 1
    lines = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith("rig: ")]
    assert lines == ["error: LinAlgError: Singular matrix (`rig -v ...` shows the traceback)"]
    r = runner.invoke(app, ["-v", "simulate", str(FORTE), "--out", str(out)])
    assert r.exit_code == 1 and "Traceback" in r.stderr and "in broken" in r.stderr
    monkeypatch.undo()
    r = runner.invoke(app, ["simulate", str(tmp_path / "none.yaml"), "--out", str(out)])
    assert r.exit_code == 2 and "Traceback" not in r.stderr and not out.exists()


def _piped(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(Path(sys.executable).with_name("rig")), *args],
                          capture_output=True, text=True, timeout=900)


@pytest.mark.slow
def test_progress_off_a_terminal_is_plain_lines_on_stderr_and_q_silences_it(tmp_path) -> None:
    blow = tmp_path / "b.h5"
    rig.simulate(FORTE, duration=0.03, out=blow)
    args = ["diagnose", str(blow), "--candidate", "compliant_string", "--jobs", "1",
            "--duration", "0.02"]
    res = _piped(args)
    assert res.returncode == 0, res.stderr
    progress = [ln for ln in res.stderr.splitlines() if ln.startswith("rig: ")]
    assert progress and progress[0].startswith("rig: fitting candidate effects")
    assert "\x1b[" not in res.stderr  # no terminal control codes in a log
    assert "rig: " not in res.stdout and "diagnosed in" in res.stdout
    quiet = _piped(["-q", *args])
    assert quiet.returncode == 0 and "rig: " not in quiet.stderr
    assert quiet.stdout.splitlines()[0] == res.stdout.splitlines()[0]


@pytest.mark.parametrize(("words", "cword", "expected"), [
    ("rig sim", 1, ["simulate"]),
    ("rig diagnose --cand", 2, ["--candidate"]),
    ("rig simulate -e compl", 3, ["compliant_string"]),
])
def test_shell_completion_of_commands_options_and_effect_names(words, cword, expected) -> None:
    env = {**os.environ, "_RIG_COMPLETE": "complete_bash", "COMP_WORDS": words,
           "COMP_CWORD": str(cword)}
    res = subprocess.run([str(Path(sys.executable).with_name("rig"))], env=env,
                         capture_output=True, text=True, timeout=120)
    assert res.stdout.split() == expected, res.stderr


@pytest.mark.slow
def test_compare_and_diagnose_json_validate_and_say_what_the_text_says(tmp_path) -> None:
    from rig.analysis import synth
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    truth = ActionModel(effects=[{"compliant_string": {"stiffness": 3.0e4}}])
    data = tmp_path / "d.h5"
    synth.synth(truth, [profiles.load(FORTE), profiles.load(FORTE)], data, seed=4,
                duration=0.1)
    r = runner.invoke(app, ["compare", str(data), "--trial", "0", "--trial", "1", "--json"])
    assert r.exit_code == 0, r.output
    doc = _validated(r.stdout, "rig.compare/1")
    assert len(doc["trials"]) == 2 and doc["trials"][1]["trial"].endswith("#1")
    base = doc["trials"][0]["models"][0]
    assert base["ok"] and base["errors"]["hammer_angle"]["units"] == "rad"
    r = runner.invoke(app, ["diagnose", str(data), "--candidate", "compliant_string",
                            "--candidate", "felt_hysteresis", "--jobs", "1",
                            "--duration", "0.1", "--json"])
    assert r.exit_code == 0, r.output
    d = _validated(r.stdout, "rig.diagnose/1")["diagnosis"]
    assert d["chosen"] == ["compliant_string"] and d["final"]["significant"]
    k = d["final"]["values"]["compliant_string.stiffness"]
    s = d["final"]["sigma"]["compliant_string.stiffness"]
    assert abs(k - 3.0e4) < 4 * s and d["final"]["units"]["compliant_string.stiffness"] == "N/m"
    assert {c["name"] for c in d["candidates"]} == {"compliant_string", "felt_hysteresis"}
    assert d["verdict"].startswith("missing effect: compliant_string")
    # the blow's events found in both trials, timed under the base model and the string
    t = d["timing"]
    assert t["labels"] == ["base model", "compliant_string"] and t["tolerance"] == 1e-3
    assert {r["event"] for r in t["rows"]} >= {"strike", "key_bottom"}
    assert all(r["low"] <= r["measured"] <= r["high"] and r["spread"]["compliant_string"] >= 0
               for r in t["rows"])
