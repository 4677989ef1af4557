"""Parameter overrides on one parsed tree, ``default`` restorable (issue 16)."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig.inputs import params as params_mod
from rig.inputs.params import Parameters
from rig.model.effects import make
from rig.services import simulate as svc

THESIS_D4 = 2.446  # contacts.4.D, the back check's damping, thesis Table A.4


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def test_default_restores_the_thesis_value_and_set_chains():
    p = Parameters.default()
    assert p.set("contacts.4.D", 3.0).set("bodies.key.mass", 0.13) is p
    assert p.get("contacts.4.D") == 3.0
    p.set("contacts.4.D", "default")
    assert p.get("contacts.4.D") == THESIS_D4
    assert p.get("bodies.key.mass") == 0.13  # only the named one went back
    com = Parameters.default().get("bodies.key.com")
    p.set("bodies.key.com", [0.1, 0.2]).set("bodies.key.com", "default")
    assert p.get("bodies.key.com") == com
    assert p.update({"bodies": {"key": {"mass": "default"}}}) is p
    assert p.get("bodies.key.mass") == Parameters.default().get("bodies.key.mass")


def test_instances_do_not_share_the_parsed_tree():
    a, b = Parameters.default(), Parameters.default()
    a.set("contacts.4.D", 9.0)
    assert b.get("contacts.4.D") == THESIS_D4
    assert Parameters.default().get("contacts.4.D") == THESIS_D4


def test_params_file_over_model_file_changes_only_what_it_names(tmp_path):
    model = write(tmp_path, "model.yaml",
                  "parameters: {contacts: {4: {D: 3.0, A: 0.5}}, bodies: {key: {mass: 0.2}}}\n")
    # D back to the thesis value, the key mass set to the thesis value explicitly (the
    # old code skipped values equal to the default, leaving the model file's 0.2)
    thesis_mass = Parameters.default().get("bodies.key.mass")
    over = write(tmp_path, "p.yaml",
                 f"contacts: {{4: {{D: default}}}}\nbodies: {{key: {{mass: {thesis_mass}}}}}\n")
    m = svc.build_model(model, params_file=over)
    assert m.params.get("contacts.4.D") == THESIS_D4
    assert m.params.get("contacts.4.A") == 0.5  # from the model file, untouched
    assert m.params.get("bodies.key.mass") == thesis_mass


def test_a_params_file_is_parsed_once_not_per_parameter(tmp_path, monkeypatch):
    over = write(tmp_path, "p.yaml", "contacts: {4: {D: 3.0}}\n")
    calls: list[str] = []
    real = params_mod._load_yaml_text

    def counting(text: str, source: str):
        calls.append(source)
        return real(text, source)

    monkeypatch.setattr(params_mod, "_load_yaml_text", counting)
    params_mod._parsed_defaults.cache_clear()
    m = svc.build_model(None, params_file=over)
    assert m.params.get("contacts.4.D") == 3.0
    # the package's two files once, the user's file once: never once per parameter
    assert sorted(calls) == sorted(["thesis params", "chosen", str(over)])


def test_bad_values_in_a_params_file_name_the_file_and_field(tmp_path):
    over = write(tmp_path, "p.yaml", "contacts: {4: {D: defualt}}\n")
    with pytest.raises(ValueError) as err:
        svc.build_model(None, params_file=over)
    assert str(over) in str(err.value) and "contacts.4.D" in str(err.value)


def test_effect_values_take_default():
    e = make({"backcheck_law": {"stiffness_scale": 3.0}})
    assert e.values["stiffness_scale"] == 3.0
    e = make({"backcheck_law": {"stiffness_scale": "default"}})
    spec = next(p for p in e.parameters if p.name == "stiffness_scale")
    assert e.values["stiffness_scale"] == spec.default


def test_default_in_a_model_yaml_effect(tmp_path):
    model = write(tmp_path, "model.yaml",
                  "effects: [{key_liftoff: {stiffness_scale: default}}]\n")
    m = svc.build_model(model)
    e = m.effects[0]
    spec = next(p for p in e.parameters if p.name == "stiffness_scale")
    assert e.values["stiffness_scale"] == spec.default
