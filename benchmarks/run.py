"""Run every benchmark script in this folder (``bench_*.py``), one after the other.

    python benchmarks/run.py                 # all of them
    python benchmarks/run.py rigidity agent  # only bench_rigidity.py and bench_agent.py
    python benchmarks/run.py --quick         # short versions, where a script has one

Each script prints its own table with ratios against a baseline measured in the same run.
Timings are never part of the tests.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="benchmark names (bench_NAME.py); default all")
    parser.add_argument("--quick", action="store_true", help="pass --quick to scripts that take it")
    args = parser.parse_args()
    scripts = sorted(HERE.glob("bench_*.py"))
    if args.names:
        wanted = {f"bench_{n.removeprefix('bench_').removesuffix('.py')}.py" for n in args.names}
        unknown = wanted - {s.name for s in scripts}
        if unknown:
            parser.error(f"no such benchmark: {', '.join(sorted(unknown))}")
        scripts = [s for s in scripts if s.name in wanted]
    failed = 0
    for script in scripts:
        print(f"\n=== {script.name} ===", flush=True)
        extra = ["--quick"] if args.quick and "--quick" in script.read_text() else []
        failed += subprocess.call([sys.executable, str(script), *extra]) != 0
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
