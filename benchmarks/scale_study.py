"""Paper 000 reproduction over several seeds (issue 3 acceptance numbers).

Runs every scale scenario for ``--seeds`` seeds and prints per-run results and medians, then
the active case with 1 degree bearing noise and 10 % message loss. Usage::

    python benchmarks/scale_study.py [--seeds 10] [--duration 20] [--json out.json]
        [--engine cores|compiled]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

from sim.runner import summarize
from sim.scenarios import SCENARIOS, run_scenario


def _median(values: list[float | None]) -> float | None:
    """Median with ``None`` (never converged) counted as +infinity."""
    v = sorted(math.inf if x is None else x for x in values)
    m = statistics.median(v)
    return None if math.isinf(m) else m


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--json", type=str, default=None)
    ap.add_argument(
        "--engine",
        choices=("cores", "compiled"),
        default="cores",
        help="agent cores (the reference) or the compiled engine (~250x real time)",
    )
    args = ap.parse_args()
    rows = []
    for name in SCENARIOS:
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            res = {
                "scenario": name,
                "seed": seed,
                **summarize(run_scenario(name, seed, args.duration, engine=args.engine)),
            }
            res["wall_s"] = time.perf_counter() - t0
            rows.append(res)
            print(json.dumps(res), flush=True)
    for seed in range(args.seeds):
        rec = run_scenario(
            "scale-active",
            seed,
            args.duration,
            bearing_noise_rad=math.radians(1.0),
            loss=0.1,
            engine=args.engine,
        )
        res = {"scenario": "scale-active+noise1deg+loss10", "seed": seed, **summarize(rec)}
        rows.append(res)
        print(json.dumps(res), flush=True)
    print(
        "\nscenario                          median converged_s  median lambda_bar_mean  "
        "never  median final loc err [m]  median final chi err max"
    )
    summary = {}
    for name in [*SCENARIOS, "scale-active+noise1deg+loss10"]:
        rs = [r for r in rows if r["scenario"] == name]
        conv = _median([r["converged_s"] for r in rs])
        lam = statistics.median(r["lambda_bar_mean"] for r in rs)
        never = sum(r["converged_s"] is None for r in rs)
        loc = statistics.median(r["final_localization_error"] for r in rs)
        chi = statistics.median(r["final_chi_error_max"] for r in rs)
        summary[name] = {
            "converged_s": conv,
            "lambda_bar_mean": lam,
            "never": never,
            "final_localization_error": loc,
            "final_chi_error_max": chi,
        }
        print(f"{name:34s}{conv!s:>20}{lam:>24.4f}{never:>7d}{loc:>26.4f}{chi:>26.5f}")
    a, r = summary["scale-active"], summary["scale-random"]
    if a["converged_s"] is not None and r["converged_s"] is not None:
        print(
            f"\nactive/random converged_s ratio: {a['converged_s'] / r['converged_s']:.3f} (<= 0.75)"
        )
    print(
        f"active/random lambda_bar ratio: {a['lambda_bar_mean'] / r['lambda_bar_mean']:.1f} (>= 5)"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"runs": rows, "summary": summary}, f, indent=1)


if __name__ == "__main__":
    main()
