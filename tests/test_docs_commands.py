"""Docs that run: every command shown in README.md, docs/user-guide.md and
docs/workflow.md (and the Python blocks of docs/workflow.md and docs/api.md) is run
here, in order, in a scratch folder holding the shipped profiles/ and examples/, so a
missing file or a command that no longer works fails CI (issue 15).

Only two things shown are not run, each for a stated reason: the README's install step
(`python3 -m venv .venv && .venv/bin/pip install -e .`: CI's own install, tools/test.sh)
and `bash tools/test.sh` (this test suite itself)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RIG = Path(sys.executable).with_name("rig")
NOT_RUN = {
    "python3 -m venv .venv": "CI's own install step (tools/test.sh)",
    ".venv/bin/pip install -e .": "CI's own install step (tools/test.sh)",
    "bash tools/test.sh": "the test suite itself",
}


def blocks(text: str) -> list[tuple[str, str]]:
    """(language, body) of every fenced block, and of every 4-space indented block."""
    out = [(m.group(1).strip(), m.group(2))
           for m in re.finditer(r"^```([^\n]*)\n(.*?)^```", text, re.S | re.M)]
    unfenced = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    for m in re.finditer(r"(?:^ {4}\S.*\n?)+", unfenced, re.M):
        out.append(("", "\n".join(line[4:] for line in m.group(0).splitlines())))
    return out


def commands(text: str) -> list[str]:
    """The shell commands shown: lines starting with ``rig`` or another program the docs
    tell the user to type (continuation lines joined), split at ``&&``."""
    found: list[str] = []
    for lang, body in blocks(text):
        if lang not in ("", "bash", "sh", "console", "shell"):
            continue
        joined = re.sub(r"\\\n\s*", " ", body)
        for line in joined.splitlines():
            line = line.strip().removeprefix("$ ")
            if re.match(r"^(rig|python3?|bash|\.venv/bin/\S+)\s", line):
                found.extend(" ".join(part.split()) for part in line.split("&&"))
    return found


def python_blocks(text: str) -> list[str]:
    return [body for lang, body in blocks(text) if lang == "python"]


def _run(cmd: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    argv = shlex.split(cmd)
    if argv[0] in ("rig", ".venv/bin/rig"):
        argv[0] = str(RIG)
    env = {**os.environ, "COLUMNS": "120"}
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=900, env=env)


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("docs")
    for name in ("profiles", "examples"):
        (d / name).symlink_to(ROOT / name)
    (d / "rig").mkdir()
    (d / "rig" / "data").symlink_to(ROOT / "rig" / "data")
    return d


def test_the_command_parser_finds_each_doc_s_commands() -> None:
    readme = commands((ROOT / "README.md").read_text())
    assert ".venv/bin/rig run profiles/forte.yaml" in readme and "bash tools/test.sh" in readme
    wf = commands((ROOT / "docs/workflow.md").read_text())
    assert wf[0].startswith("rig synth --model examples/hidden-string/truth.yaml --profile")
    assert wf[0].endswith("--out data.h5") and any(c.startswith("rig fit") for c in wf)


@pytest.mark.slow
@pytest.mark.parametrize("doc", ["README.md", "docs/user-guide.md", "docs/workflow.md",
                                 "docs/api.md"])
def test_every_documented_command_runs(scratch: Path, doc: str) -> None:
    text = (ROOT / doc).read_text()
    if doc == "docs/api.md" and not (scratch / "data.h5").exists():  # run alone: its input
        assert _run(commands((ROOT / "docs/workflow.md").read_text())[0], scratch).returncode == 0
    ran = 0
    for cmd in commands(text):
        if cmd in NOT_RUN:
            continue
        res = _run(cmd, scratch)
        assert res.returncode == 0, f"{doc}: `{cmd}` exited {res.returncode}:\n" \
                                    f"{res.stdout[-2000:]}\n{res.stderr[-2000:]}"
        ran += 1
    for code in python_blocks(text):  # -P: the scratch folder's rig/data (a command names
        # it) must not shadow the installed package as a namespace package
        res = subprocess.run([sys.executable, "-P", "-c", code], cwd=scratch, capture_output=True,
                             text=True, timeout=900)
        assert res.returncode == 0, f"{doc}: Python block failed:\n{code}\n{res.stderr[-3000:]}"
        ran += 1
    assert ran > 0
