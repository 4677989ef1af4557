"""The commands the docs show, the outputs they show for them, and how the two are compared.

Shared by tests/test_docs_commands.py (which runs every documented command and fails on a
stale output) and tools/refresh_docs.py (which runs them the same way and rewrites the
shown outputs).

**Commands**: lines of a shell block (fenced without a language, or ``bash``, ``sh``,
``console``, ``shell``; or indented by 4 spaces) that start with ``rig``, ``python``,
``bash`` or ``.venv/bin/...``; continuation lines joined, split at ``&&``.

**Shown outputs**: a fenced block without a language tag (or ``text``) whose lines are
not commands shows the output of the last command of the nearest shell block before it,
with only prose or other such output blocks between (a paragraph may explain the command
before its output is shown; any other block, e.g. ``yaml`` or ``python``, ends the chain).

**Comparison**: the output is the command's stdout, then its stderr without the progress
lines (``rig: ...``). A shown block is a window onto it: each run of its lines between
``...`` lines must be consecutive lines of the output, in order; the block may start and
end anywhere. Two lines agree when their text without the numbers is the same
(whitespace-normalised) and each number agrees:

- a value printed with its uncertainty (``30310 +- 480``, ``(1.862 +- 0.042)e10``, read
  as ``1.862e10 +- 0.042e10``) within that printed uncertainty;
- any other number (an uncertainty too) within one unit of its last shown digit: the
  rounding of a figure that sits on a digit's edge. A whole number's last digit is its
  last non-zero one (``480``: tens; ``30310``: tens) and one without trailing zeros (a
  count, a rank) must be exact. With the lock file (requirements.lock) a seed-fixed
  command prints the same digits on one machine, so anything more is a stale doc. Not
  on every machine: the same commit and lock printed other last digits on another CPU
  (2026-11-27, an Emerald Rapids VM against the earlier sessions' machine, with numpy's
  AVX-512 paths, OpenBLAS's core type and numba's target CPU each ruled out: the base
  model's noise ratio 929.2 -> 929.5 in the hidden-string example, its flexible shank
  fitted alone at E = (1.757 +- 0.099)e10 Pa against (1.802 +- 0.052)e10, its final fit
  restarted into a minimum 0.3 % lower; the Kawai stroke 15's fitted radius 7.26 ->
  7.17 mm); the docs show what the machine of the last refresh printed
  (tools/refresh_docs.py);
- a shown value below 1e-6 in size (p-values such as ``7.6e-144``) agrees with an actual
  one of the same sign when their log10 differ by at most 4 % of the shown one's, and at
  least 2 decades: such tail probabilities come from a sum of squares in which the last
  bits of each term add up (2 % on a normal statistic is about 4 % on log10 p).

Wall-clock figures are not compared; only these, each matched as written:
``diagnosed in <t> s`` and ``... in <t> s wall`` (TIMING).
"""

from __future__ import annotations

import difflib
import math
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RIG = Path(sys.executable).with_name("rig")
DOCS = ["README.md", "docs/user-guide.md", "docs/workflow.md", "docs/import.md",
        "docs/real-data.md"]
