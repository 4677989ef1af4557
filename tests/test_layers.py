"""The code holds its layers (issue 14): no import cycle among rig's modules, counting
imports inside functions; the import-linter contracts of pyproject.toml hold."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import import_cycles  # noqa: E402


def test_the_cycle_finder_finds_a_cycle_and_only_cycles() -> None:
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert import_cycles.cycles(g) == [["a", "b", "c"]]
    assert import_cycles.cycles({"a": {"b"}, "b": set()}) == []


def test_function_level_imports_count(tmp_path: Path) -> None:
    src = tmp_path / "m.py"
    src.write_text("def f():\n    from rig.x import y\n    import rig.z\n"
                   "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import rig.w\n")
    found = import_cycles.imports("rig.m", src, {"rig.x", "rig.x.y", "rig.z", "rig.w", "rig.m"})
    assert found == {"rig.x.y", "rig.z"}  # the TYPE_CHECKING import is not one at run time


def test_no_import_cycle_among_rigs_modules() -> None:
    g = import_cycles.graph()
    assert len(g) > 60 and "rig.loop.backends" in g
    assert import_cycles.cycles(g) == []


def test_the_import_linter_contracts_hold() -> None:
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("import-linter is not installed (pip install -e '.[test]')")
    res = subprocess.run([exe], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-3000:]
    assert "0 broken" in res.stdout


def _table_rows() -> list[tuple[str, str]]:
    """docs/architecture.md's module table: (first cell, whole row) per row."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    section = text.split("\n## Modules, one line each\n", 1)[1].split("\n## ", 1)[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| `")]
    return [(ln.split("|")[1], ln) for ln in rows]


def unlisted_modules(rows: list[tuple[str, str]], modules: list[Path]) -> list[str]:
    """The modules (paths under rig/) that no row of the table lists: a top-level module
    by its path in a row's first cell, a package's module by its name in backticks in the
    row whose first cell names its package folder (``__init__`` needs no mention)."""
    missing = []
    for m in modules:
        rel = m.as_posix()
        folder = rel.rsplit("/", 1)[0] + "/"
        if folder == "rig/":
            ok = any(f"`{rel}`" in first for first, _ in rows)
        else:
            row = [r for first, r in rows if f"`{folder}`" in first]
            ok = bool(row) and (m.stem == "__init__" or f"`{m.stem}`" in row[0])
        if not ok:
            missing.append(rel)
    return missing


def test_the_table_check_finds_a_missing_module() -> None:
    rows = [("`rig/a.py`", "| `rig/a.py` | x |"), ("`rig/p/`", "| `rig/p/` | `one` |")]
    assert unlisted_modules(rows, [Path("rig/a.py"), Path("rig/p/one.py"),
                                   Path("rig/p/__init__.py")]) == []
    assert unlisted_modules(rows, [Path("rig/b.py"), Path("rig/p/two.py"),
                                   Path("rig/q/one.py")]) == ["rig/b.py", "rig/p/two.py",
                                                              "rig/q/one.py"]


def test_the_architecture_table_lists_every_module() -> None:
    modules = sorted(p.relative_to(ROOT) for p in (ROOT / "rig").rglob("*.py"))
    assert len(modules) > 100
    assert unlisted_modules(_table_rows(), modules) == []
