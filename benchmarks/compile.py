"""Where the first use's compile time goes, on an EMPTY numba cache (issue 16).

    .venv/bin/python benchmarks/compile.py            # rigid blow, then the full model
    .venv/bin/python benchmarks/compile.py --rigid    # only what `rig simulate` needs

Runs a fresh interpreter with ``NUMBA_CACHE_DIR`` and ``RIG_CACHE_DIR`` pointing
to new empty folders (so nothing compiled or settled before is used, and the
package's own ``__pycache__`` is left alone) and times, in that process:
importing the model, each stage of a first forte blow (build, rest state,
simulate) and each compiled function that Python called, with its signature
count (numba's ``numba:compile`` events: the time of a function includes the
functions it compiles for itself, e.g. an integrator inlining the kernel).
The total is the wall time of the whole child process.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
from numba.core import event
records = []

stack = []

class Listener(event.Listener):
    def on_start(self, ev):
        stack.append(time.perf_counter())

    def on_end(self, ev):
        took = time.perf_counter() - stack.pop()
        d = ev.data or {}
        disp = d.get("dispatcher")
        name = getattr(getattr(disp, "py_func", None), "__qualname__", str(disp))
        module = getattr(getattr(disp, "py_func", None), "__module__", "")
        records.append((module + "." + name, took, len(stack)))

import numba.core.dispatcher as D
real = D.Dispatcher._compile_for_args
calls = []

def timed(self, *a, **k):
    t = time.perf_counter()
    try:
        return real(self, *a, **k)
    finally:
        calls.append((self.py_func.__module__ + "." + self.py_func.__qualname__,
                      time.perf_counter() - t))

D.Dispatcher._compile_for_args = timed
event.register("numba:compile", Listener())
stages = {}
t = time.perf_counter()
from pathlib import Path
from rig.inputs import profiles
from rig.model.action import ActionModel
stages["import the model"] = time.perf_counter() - t
forte = profiles.load(Path(sys.argv[1]) / "profiles" / "forte.yaml")
for label, effects in json.loads(sys.argv[2]):
    before = len(calls)
    t = time.perf_counter(); m = ActionModel(effects=effects)
    stages[label + ": build"] = time.perf_counter() - t
    t = time.perf_counter(); m.rest_state()
    stages[label + ": rest state"] = time.perf_counter() - t
    t = time.perf_counter(); m.simulate(forte)
    stages[label + ": simulate"] = time.perf_counter() - t
    t = time.perf_counter(); m.simulate(forte)
    stages[label + ": simulate again (compiled)"] = time.perf_counter() - t
print("RESULT" + json.dumps({"stages": stages, "calls": calls,
                             "compiles": records}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rigid", action="store_true", help="only the rigid model's blow")
    args = ap.parse_args()
    models = [("rigid", [])] + ([] if args.rigid else [("full", ["flexible_shank",
                                                                 "key_liftoff"])])
    with tempfile.TemporaryDirectory(prefix="rig-bench-compile-") as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba"),
               "RIG_CACHE_DIR": str(Path(tmp) / "rig")}
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", _CHILD, str(ROOT), json.dumps(models)],
                              env=env, capture_output=True, text=True)
        total = time.perf_counter() - t0
        written = sum(1 for _ in (Path(tmp) / "numba").rglob("*.nbc"))
    line = next((x for x in proc.stdout.splitlines() if x.startswith("RESULT")), None)
    if proc.returncode != 0 or line is None:
        sys.exit(f"the child failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}")
    data = json.loads(line[len("RESULT"):])
    print(f"first use on an empty numba cache: {total:.1f} s whole process "
          f"(load average {os.getloadavg()[0]:.2f}; {written} compiled signatures cached)")
    for name, s in data["stages"].items():
        print(f"  {name:<42} {s:7.2f} s")
    print("compiled functions called from Python (time includes what each compiles inside):")
    for name, s in data["calls"]:
        print(f"  {name:<60} {s:7.2f} s")
    print(f"numba compile events ({len(data['compiles'])}), the longest: time including "
          "nested compiles, nesting depth")
    for name, took, depth in sorted(data["compiles"], key=lambda r: -r[1])[:10]:
        print(f"  {took:7.2f} s  depth {depth}  {name}")


if __name__ == "__main__":
    main()
