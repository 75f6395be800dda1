"""Per grid point statistics of a sweep: median, interquartile range, fractions, bootstrap CI.

* A metric whose name starts with ``converged`` is a time that is ``None`` when the run never
  converged; it counts as +infinity (so "median never" is possible, as the README reports it)
  and JSON shows infinity as ``null``. Other ``None`` values are left out.
* Boolean metrics (``stayed_above_lambda_min``, ``rigidity_lost``) become the fraction of runs
  where they hold; ``converged`` is the fraction of runs with a ``converged_s``.
* The confidence interval of the median is the percentile bootstrap (Efron & Tibshirani,
  *An Introduction to the Bootstrap*, ch. 13): ``B = 2000`` resamples with replacement, the
  2.5 % and 97.5 % quantiles of their medians; the resampling generator is seeded by the grid
  point, so the same rows give the same interval.
"""

from __future__ import annotations

import json
import math

import numpy as np

from sim.sweep.results import row_metrics
from sim.sweep.runs import RunStatus

BOOTSTRAP_RESAMPLES = 2000
CI_LEVEL = 0.95
KEY_METRICS: dict[str, tuple[str, ...]] = {
    "scale": ("converged_s", "lambda_bar_mean", "final_localization_error", "final_chi_error_max"),
    "rigidity": (
        "min_rigidity_eigenvalue",
        "fraction_time_rigid",
        "final_localization_error",
        "distributed_eigen_error_p95",
    ),
}
"""Metrics the printed table shows per scenario family (``--json`` has all of them)."""
KEY_FRACTIONS: dict[str, tuple[str, ...]] = {
    "scale": ("converged",),
    "rigidity": ("stayed_above_lambda_min", "rigidity_lost"),
}


def family(scenario: str) -> str:
    return "rigidity" if scenario.startswith("rigidity") else "scale"


def quantile(sorted_x: np.ndarray, q: float) -> float:
    """Linear-interpolation quantile of sorted values that may hold +inf (inf-safe)."""
    n = len(sorted_x)
    h = (n - 1) * q
    lo, hi = math.floor(h), math.ceil(h)
    a, b = float(sorted_x[lo]), float(sorted_x[hi])
    if a == b or math.isinf(b):
        return a if a == b else math.inf
    return a + (b - a) * (h - lo)


def bootstrap_median_ci(
    x: np.ndarray, seed: int, resamples: int = BOOTSTRAP_RESAMPLES, level: float = CI_LEVEL
) -> tuple[float, float]:
    """Percentile bootstrap interval of the median of ``x`` (see the module docstring)."""
    if len(x) == 0:
        return math.nan, math.nan
    rng = np.random.default_rng([seed, 1729])
    idx = rng.integers(0, len(x), size=(resamples, len(x)))
    meds = np.sort(np.median(x[idx], axis=1))
    a = (1.0 - level) / 2.0
    return quantile(meds, a), quantile(meds, 1.0 - a)


def metric_stats(values: list[object], name: str, seed: int) -> dict[str, object] | None:
    """Statistics of one metric over the runs of one grid point (``None``: not numeric)."""
    conv = name.startswith("converged")
    xs: list[float] = []
    for v in values:
        if v is None:
            if conv:
                xs.append(math.inf)
        elif isinstance(v, bool):
            return None
        elif isinstance(v, int | float):
            xs.append(float(v))
        else:
            return None
    if not xs:
        return {"n": 0, "median": None, "q25": None, "q75": None, "iqr": None, "ci95": None}
    x = np.sort(np.array(xs))
    lo, hi = bootstrap_median_ci(x, seed)
    q25, q75 = quantile(x, 0.25), quantile(x, 0.75)
    return {
        "n": len(xs),
        "median": float(np.median(x)),
        "q25": q25,
        "q75": q75,
        "iqr": q75 - q25 if math.isfinite(q75 - q25) else math.inf,
        "ci95": [lo, hi],
    }


