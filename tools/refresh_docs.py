"""Rewrite the outputs the docs show with what their commands print now.

    python tools/refresh_docs.py [--dry-run] [DOC ...]   # default: README.md,
                                                       # docs/user-guide.md, docs/workflow.md

Runs each doc's commands in order in one scratch folder, as tests/test_docs_commands.py
does (tools/doc_outputs.py: the shipped profiles/, examples/ and rig/data, COLUMNS=120, a
scratch rest-state cache), then replaces each shown output line by the output line it
shows, matched as the test matches but with the numbers free: the doc keeps its selection
of lines and its ``...``. Nothing outside the shown output blocks is touched; each changed
line is printed. Exit 1 when a command fails or a shown line has no counterpart (that block
is left as it was: edit it by hand). The Python blocks are not run: they show no output.
Run it with the venv's python: the ``rig`` beside it is the one run."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import doc_outputs as d


def refresh(doc: str, scratch: Path, write: bool) -> bool:
    path = d.ROOT / doc
    text = path.read_text()
    lines = text.splitlines(keepends=True)
    shown = d.shown_outputs(text)
    ok = True
    for i, cmd in enumerate(d.commands(text)):
        if cmd in d.NOT_RUN:
            continue
        t0 = time.perf_counter()
        res = d.run(cmd, scratch)
        print(f"{doc}: `{cmd}` ({time.perf_counter() - t0:.1f} s)", flush=True)
        if res.returncode != 0:
            print(f"  exited {res.returncode}:\n{res.stderr[-2000:]}")
            return False
        actual = d.output_lines(res)
        for block in shown.get(i, []):
            found = d.match(block.lines, actual, d.same_text)
            if isinstance(found, d.Miss):
                print("  " + d.describe(doc, cmd, block, found).replace("\n", "\n  ")
                      + "\n  (no line with that text: block left as it was)")
                ok = False
                continue
            for k, j in enumerate(found):
                n = block.line + k
                if j is not None and lines[n].rstrip("\n") != actual[j].rstrip():
                    print(f"  {doc}:{n + 1}\n  - {lines[n].rstrip()}\n  + {actual[j].rstrip()}")
                    lines[n] = actual[j].rstrip() + "\n"
    new = "".join(lines)
    if write and new != text:
        path.write_text(new)
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("docs", nargs="*", default=d.DOCS, help="docs, relative to the repository")
    ap.add_argument("--dry-run", action="store_true", help="print the changes, write nothing")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="refresh-docs-") as tmp:
        scratch = d.make_scratch(Path(tmp))
        os.environ["RIG_CACHE_DIR"] = str(scratch / ".rig-cache")  # as tests/conftest.py
        ok = [refresh(doc, scratch, not args.dry_run) for doc in args.docs]
    return 0 if all(ok) else 1


if __name__ == "__main__":
    sys.exit(main())
