"""What a sweep runs: seeds x grid points, from the command line or a TOML sweep file.

A sweep is a list of *cases*; each case names one or more scenarios and parameters, a list
value being a grid axis. The grid of a case is the cartesian product of its axes (scenario
included); the sweep's grid points are the union over cases, in file order. Every grid point
runs every seed.

Seeds: ``--seeds A:B`` is inclusive (``0:999`` is 1000 seeds), ``3,7,11`` a list. A run's
random numbers depend only on its seed and its grid point, never on which worker ran it or
when: the run seed is the sweep seed itself by default (so ``bearingflock scenario NAME --seed
S`` reproduces any row), or, with a ``seed_root``, the first word of the
``numpy.random.SeedSequence(seed_root, spawn_key=(seed,))`` state. Inside a run every stream is
a ``SeedSequence`` child of the run seed (``numpy.random.default_rng([seed, k])``).
"""

from __future__ import annotations

import itertools
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim.sweep.params import ParamValue, normalize, parse_value

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ENGINES = ("cores", "compiled")
CASE_KEYS = ("scenario", "duration", "label")
"""Keys of a ``[[case]]`` table that are not scenario parameters."""
TOP_KEYS = ("seeds", "duration", "engine", "seed_root", "timeout_s", "case", "description")


class SpecError(ValueError):
    """A sweep specification that cannot run (the message says what to fix)."""


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"A:B"`` (inclusive) or ``"3,7,11"`` -> sorted unique non-negative seeds."""
    text = str(text).strip()
    if not text:
        raise SpecError("empty seed list")
    seeds: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        try:
            if ":" in part:
                a_s, b_s = part.split(":", 1)
                a, b = int(a_s), int(b_s)
                if b < a:
                    raise SpecError(f"seed range {part!r} is empty (end before start)")
                seeds.update(range(a, b + 1))
            else:
                seeds.add(int(part))
        except ValueError as e:
            if isinstance(e, SpecError):
                raise
            raise SpecError(f"bad seed {part!r}: use A:B (inclusive) or a,b,c") from None
    if min(seeds) < 0:
        raise SpecError("seeds must be >= 0")
    return tuple(sorted(seeds))


def run_seed(seed: int, seed_root: int | None) -> int:
    """The scenario seed of sweep seed ``seed`` (see the module docstring)."""
    if seed_root is None:
        return seed
    ss = np.random.SeedSequence(seed_root, spawn_key=(seed,))
    return int(ss.generate_state(1, dtype=np.uint32)[0])


@dataclass(frozen=True)
class GridPoint:
    """One scenario with one value per parameter."""

    scenario: str
    params: tuple[tuple[str, ParamValue], ...]
    duration_s: float
    label: str = ""

    @property
    def params_dict(self) -> dict[str, ParamValue]:
        return dict(self.params)

    @property
    def key(self) -> str:
        """Stable identity (rows and ``--resume`` match on it)."""
        return json.dumps(
            {"scenario": self.scenario, "params": self.params_dict, "duration_s": self.duration_s},
            sort_keys=True,
        )

    def title(self) -> str:
        p = " ".join(f"{k}={v}" for k, v in self.params)
        return self.label or (f"{self.scenario} {p}".strip())


@dataclass(frozen=True)
class Case:
    scenarios: tuple[str, ...]
    axes: tuple[tuple[str, tuple[ParamValue, ...]], ...] = ()
    duration_s: float | None = None
    label: str = ""


@dataclass(frozen=True)
class SweepSpec:
    """A whole sweep; :meth:`points` and :attr:`seeds` define its runs."""

    cases: tuple[Case, ...]
    seeds: tuple[int, ...]
    engine: str = "cores"
    duration_s: float | None = None
    seed_root: int | None = None
    timeout_s: float | None = None
    description: str = ""

    def points(self) -> list[GridPoint]:
        """Every grid point, cases in order, each case's product in axis order."""
        from sim.sweep.runs import default_duration

        out: list[GridPoint] = []
        seen: set[str] = set()
        for case in self.cases:
            names = [a for a, _ in case.axes]
            for sc in case.scenarios:
                dur = case.duration_s or self.duration_s or default_duration(sc)
                for combo in itertools.product(*(v for _, v in case.axes)):
                    gp = GridPoint(sc, tuple(zip(names, combo, strict=True)), dur, case.label)
                    if gp.key not in seen:
                        seen.add(gp.key)
                        out.append(gp)
        return out

    def to_json(self) -> dict[str, object]:
        """What the results directory's manifest keeps (``--resume`` checks it)."""
        return {
            "engine": self.engine,
            "seed_root": self.seed_root,
            "points": [json.loads(p.key) for p in self.points()],
        }


