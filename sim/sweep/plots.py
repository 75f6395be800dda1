"""``bearingflock sweep plot DIR``: the figures people look at after a sweep.

* ``cdf_<metric>.png``: the empirical CDF of the convergence time per grid point (runs that
  never converged keep the curve below 1: its height at the end is the fraction converged);
* ``<metric>_vs_<param>.png``: each key metric's median against every numeric parameter the
  grid varies, with the 95 % bootstrap interval of the median as a band, one line per value
  of the other grid coordinates;
* ``heatmap_<metric>.png``: for two-parameter grids, the median on the grid.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from sim.sweep.summary import KEY_METRICS, family, summarize_points


def _key(s: dict) -> str:
    return s["label"] or " ".join([s["scenario"], *(f"{k}={v}" for k, v in s["params"].items())])


def _numeric_axes(summaries: list[dict]) -> list[str]:
    names: list[str] = []
    for s in summaries:
        for k in s["params"]:
            if k not in names:
                names.append(k)
    out = []
    for k in names:
        vals = {s["params"].get(k) for s in summaries if k in s["params"]}
        if len(vals) > 1 and all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in vals
        ):
            out.append(k)
    return out


def plot_cdf(rows: list[dict], summaries: list[dict], metric: str, out_dir: Path, plt) -> Path:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for s in summaries:
        vals = [r.get(metric) for r in rows if r["point"] == s["point"] and r["status"] == "ok"]
        if not vals:
            continue
        x = np.sort([float(v) for v in vals if v is not None])
        y = np.arange(1, len(x) + 1) / len(vals)
        ax.step(np.concatenate([[0.0], x]), np.concatenate([[0.0], y]), where="post", label=_key(s))
    ax.set_xlabel(f"{metric} [s]")
    ax.set_ylabel("fraction of runs converged")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"CDF of {metric} per grid point")
    path = out_dir / f"cdf_{metric}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _median(s: dict, metric: str) -> tuple[float, float, float]:
    st = s["metrics"].get(metric)
    if not st or st["median"] is None:
        return math.nan, math.nan, math.nan
    lo, hi = st["ci95"]
    return st["median"], lo, hi


def plot_vs_param(summaries: list[dict], metric: str, param: str, out_dir: Path, plt) -> Path:
    fig, ax = plt.subplots(figsize=(7, 4.5))
    groups: dict[str, list[dict]] = {}
    for s in summaries:
        if param not in s["params"]:
            continue
        rest = {k: v for k, v in s["params"].items() if k != param}
        g = " ".join([s["scenario"], *(f"{k}={v}" for k, v in rest.items())])
        groups.setdefault(g, []).append(s)
    for g, ss in groups.items():
        ss = sorted(ss, key=lambda s: s["params"][param])
        x = np.array([s["params"][param] for s in ss], dtype=float)
        stats = np.array([_median(s, metric) for s in ss], dtype=float)
        m, lo, hi = stats[:, 0], stats[:, 1], stats[:, 2]
        hi = np.where(np.isinf(hi), np.nan, hi)
        (line,) = ax.plot(x, np.where(np.isinf(m), np.nan, m), "o-", label=g)
        ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2)
    ax.set_xlabel(param)
    ax.set_ylabel(f"median {metric} (95% CI)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    path = out_dir / f"{metric}_vs_{param.replace('.', '_')}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_heatmap(summaries: list[dict], metric: str, px: str, py: str, out_dir: Path, plt) -> Path:
    xs = sorted({s["params"][px] for s in summaries})
    ys = sorted({s["params"][py] for s in summaries})
    grid = np.full((len(ys), len(xs)), np.nan)
    for s in summaries:
        m, _, _ = _median(s, metric)
        grid[ys.index(s["params"][py]), xs.index(s["params"][px])] = (
            m if math.isfinite(m) else np.nan
        )
    fig, ax = plt.subplots(figsize=(6, 4.5))
    cmap = plt.get_cmap("viridis").with_extremes(bad="lightgrey")  # "never" or no runs
    im = ax.imshow(np.ma.masked_invalid(grid), origin="lower", aspect="auto", cmap=cmap)
    ax.set_xticks(range(len(xs)), [str(v) for v in xs])
    ax.set_yticks(range(len(ys)), [str(v) for v in ys])
    ax.set_xlabel(px)
    ax.set_ylabel(py)
    for (i, j), v in np.ndenumerate(grid):
        never = bool(np.isnan(v))
        text = "never" if never else f"{v:.3g}"
        ax.text(j, i, text, ha="center", va="center", color="k" if never else "w")
    fig.colorbar(im, ax=ax, label=f"median {metric}")
    path = out_dir / f"heatmap_{metric}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_sweep(rows: list[dict], out_dir: Path) -> list[Path]:
    """Every figure the sweep's grid supports (see the module docstring), as PNG files."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    summaries = summarize_points(rows)
    metrics = {m for r in rows for m in json.loads(r["metrics"] or "[]")}
    paths: list[Path] = []
    for m in ("converged_s",):
        if m in metrics:
            paths.append(plot_cdf(rows, summaries, m, out_dir, plt))
    axes = _numeric_axes(summaries)
    keys = [
        m for fam in sorted({family(s["scenario"]) for s in summaries}) for m in KEY_METRICS[fam]
    ]
    for m in keys:
        if m not in metrics:
            continue
        paths.extend(plot_vs_param(summaries, m, p, out_dir, plt) for p in axes)
        if (
            len(axes) == 2
            and all(set(s["params"]) == set(axes) for s in summaries)
            and len({s["scenario"] for s in summaries}) == 1
        ):
            paths.append(plot_heatmap(summaries, m, axes[0], axes[1], out_dir, plt))
    return paths
