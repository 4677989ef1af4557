"""User physics through diagnose and fit (issue 13, item 1): docs/effects.md's examples run
as shown; a user effect with its own coordinate is a candidate under the default
(compiled) base model; ``--write`` names it so the file loads; ``rig fit --write`` keeps
every fitted value of an effect named by path."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from rig.analysis import synth
from rig.cli import app
from rig.inputs import profiles
from rig.model.action import ActionModel
from rig.services import diagnose as svc_diagnose
from rig.services import fit as svc_fit

ROOT = Path(__file__).parents[1]
DOC = ROOT / "docs" / "effects.md"
FORTE = ROOT / "profiles" / "forte.yaml"


def doc_blocks(lang: str) -> list[str]:
    """The fenced blocks of docs/effects.md in this language ("" for plain ones)."""
    out, cur, fence = [], [], None
    for line in DOC.read_text().splitlines():
        if line.startswith("```"):
            if fence is None:
                fence, cur = line[3:].strip(), []
            else:
                if fence == lang:
                    out.append("\n".join(cur) + "\n")
                fence = None
        elif fence is not None:
            cur.append(line)
    return out


@pytest.fixture
def my_effects(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """docs/effects.md's effect classes, as shown, in my_effects.py in the working dir."""
    py = doc_blocks("python")
    classes = [b for b in py if "class " in b]
    assert len(classes) == 2, "docs/effects.md: expected SofterStringFelt and HammerMaxwell"
    (tmp_path / "my_effects.py").write_text("\n\n".join(classes))
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    return tmp_path / "my_effects.py"


def test_docs_effects_examples_run_as_shown(my_effects: Path, tmp_path: Path) -> None:
    (model_yaml,) = [b for b in doc_blocks("yaml") if "effects:" in b]
    (tmp_path / "model.yaml").write_text(model_yaml)
    model = ActionModel.from_yaml(tmp_path / "model.yaml")
    assert model.effect_names == ["flexible_shank", "key_liftoff", "softer_string_felt"]
    assert model.effects[2].values["scale"] == 0.4
    assert model.effects[1].values["damping"] == 80
    # the Python example, as shown
    (use,) = [b for b in doc_blocks("python") if "ActionModel(effects=" in b]
    ns: dict = {}
    exec(compile(use, "docs/effects.md", "exec"), ns)  # noqa: S102
    assert ns["model"].effect_names == ["flexible_shank", "softer_string_felt"]
    # the command lines, as shown (the profile from the repository)
    (Path("profiles")).mkdir()
    (Path("profiles") / "forte.yaml").write_text(FORTE.read_text())
    runner = CliRunner()
    (cmds,) = [b for b in doc_blocks("") if "rig simulate" in b]
    for line in cmds.strip().splitlines():
        args = line.split()[1:] + ["--duration", "0.03"]
        r = runner.invoke(app, args)
        assert r.exit_code == 0, (line, r.output)
    assert Path("runs/soft.h5").is_file()
    # the Maxwell element integrates (Python forces: scipy-LSODA)
    hm = ActionModel(effects=["my_effects.py:HammerMaxwell"], base_dir=tmp_path)
    assert hm.integrator.name == "scipy-LSODA"
    res = hm.simulate(profiles.load(FORTE), 0.02)
    assert res.success and "hammer_maxwell_rest_angle" in res.channels


def test_fit_write_keeps_values_of_effects_named_by_path(my_effects: Path,
                                                         tmp_path: Path) -> None:
    truth = ActionModel(effects=["my_effects.py:SofterStringFelt"], base_dir=tmp_path)
    truth.effects[0].set("scale", 0.7)
    run = tmp_path / "run.h5"
    synth.synth(truth, [profiles.load(FORTE)], run, seed=1, duration=0.08,
                load_cell_filter=False)
    model = tmp_path / "soft.yaml"
    model.write_text("effects:\n  - my_effects.py:SofterStringFelt: {scale: 0.4}\n")
    sub = tmp_path / "out"
    res = svc_fit.fit([run], model, ["softer_string_felt.scale"], jobs=1, max_nfev=6,
                      write=sub / "fitted.yaml")
    v = res.values["softer_string_felt.scale"]
    assert abs(v - 0.7) < 0.15 and abs(v - 0.4) > 0.2  # fitted, not the starting 0.4
    written = yaml.safe_load((sub / "fitted.yaml").read_text())["effects"]
    assert written == [{"../my_effects.py:SofterStringFelt": {"scale": v}}]
    loaded = ActionModel.from_yaml(sub / "fitted.yaml")
    assert loaded.effects[0].values["scale"] == v


@pytest.mark.slow
def test_user_effect_with_own_coordinate_is_a_candidate_and_written_loadable(
        my_effects: Path, tmp_path: Path) -> None:
    truth = ActionModel(effects=[{"my_effects.py:HammerMaxwell": {"k": 2.0, "tau": 0.05}}],
                        base_dir=tmp_path)
    run = tmp_path / "run.h5"
    blows = [profiles.load(FORTE),
             profiles.from_points([[0, 0], [0.02, 0], [0.1, 24], [0.3, 24]], name="24 N")]
    synth.synth(truth, blows, run, seed=2, duration=0.06, load_cell_filter=False)
    out = tmp_path / "models" / "found.yaml"
    diag = svc_diagnose.diagnose(run, None, duration=0.06, candidates=[],
                                 extra=["my_effects.py:HammerMaxwell"], jobs=1, write=out)
    cand = diag.candidates[0]
    assert not cand.error, cand.describe()
    said = [n for n in diag.notes if "scipy-LSODA" in n]
    assert len(said) == 1 and "hammer_maxwell" in said[0]
    assert diag.best is not None and diag.best.name == "hammer_maxwell", \
        "\n".join(diag.report_lines())
    (entry,) = yaml.safe_load(out.read_text())["effects"]
    assert list(entry) == ["../my_effects.py:HammerMaxwell"]
    loaded = ActionModel.from_yaml(out)
    assert loaded.effect_names == ["hammer_maxwell"]
    assert loaded.integrator.name == "scipy-LSODA"
    k = loaded.effects[0].values["k"]
    assert k == entry["../my_effects.py:HammerMaxwell"]["k"]
