"""Docs that run: every command shown in README.md, docs/user-guide.md and
docs/workflow.md (and the Python blocks of docs/workflow.md and docs/api.md) is run
here, in order, in a scratch folder holding the shipped profiles/ and examples/, so a
missing file or a command that no longer works fails CI (issue 15); the output a doc
shows for a command must be what it prints now, numbers within a run-to-run tolerance
(tools/doc_outputs.py says how they are compared; tools/refresh_docs.py rewrites them).

Only two things shown are not run, each for a stated reason: the README's install step
(`bash tools/install.sh`: the set-up tools/test.sh runs first, CI's own install) and
`bash tools/test.sh` (this test suite itself)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import doc_outputs as d  # noqa: E402

DOC = """Make data:
```
rig synth --out data.h5
```
which prints
```
2 trial(s)
wrote data.h5
```
Then
```
rig diagnose data.h5 \\
    --write fixed.yaml
```
First, where it fails:
```
  hammer_angle         1.06 %
  ...
```
then the candidates:
```
  1. compliant_string: stiffness = 29960 +- 270 N/m, E = (1.862 +- 0.042)e10 Pa
...
  step 1: p = 7.6e-144, lag +0.33 ms, bias -1.46, rms 3.8e-05
diagnosed in 145.1 s
```
```yaml
a: 1
```
```
not: an output (a yaml block came between)
```
"""
OUT = """where it fails:
  hammer_angle         1.07 %
  key_dip              0.35 %
  1. compliant_string: stiffness = 30100 +- 272 N/m, E = (1.87 +- 0.043)e10 Pa
  2. flexible_shank: stiffness = 9 N/m
  step 1: p = 2.1e-145, lag +0.34 ms, bias -1.47, rms 3.9e-05
