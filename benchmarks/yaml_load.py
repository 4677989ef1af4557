"""Why rig reads YAML with PyYAML's libyaml parser and YAML 1.2 core-schema rules of its
own (rig.inputs.params) rather than with ruamel.yaml, the maintained YAML 1.2 library:

    .venv/bin/python benchmarks/yaml_load.py [--repeats 30]

Prints, for the package's two parameter files (read by every model built in a fresh
process) and a shipped profile: the best time of rig's loader, of ruamel.yaml's safe
loader (C parser where ruamel.yaml.clib is installed, and pure Python), their ratio, and
whether the three read the same values. tests/test_inputs_as_written.py checks the rules
against ruamel.yaml scalar by scalar.
"""

from __future__ import annotations

import argparse
import io
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML

from rig.inputs.params import _load_yaml_text

ROOT = Path(__file__).resolve().parents[1]
FILES = [ROOT / "rig/data/action-parameters.yaml", ROOT / "rig/data/chosen-parameters.yaml",
         ROOT / "profiles/forte.yaml"]


def best(fn: Callable[[], Any], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    texts = [f.read_text() for f in FILES]
    ours = lambda: [_load_yaml_text(t, "bench") for t in texts]  # noqa: E731
    loaders = {"rig (libyaml + core schema)": ours}
    for pure in (False, True):
        y = YAML(typ="safe", pure=pure)
        loaders[f"ruamel.yaml safe, pure={pure}"] = (
            lambda y=y: [y.load(io.StringIO(t)) for t in texts])
    same = {name: fn() == ours() for name, fn in loaders.items()}
    times = {name: best(fn, args.repeats) for name, fn in loaders.items()}
    base = times["rig (libyaml + core schema)"]
    print(f"files: {', '.join(f.name for f in FILES)} ({sum(map(len, texts))} bytes)")
    for name, t in times.items():
        print(f"{name:32s} {t * 1e3:8.2f} ms  {t / base:6.1f}x  same values: {same[name]}")


if __name__ == "__main__":
    main()