def _check_common(engine: str, duration_s: float | None, timeout_s: float | None) -> None:
    if engine not in ENGINES:
        raise SpecError(f"unknown engine {engine!r}; choose {' or '.join(ENGINES)}")
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise SpecError("duration must be a positive number of seconds")
    if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s > 0):
        raise SpecError("timeout must be a positive number of seconds")


def _check_case(case: Case, engine: str) -> Case:
    """``case`` with its values normalized; :class:`SpecError` for what cannot run."""
    from sim.sweep.runs import check_scenario

    axes = []
    try:
        for sc in case.scenarios:
            check_scenario(sc, engine)
        for name, values in case.axes:
            if not values:
                raise SpecError(f"parameter {name!r} has no values")
            norm = tuple(dict.fromkeys(normalize(name, v) for v in values))
            axes.append((name, norm))
    except SpecError:
        raise
    except ValueError as e:
        raise SpecError(str(e)) from None
    return Case(case.scenarios, tuple(axes), case.duration_s, case.label)


def parse_set(items: list[str]) -> tuple[tuple[str, tuple[ParamValue, ...]], ...]:
    """``["loss=0,0.1", "bearing_noise_deg=1"]`` -> grid axes."""
    axes: list[tuple[str, tuple[ParamValue, ...]]] = []
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or not name or not values.strip():
            raise SpecError(f"--set {item!r}: use NAME=V1,V2,...")
        if name in dict(axes):
            raise SpecError(f"--set {name} given twice")
        axes.append((name, tuple(parse_value(v) for v in values.split(","))))
    return tuple(axes)


def from_cli(
    scenarios: str,
    seeds: str,
    sets: list[str],
    engine: str,
    duration_s: float | None,
    seed_root: int | None = None,
    timeout_s: float | None = None,
) -> SweepSpec:
    """The sweep of ``bearingflock sweep SCENARIO[,SCENARIO...] --seeds ... --set ...``."""
    _check_common(engine, duration_s, timeout_s)
    names = tuple(s.strip() for s in scenarios.split(",") if s.strip())
    if not names:
        raise SpecError("no scenario given")
    case = _check_case(Case(names, parse_set(sets)), engine)
    return SweepSpec((case,), parse_seeds(seeds), engine, duration_s, seed_root, timeout_s)


def _as_values(name: str, raw: object) -> tuple[ParamValue, ...]:
    values = raw if isinstance(raw, list) else [raw]
    out: list[ParamValue] = []
    for v in values:
        if isinstance(v, bool | int | float | str):
            out.append(v)
        else:
            raise SpecError(f"parameter {name!r}: values must be numbers, booleans or strings")
    return tuple(out)


def from_toml(path: Path, seeds: str | None = None, engine: str | None = None) -> SweepSpec:
    """Read a sweep file (format in ``docs/sweep.md``); ``seeds``/``engine`` override it."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise SpecError(f"cannot read sweep file {path}: {e}") from None
    unknown = set(data) - set(TOP_KEYS)
    if unknown:
        raise SpecError(f"{path}: unknown keys {sorted(unknown)}; allowed: {list(TOP_KEYS)}")
    eng = engine or str(data.get("engine", "cores"))
    dur = data.get("duration")
    timeout = data.get("timeout_s")
    _check_common(eng, dur, timeout)
    raw_cases = data.get("case")
    if not isinstance(raw_cases, list) or not raw_cases:
        raise SpecError(f"{path}: no [[case]] tables")
    cases = []
    for i, rc in enumerate(raw_cases):
        if "scenario" not in rc:
            raise SpecError(f"{path}: case {i + 1} has no scenario")
        sc = rc["scenario"]
        names = tuple(sc) if isinstance(sc, list) else (str(sc),)
        axes = tuple((k, _as_values(k, v)) for k, v in rc.items() if k not in CASE_KEYS)
        case = Case(names, axes, rc.get("duration"), str(rc.get("label", "")))
        _check_common(eng, case.duration_s, None)
        cases.append(_check_case(case, eng))
    seed_text = seeds if seeds is not None else str(data.get("seeds", "0:9"))
    root = data.get("seed_root")
    return SweepSpec(
        tuple(cases),
        parse_seeds(seed_text),
        eng,
        dur,
        None if root is None else int(root),
        timeout,
        str(data.get("description", "")),
    )