def summarize_points(rows: list[dict[str, object]]) -> list[dict[str, object]]:
    """One summary per grid point, in point order."""
    by_point: dict[int, list[dict[str, object]]] = {}
    for r in rows:
        by_point.setdefault(int(r["point"]), []).append(r)  # type: ignore[arg-type]
    out = []
    for point, rs in sorted(by_point.items()):
        ok = [r for r in rs if r["status"] == RunStatus.OK.value]
        names = row_metrics(ok[0]) if ok else []
        metrics: dict[str, object] = {}
        fractions: dict[str, float | None] = {}
        for m in names:
            vals = [r.get(m) for r in ok]
            if m == "converged_s":
                fractions["converged"] = sum(v is not None for v in vals) / len(ok)
            if all(isinstance(v, bool) for v in vals):
                fractions[m] = sum(bool(v) for v in vals) / len(ok)
                continue
            st = metric_stats(vals, m, point)
            if st is not None:
                metrics[m] = st
        out.append(
            {
                "point": point,
                "scenario": rs[0]["scenario"],
                "label": rs[0]["label"] or "",
                "params": json.loads(str(rs[0]["params"])),
                "duration_s": rs[0]["duration_s"],
                "runs": len(rs),
                "ok": len(ok),
                "failed": sum(r["status"] == RunStatus.FAILED.value for r in rs),
                "timeout": sum(r["status"] == RunStatus.TIMEOUT.value for r in rs),
                "fractions": fractions,
                "metrics": metrics,
                "wall_s_median": float(np.median([float(r["wall_s"]) for r in rs])),  # type: ignore[arg-type]
            }
        )
    return out


def json_safe(obj: object) -> object:
    """Infinity and NaN -> ``None`` (JSON has neither), recursively."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    return obj


def _fmt(x: object) -> str:
    if x is None:
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "never"
    if isinstance(x, float) and math.isnan(x):
        return "-"
    v = float(x)  # type: ignore[arg-type]
    return f"{v:.3g}" if abs(v) < 1000 else f"{v:.0f}"


def table(summaries: list[dict[str, object]], title: str = "sweep summary"):
    """A rich :class:`~rich.table.Table` of the key metrics (median [95% CI], IQR)."""
    from rich.markup import escape
    from rich.table import Table

    fams = sorted({family(str(s["scenario"])) for s in summaries})
    t = Table(title=title, caption="median [95% bootstrap CI of the median] (interquartile range)")
    t.add_column("grid point")
    t.add_column("runs (failed)", justify="right")
    frac_cols = [f for fam in fams for f in KEY_FRACTIONS[fam]]
    metric_cols = list(dict.fromkeys(m for fam in fams for m in KEY_METRICS[fam]))
    for f in frac_cols:
        t.add_column(f"frac {f}", justify="right")
    for m in metric_cols:
        t.add_column(f"{m}: median [95% CI] (IQR)", justify="right")
    for s in summaries:
        params = s["params"]
        name = s["label"] or " ".join(
            [str(s["scenario"]), *(f"{k}={v}" for k, v in params.items())]  # type: ignore[union-attr]
        )
        bad = int(s["failed"]) + int(s["timeout"])  # type: ignore[call-overload]
        cells = [str(name), f"{s['runs']} ({bad})"]
        fr: dict = s["fractions"]  # type: ignore[assignment]
        cells += [_fmt(fr.get(f)) for f in frac_cols]
        ms: dict = s["metrics"]  # type: ignore[assignment]
        for m in metric_cols:
            st = ms.get(m)
            if not st or st["median"] is None:
                cells.append("-")
                continue
            lo, hi = st["ci95"]
            cells.append(
                escape(f"{_fmt(st['median'])} [{_fmt(lo)}, {_fmt(hi)}] ({_fmt(st['iqr'])})")
            )
        t.add_row(*cells)
    return t