diagnosed in 38.0 s
wrote fixed.yaml""".splitlines()


def test_the_command_parser_finds_each_doc_s_commands() -> None:
    readme = d.commands((ROOT / "README.md").read_text())
    assert readme[:2] == ["bash tools/install.sh", ".venv/bin/rig run profiles/forte.yaml"]
    assert "bash tools/test.sh" in readme and all(c in d.NOT_RUN for c in (readme[0], readme[-1]))
    wf = d.commands((ROOT / "docs/workflow.md").read_text())
    assert wf[0].startswith("rig synth --model examples/hidden-string/truth.yaml --profile")
    assert wf[0].endswith("--out data.h5") and any(c.startswith("rig fit") for c in wf)


def test_output_blocks_belong_to_the_command_before_them() -> None:
    assert d.commands(DOC) == ["rig synth --out data.h5",
                               "rig diagnose data.h5 --write fixed.yaml"]
    shown = d.shown_outputs(DOC)
    assert sorted(shown) == [0, 1] and len(shown[0]) == 1 and len(shown[1]) == 2
    assert shown[0][0].lines == ["2 trial(s)", "wrote data.h5"]
    assert DOC.splitlines()[shown[1][1].line].startswith("  1. compliant_string")
    wf = (ROOT / "docs/workflow.md").read_text()  # synth, compare, diagnose (2), compare
    cmds, blocks = d.commands(wf), d.shown_outputs(wf)
    assert [(cmds[i].split()[1], len(b)) for i, b in sorted(blocks.items())] == \
        [("synth", 1), ("compare", 1), ("diagnose", 2), ("compare", 1)]


def test_shown_lines_match_within_the_tolerance_and_with_elisions() -> None:
    blocks = d.shown_outputs(DOC)
    assert d.match(blocks[0][0].lines, ["2 trial(s)", "wrote data.h5"]) == [0, 1]
    assert d.match(blocks[1][0].lines, OUT) == [1, None]
    assert d.match(blocks[1][1].lines, OUT) == [3, None, 5, 6]  # the time is not compared


@pytest.mark.parametrize("shown, actual", [
    ("stiffness = 29960 +- 270 N/m", "stiffness = 30240 +- 270 N/m"),  # beyond its +- 270
    ("stiffness = 30310 +- 480 N/m", "stiffness = 30060 +- 890 N/m"),  # the uncertainty moved
    ("2 trial(s)", "3 trial(s)"),                       # a count: exact
    ("lag +0.33 ms", "lag +0.35 ms"),                   # 2 units of the last digit
    ("err -0.0495 ms", "err -0.0417 ms"),
    ("removes 98.0 %", "removes 97.8 %"),
    ("E = (1.862 +- 0.042)e10 Pa", "E = (1.862 +- 0.042)e11 Pa"),
    ("p = 7.6e-144", "p = 7.6e-150"),                   # 6 decades: 4.2 % of log10 p
    ("p = 2e-7", "p = 3e-10"),                          # 2.8 decades
    ("p = 7.6e-144", "p = 0.03"),
    ("bias -1.46", "bias 1.46"),
    ("hammer_angle 1.06 %", "key_angle 1.06 %"),
    ("diagnosed in 145.1 s", "diagnosed in 145.1 s, 3 candidates"),
])
def test_a_changed_number_or_text_fails(shown: str, actual: str) -> None:
    assert d.lines_agree(shown, shown) and not d.lines_agree(shown, actual)


@pytest.mark.parametrize("shown, actual", [
    ("RMS 0.00399", "RMS 0.004"),                       # one unit of the last digit
    ("stiffness = 29960 +- 270 N/m", "stiffness = 30200 +- 260 N/m"),  # within +- 270
    ("stiffness = 30310 +- 480 N/m", "stiffness = 30060 +- 490 N/m"),
    ("lag +0.33 ms", "lag +0.34 ms"),
    ("rms 3.8e-05", "rms 3.9e-05"),
    ("E = (1.862 +- 0.042)e10 Pa", "E = (18.7 +- 0.42)e9 Pa"),
    ("p = 7.6e-144", "p = 3e-149"),                     # 5.4 decades, 3.8 % of log10 p
    ("p = 2e-7", "p = 3e-9"),
    ("  hammer_angle  1.06 %", "hammer_angle 1.06    %"),
    ("diagnosed in 145.1 s", "diagnosed in 13.1 s"),
    ("simulated 0.300 s in 1.234 s wall", "simulated 0.300 s in 0.2 s wall"),
])
def test_lines_that_agree(shown: str, actual: str) -> None:
    assert d.lines_agree(shown, actual)


def test_lines_between_elisions_are_consecutive() -> None:
    shown = ["  hammer_angle         1.06 %", "  key_dip              0.35 %"]
    assert d.match(shown, OUT) == [1, 2]
    out = OUT[:2] + ["  whippen_angle        0.45 %"] + OUT[2:]
    assert isinstance(d.match(shown, out), d.Miss)  # a line between them in the output
    assert d.match([shown[0], "...", shown[1]], out) == [1, None, 3]
    assert isinstance(d.match(shown[::-1], OUT), d.Miss)  # in another order
    assert d.match(shown[::-1], OUT[:3] + OUT[1:2]) == [2, 3]


def test_a_miss_names_the_doc_line_and_the_closest_actual_line() -> None:
    block = d.shown_outputs(DOC)[1][1]
    stale = [line.replace("30100", "25000") for line in OUT]
    miss = d.match(block.lines, stale)
    assert isinstance(miss, d.Miss) and miss.index == 0
    assert miss.actual == stale[3]
    msg = d.describe("docs/x.md", "rig diagnose data.h5", block, miss)
    assert msg.startswith("docs/x.md:22: `rig diagnose data.h5`")
    assert "doc:    1. compliant_string: stiffness = 29960" in msg
    assert "actual: 1. compliant_string: stiffness = 25000" in msg
    later = d.match(block.lines, OUT[:5] + ["  step 1: p = 2.1e-145, lag +0.45 ms, bias -1.47, "
                                            "rms 3.9e-05", OUT[6]])
    assert isinstance(later, d.Miss) and later.index == 2 and "+0.45" in str(later.actual)


def test_the_refresh_match_frees_the_numbers_only() -> None:
    block = d.shown_outputs(DOC)[1][1]
    stale = [line.replace("30100", "25000") for line in OUT]
    assert d.match(block.lines, stale, d.same_text) == [3, None, 5, 6]
    assert isinstance(d.match(["  3. compliant_string: stiffness = 29960 +- 270 N/m, "
                               "E = (1.862 +- 0.042)e10 Pa, more"], OUT, d.same_text), d.Miss)


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    return d.make_scratch(tmp_path_factory.mktemp("docs"))


@pytest.mark.slow
@pytest.mark.docs
@pytest.mark.parametrize("doc", [*d.DOCS, "docs/api.md"])
def test_every_documented_command_runs_and_prints_what_the_doc_shows(scratch: Path,
                                                                      doc: str) -> None:
    text = (ROOT / doc).read_text()
    if doc == "docs/api.md" and not (scratch / "data.h5").exists():  # run alone: its input
        assert d.run(d.commands((ROOT / "docs/workflow.md").read_text())[0],
                     scratch).returncode == 0
    shown = d.shown_outputs(text)
    ran = 0
    stale = []
    for i, cmd in enumerate(d.commands(text)):
        if cmd in d.NOT_RUN:
            continue
        res = d.run(cmd, scratch)
        assert res.returncode == 0, f"{doc}: `{cmd}` exited {res.returncode}:\n" \
                                    f"{res.stdout[-2000:]}\n{res.stderr[-2000:]}"
        ran += 1
        for block in shown.get(i, []):
            miss = d.match(block.lines, d.output_lines(res))
            if isinstance(miss, d.Miss):
                stale.append(d.describe(doc, cmd, block, miss))
    for code in d.python_blocks(text):  # -P: the scratch folder's rig/data (a command names
        # it) must not shadow the installed package as a namespace package
        res = subprocess.run([sys.executable, "-P", "-c", code], cwd=scratch, capture_output=True,
                             text=True, timeout=900)
        assert res.returncode == 0, f"{doc}: Python block failed:\n{code}\n{res.stderr[-3000:]}"
        ran += 1
    assert ran > 0
    assert not stale, "\n".join(stale)