NOT_RUN = {
    "bash tools/install.sh": "the set-up that tools/test.sh runs before the tests (CI's install)",
    "bash tools/test.sh": "the test suite itself",
}
SHELL = ("", "bash", "sh", "console", "shell")
OUTPUT = ("", "text")
TIMING = [re.compile(r"(?<=^diagnosed in )\S+(?= s$)"), re.compile(r"(?<= in )\S+(?= s wall)")]
TINY = 1e-6
NUM = re.compile(r"(?<![\w.])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
GROUPED = re.compile(r"\(([^()]*)\)e([-+]?\d+)")  # (1.862 +- 0.042)e10


@dataclass
class Shown:
    """An output block the doc shows: its lines and where they are (0-based line index)."""
    line: int
    lines: list[str]


@dataclass
class Miss:
    """The first shown line with no counterpart, and the actual line closest to it."""
    doc_line: str
    index: int  # within the block
    actual: str | None


# -- the docs' blocks ----------------------------------------------------------------------

def _fenced(text: str) -> list[tuple[str, str, int]]:
    """(language, body, line index of the body's first line) of every fenced block."""
    return [(m.group(1).strip(), m.group(2), text.count("\n", 0, m.start(2)))
            for m in re.finditer(r"^```([^\n]*)\n(.*?)^```", text, re.S | re.M)]


def blocks(text: str) -> list[tuple[str, str]]:
    """(language, body) of every fenced block, then of every 4-space indented block."""
    out = [(lang, body) for lang, body, _ in _fenced(text)]
    unfenced = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    for m in re.finditer(r"(?:^ {4}\S.*\n?)+", unfenced, re.M):
        out.append(("", "\n".join(line[4:] for line in m.group(0).splitlines())))
    return out


def _commands_in(lang: str, body: str) -> list[str]:
    if lang not in SHELL:
        return []
    found: list[str] = []
    for line in re.sub(r"\\\n\s*", " ", body).splitlines():
        line = line.strip().removeprefix("$ ")
        if re.match(r"^(rig|python3?|bash|\.venv/bin/\S+)\s", line):
            found.extend(" ".join(part.split()) for part in line.split("&&"))
    return found


def commands(text: str) -> list[str]:
    """The shell commands shown, in the order they are run."""
    return [cmd for lang, body in blocks(text) for cmd in _commands_in(lang, body)]


def shown_outputs(text: str) -> dict[int, list[Shown]]:
    """The output blocks shown, by the index in commands(text) of the command they show."""
    out: dict[int, list[Shown]] = {}
    n = 0
    owner: int | None = None
    for lang, body, line in _fenced(text):
        cmds = _commands_in(lang, body)
        if cmds:
            n += len(cmds)
            owner = n - 1
        elif lang in OUTPUT and owner is not None:
            out.setdefault(owner, []).append(Shown(line, body.splitlines()))
        else:
            owner = None
    return out


def python_blocks(text: str) -> list[str]:
    return [body for lang, body in blocks(text) if lang == "python"]


# -- running them --------------------------------------------------------------------------

def make_scratch(d: Path) -> Path:
    """A folder holding the shipped files the docs' commands name."""
    for name in ("profiles", "examples"):
        (d / name).symlink_to(ROOT / name)
    (d / "rig").mkdir()
    (d / "rig" / "data").symlink_to(ROOT / "rig" / "data")
    return d


def run(cmd: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    argv = shlex.split(cmd)
    if argv[0] in ("rig", ".venv/bin/rig"):
        argv[0] = str(RIG)
    elif argv[0] in ("python", "python3", ".venv/bin/python"):  # the environment rig is in
        argv[0] = sys.executable
    env = {**os.environ, "COLUMNS": "120"}
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=900, env=env)


def output_lines(res: subprocess.CompletedProcess[str]) -> list[str]:
    """stdout, then stderr without the progress lines."""
    return res.stdout.splitlines() + [line for line in res.stderr.splitlines()
                                      if not line.startswith("rig: ")]


# -- comparing -----------------------------------------------------------------------------

def _split(line: str) -> tuple[str, list[str]]:
    """(the text with each number as a placeholder, whitespace-normalised; the numbers)."""
    for pat in TIMING:
        line = pat.sub("<wall-clock>", line)
    line = GROUPED.sub(lambda m: "(" + NUM.sub(lambda n: n.group(0) + "e" + m.group(2),
                                                m.group(1)) + ")", line)
    return " ".join(NUM.sub("\0", line).split()), NUM.findall(line)


def _last_digit(s: str) -> float:
    """The value of one unit of the last digit shown; 0 for a whole number with no
    trailing zeros (a count), 10**k for one with k trailing zeros (``480``, ``30310``)."""
    mant, e, exp = s.lower().partition("e")
    if "." not in mant and not e:
        digits = mant.lstrip("+-")
        zeros = len(digits) - len(digits.rstrip("0"))
        return 0.0 if zeros == 0 or zeros == len(digits) else 10.0 ** zeros
    decimals = len(mant.partition(".")[2])
    return 10.0 ** (int(exp or 0) - decimals)


def numbers_agree(shown: str, actual: str, uncertainty: str | None = None) -> bool:
    """Whether an actual number shows the same as a shown one (the rules above);
    ``uncertainty``: the shown value's printed uncertainty, if it has one."""
    x, y = float(shown), float(actual)
    if x == y:
        return True
    if abs(x) < TINY and x != 0:
        return x * y > 0 and abs(math.log10(abs(x) / abs(y))) <= max(
            2.0, 0.04 * abs(math.log10(abs(x))))
    slack = _last_digit(shown) * (1 + 1e-9)  # the float of 0.1 + one unit, not a miss
    if uncertainty is not None:
        slack = max(slack, float(uncertainty))
    return abs(x - y) <= slack


def lines_agree(shown: str, actual: str) -> bool:
    (s_text, s_nums), (a_text, a_nums) = _split(shown), _split(actual)
    if s_text != a_text or len(s_nums) != len(a_nums):
        return False
    between = s_text.split("\0")[1:-1]  # the text between number k and number k + 1
    for k, (s, a) in enumerate(zip(s_nums, a_nums, strict=True)):
        u = s_nums[k + 1] if k < len(between) and between[k].strip() == "+-" else None
        if not numbers_agree(s, a, u):
            return False
    return True


def same_text(shown: str, actual: str) -> bool:
    """The loose agreement tools/refresh_docs.py matches with: the numbers may differ."""
    return _split(shown)[0] == _split(actual)[0]


def match(shown: list[str], actual: list[str],
          agree: Callable[[str, str], bool] = lines_agree) -> list[int | None] | Miss:
    """For each shown line, the index of the actual line it shows (None for ``...``); or
    the first shown line that has none."""
    found: list[int | None] = []
    pos = 0
    i = 0
    while i < len(shown):
        if shown[i].strip() == "...":
            found.append(None)
            i += 1
            continue
        run = shown[i:]
        run = run[:next((k for k, s in enumerate(run) if s.strip() == "..."), len(run))]
        best = (-1, pos)  # (lines agreeing, start)
        for start in range(pos, len(actual) - len(run) + 1):
            k = next((k for k, s in enumerate(run) if not agree(s, actual[start + k])),
                     len(run))
            if k == len(run):
                break
            best = max(best, (k, start), key=lambda b: b[0])
        else:
            k, start = best
            if k > 0:
                closest: str | None = actual[start + k] if start + k < len(actual) else None
            else:
                rest = actual[pos:] or actual
                closest = max(rest, default=None, key=lambda a: difflib.SequenceMatcher(
                    None, " ".join(run[0].split()), " ".join(a.split())).ratio())
            return Miss(run[max(k, 0)], i + max(k, 0), closest)
        found.extend(range(start, start + len(run)))
        pos = start + len(run)
        i += len(run)
    return found


def describe(doc: str, cmd: str, block: Shown, miss: Miss) -> str:
    return (f"{doc}:{block.line + miss.index + 1}: `{cmd}` no longer prints what the doc "
            f"shows (tools/refresh_docs.py rewrites it)\n  doc:    {miss.doc_line.strip()}\n"
            f"  actual: {'(no line)' if miss.actual is None else miss.actual.strip()}")
