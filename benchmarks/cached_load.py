"""How long a fresh Python process takes to load an already built model.

Each measurement is a new interpreter that runs `import gagen; gagen.load(MODEL)` on a
warm cache (the model is built once first) and reports the wall time of those two lines
measured inside the process, next to the time of `import numpy` alone in another fresh
process (NumPy is the floor: every compiled module needs it). Fresh processes alternate
between the two, and the report gives medians over the repeats:

    python benchmarks/cached_load.py [--models rrr chain:3 PATH.urdf] [--repeats 15]

`sympy loaded` says whether SymPy was imported by the load (the runtime should not need it).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

LOAD = """
import json, sys, time
t0 = time.perf_counter()
import gagen
dyn = gagen.load(sys.argv[1])
t1 = time.perf_counter()
print(json.dumps({"seconds": t1 - t0, "sympy": "sympy" in sys.modules}))
"""

NUMPY = """
import json, time
t0 = time.perf_counter()
import numpy
print(json.dumps({"seconds": time.perf_counter() - t0}))
"""


def run(code: str, *args: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         check=True, env=os.environ)
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure(model: str, repeats: int) -> dict:
    run(LOAD, model)  # build into the cache if needed
    loads, numpys, sympy = [], [], False
    for _ in range(repeats):
        result = run(LOAD, model)
        loads.append(result["seconds"])
        sympy |= result["sympy"]
        numpys.append(run(NUMPY)["seconds"])
    load, floor = statistics.median(loads), statistics.median(numpys)
    return {"model": model, "load_ms": 1e3 * load, "numpy_ms": 1e3 * floor,
            "beyond_numpy_ms": 1e3 * (load - floor), "sympy_loaded": sympy}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["rrr", "chain:3"],
                        help="models to load (default: rrr chain:3)")
    parser.add_argument("--repeats", type=int, default=15, help="fresh processes per model")
    parser.add_argument("--cache-dir", help="cache to use (default: a new temporary one)")
    args = parser.parse_args(argv)
    cache = args.cache_dir or tempfile.mkdtemp(prefix="gagen-load-bench-")
    os.environ["GAGEN_CACHE_DIR"] = cache
    print("| model | import gagen + load (ms) | import numpy (ms) | beyond NumPy (ms) "
          "| SymPy imported |")
    print("|---|--:|--:|--:|---|")
    for model in args.models:
        r = measure(model, args.repeats)
        print(f"| {r['model']} | {r['load_ms']:.1f} | {r['numpy_ms']:.1f} | "
              f"{r['beyond_numpy_ms']:.1f} | {'yes' if r['sympy_loaded'] else 'no'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
