"""A sweep's results directory: one row per run in Parquet, written as the runs finish.

Layout of ``DIR``::

    sweep.json             the sweep (engine, grid points, seeds); --resume checks it
    rows/part-000000.parquet, part-000001.parquet, ...   one file per finished batch

Parquet (pyarrow) because a study is a table of a few dozen typed columns that people filter
and aggregate (pandas, polars, DuckDB read it as is), it is compressed, and a file per batch,
written to a temporary name and renamed, makes every finished batch durable: a killed sweep
keeps all of them and ``--resume`` skips their runs. Reading concatenates the parts (schemas
are unified: a column that was all null in one part takes the type of the others); a run
recorded more than once (a failure re-run by ``--resume``) counts by its last row.

Columns: ``point`` (grid point index), ``point_key``, ``scenario``, ``label``, ``params``
(JSON object), one ``param.NAME`` column per grid parameter, ``seed``, ``run_seed``,
``duration_s``, ``engine``, ``status`` (ok / failed / timeout), ``error``, ``wall_s``,
``cpu_s``, ``worker``, ``version``, ``git_commit``, ``metrics`` (JSON list of the metric
columns this run's scenario reports), then every metric of the scenario's
``--json``.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from sim.sweep.runs import RunStatus, RunTask

FIXED_COLUMNS = (
    "point",
    "point_key",
    "scenario",
    "label",
    "params",
    "seed",
    "run_seed",
    "duration_s",
    "engine",
    "status",
    "error",
    "wall_s",
    "cpu_s",
    "worker",
    "version",
    "git_commit",
    "metrics",
)
RUN_FIELDS = ("status", "error", "wall_s", "cpu_s", "worker")
"""What :func:`sim.sweep.runs.run_one` adds to the scenario's metrics."""
MANIFEST = "sweep.json"


def package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bearingflock")
    except PackageNotFoundError:
        return "unknown"


def git_commit() -> str:
    """The checkout's commit (``+dirty`` with local changes), ``unknown`` outside git."""
    here = Path(__file__).resolve().parent
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
        )
        if rev.returncode != 0:
            return "unknown"
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def make_row(
    task: RunTask, result: dict[str, object], label: str, version: str, commit: str
) -> dict[str, object]:
    """A table row of one run (``result`` is :func:`sim.sweep.runs.run_one`'s)."""
    params = dict(task.params)
    row: dict[str, object] = {
        "point": task.point,
        "point_key": task.point_key,
        "scenario": task.scenario,
        "label": label,
        "params": json.dumps(params, sort_keys=True),
        "seed": task.seed,
        "run_seed": task.run_seed,
        "duration_s": task.duration_s,
        "engine": task.engine,
        "version": version,
        "git_commit": commit,
    }
    row.update({f"param.{k}": v for k, v in params.items()})
    row.update(result)
    row["metrics"] = json.dumps([k for k in result if k not in RUN_FIELDS])
    return row


class ResultsDir:
    """Append-only row store of one sweep (see the module docstring)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.rows_dir = self.path / "rows"

    def exists(self) -> bool:
        return (self.path / MANIFEST).exists()

    def manifest(self) -> dict[str, object]:
        return json.loads((self.path / MANIFEST).read_text())

    def start(self, manifest: dict[str, object], resume: bool) -> None:
        """Create the directory; with ``resume`` the sweep must be the recorded one."""
        if self.exists():
            old = self.manifest()
            if not resume:
                raise FileExistsError(
                    f"{self.path} already holds a sweep: pass --resume to continue it or "
                    "choose another --out"
                )
            if old.get("points") != manifest.get("points") or old.get("engine") != manifest.get(
                "engine"
            ):
                raise ValueError(
                    f"{self.path} holds another sweep (grid points or engine differ); "
                    "--resume continues the same sweep only"
                )
            if old.get("seed_root") != manifest.get("seed_root"):
                raise ValueError(f"{self.path} was run with another seed_root")
        self.rows_dir.mkdir(parents=True, exist_ok=True)
        tmp = self.path / (MANIFEST + ".tmp")
        tmp.write_text(json.dumps(manifest, indent=1))
        os.replace(tmp, self.path / MANIFEST)

    def _parts(self) -> list[Path]:
        return sorted(self.rows_dir.glob("part-*.parquet")) if self.rows_dir.exists() else []

    def append(self, rows: list[dict[str, object]]) -> Path:
        """Write one batch of rows durably (temporary file, then rename)."""
        parts = self._parts()
        n = int(parts[-1].stem.split("-")[1]) + 1 if parts else 0
        out = self.rows_dir / f"part-{n:06d}.parquet"
        tmp = out.with_suffix(".tmp")
        pq.write_table(pa.Table.from_pylist(rows), tmp)
        os.replace(tmp, out)
        return out

    def read(self) -> list[dict[str, object]]:
        """Every run's last row, in (point, seed) order."""
        parts = self._parts()
        if not parts:
            return []
        table = pa.concat_tables([pq.read_table(p) for p in parts], promote_options="permissive")
        last: dict[tuple[str, int], dict[str, object]] = {}
        for row in table.to_pylist():
            last[(str(row["point_key"]), int(row["seed"]))] = row  # type: ignore[arg-type]
        return sorted(last.values(), key=lambda r: (r["point"], r["seed"]))  # type: ignore[arg-type, return-value]

    def done(self) -> set[tuple[str, int]]:
        """``(point_key, seed)`` of the runs that finished OK (``--resume`` skips them)."""
        return {
            (str(r["point_key"]), int(r["seed"]))  # type: ignore[arg-type]
            for r in self.read()
            if r["status"] == RunStatus.OK.value
        }


def row_metrics(row: dict[str, object]) -> list[str]:
    """The metric columns of this row's scenario."""
    return list(json.loads(str(row["metrics"]))) if row.get("metrics") else []


def json_row(row: dict[str, object]) -> dict[str, object]:
    """A row as ``--json`` prints it: ``seed``, ``params``, the metrics, then bookkeeping."""
    out: dict[str, object] = {
        "seed": row["seed"],
        "params": json.loads(str(row["params"])),
        "scenario": row["scenario"],
        "point": row["point"],
        "run_seed": row["run_seed"],
        "status": row["status"],
        "error": row["error"] or None,
    }
    out.update({m: row.get(m) for m in row_metrics(row)})
    out.update(wall_s=row["wall_s"], cpu_s=row["cpu_s"])
    return out
