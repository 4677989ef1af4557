"""Model YAML files read and written in one place (rig.model.modelfile)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
import yaml

from rig.errors import InputError
from rig.model import modelfile
from rig.model.action import ActionModel

EFFECT = '''
from rig.model.effects import Effect, EffectParameter, Signature

class SofterStringFelt(Effect):
    name = "softer_string_felt"
    summary = "hammer felt softer than the thesis's fit"
    parameters = (EffectParameter("scale", "1", 0.5, (0.01, 10.0), True, "felt scale"),)
    signature = Signature(("hammer_angle",), ("string contact",), "shape", None, "softer")

    def apply(self, build):
        for coef in ("a", "b", "c"):
            path = f"contacts.12.{coef}"
            build.params.set(path, build.params.get(path) * self.values["scale"])
'''


def _model_in(folder: Path) -> Path:
    folder.mkdir(parents=True)
    (folder / "felt.py").write_text(textwrap.dedent(EFFECT))
    (folder / "p.yaml").write_text("contacts: {4: {D: 3.0}}\n")
    path = folder / "m.yaml"
    path.write_text(yaml.safe_dump({"parameters": "p.yaml",
                                    "effects": [{"felt.py:SofterStringFelt": {"scale": 0.3}},
                                                "load_cell_filter"]}))
    return path


def test_a_model_written_elsewhere_names_its_files_from_its_new_folder(tmp_path) -> None:
    src = _model_in(tmp_path / "a" / "b")
    data, base = modelfile.read(src)
    out = tmp_path / "elsewhere" / "deeper" / "m2.yaml"
    written = modelfile.write(modelfile.rebased(data, base, out.parent), out)
    again = yaml.safe_load(written.read_text())
    assert again["parameters"] == "../../a/b/p.yaml"
    assert again["effects"] == [{"../../a/b/felt.py:SofterStringFelt": {"scale": 0.3}},
                                "load_cell_filter"]
    m1, m2 = ActionModel.from_yaml(src), ActionModel.from_yaml(written)
    assert m2.effect_names == m1.effect_names == ["softer_string_felt", "load_cell_filter"]
    assert m2.build.params.get("contacts.4.D") == 3.0
    assert m2.build.params.get("contacts.12.a") == m1.build.params.get("contacts.12.a")


@pytest.mark.parametrize("text, field", [
    ("- a list\n", "expected a mapping"),
    ("efects: [load_cell_filter]\n", "efects: unknown key"),
    ("effects: load_cell_filter\n", "effects: expected a list"),
])
def test_a_bad_model_file_is_refused_naming_the_file_and_field(tmp_path, text, field) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=f"bad.yaml: {field}"):
        modelfile.read(path)


@pytest.mark.parametrize("text, field", [
    ("effects: [nosuch]\n", "effects: effect 'nosuch': not in the library"),
    ("parameters: {nosuch_param: 1}\n", "parameters: parameter 'nosuch_param'"),
    ("parameters: missing.yaml\n", "parameters: .*missing.yaml: file not found"),
    ("parameters: sub\n", "parameters: .*sub: is a folder, expected a file"),
    ("integrator: {name: bogus}\n", "integrator: expected rosenbrock"),
])
def test_errors_inside_a_model_file_name_the_file(tmp_path, text, field) -> None:
    (tmp_path / "sub").mkdir()
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=f"^{path}: {field}") as exc:
        ActionModel.from_yaml(path)
    assert "\n" not in str(exc.value)
    with pytest.raises(InputError, match=f"^{tmp_path}: is a folder, expected a file"):
        ActionModel.from_yaml(tmp_path)
