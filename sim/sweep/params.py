"""Sweep parameters: names a grid may vary and where each one goes in a scenario run.

A name is resolved in this order:

1. the options of ``bearingflock scenario``: ``bearing_noise_deg`` (degrees, 1 sigma),
   ``loss`` (probability in [0, 1)), ``latency`` (s);
2. a field of :class:`sim.runner.RunnerConfig` (``dt_s``, ``camera_rate_hz``,
   ``velocity_noise_m_s``, ``tau_v_s``, ``fov_deg``, ...);
3. a field of :class:`onboard.core.config.AgentConfig` (gains: ``k_formation``, ``nu_star``,
   ``consensus_k_p``, ``rigidity_eigen``, ...), the same for every vehicle; ``agent.NAME``
   forces this (e.g. ``agent.fov_deg`` for the cameras the rigidity layer models).
"""

from __future__ import annotations

import dataclasses
import math
import typing

import msgspec

ParamValue = bool | int | float | str

ALIASES: dict[str, str] = {
    "bearing_noise_deg": "bearing_noise_rad",
    "loss": "loss",
    "latency": "latency_s",
}
"""The ``bearingflock scenario`` options and the :class:`RunnerConfig` field each sets."""
RUNNER_FIXED = ("duration_s", "seed", "target_path", "range_pairs")
"""Runner fields the scenario itself sets (``--duration`` sets the duration)."""
AGENT_FIXED = ("agent_id", "n_agents", "edges", "p_hat0_ned", "yaw_hat0_rad", "seed")


def parse_value(text: str) -> ParamValue:
    """``"1"`` -> 1, ``"0.1"`` -> 0.1, ``"true"`` -> True, anything else stays a string."""
    t = text.strip()
    low = t.lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(t)
        except ValueError:
            pass
    return t


def _runner_fields() -> set[str]:
    from sim.runner import RunnerConfig

    return {f.name for f in dataclasses.fields(RunnerConfig)} - set(RUNNER_FIXED)


def _agent_fields() -> set[str]:
    from onboard.core.config import field_types

    return set(field_types()) - set(AGENT_FIXED)


def target(name: str) -> tuple[str, str]:
    """``(where, field)``: where is ``"runner"`` or ``"agent"``; :class:`ValueError` if unknown."""
    if name.startswith("agent."):
        f = name.removeprefix("agent.")
        if f in _agent_fields():
            return "agent", f
    elif name in ALIASES:
        return "runner", ALIASES[name]
    elif name in _runner_fields():
        return "runner", name
    elif name in _agent_fields():
        return "agent", name
    raise ValueError(
        f"unknown sweep parameter {name!r}: use one of {', '.join(ALIASES)}, a RunnerConfig "
        "field (sim/runner.py) or an AgentConfig field (onboard/core/config.py); see docs/sweep.md"
    )


def _hint(where: str, field: str) -> object:
    from onboard.core.config import field_types
    from sim.runner import RunnerConfig

    if where == "agent":
        return field_types()[field]
    return typing.get_type_hints(RunnerConfig)[field]


def normalize(name: str, value: ParamValue) -> ParamValue:
    """``value`` converted to its field's type (``loss=0`` is ``0.0``: the same grid point, and
    the compiled engine is not compiled again for an integer); :class:`ValueError` for what
    ``bearingflock scenario`` would reject or the field cannot hold."""
    where, f = target(name)
    num = isinstance(value, int | float) and not isinstance(value, bool)
    if name in ALIASES:
        if not (num and math.isfinite(value)):  # type: ignore[arg-type]
            raise ValueError(f"{name} must be a number, got {value!r}")
        value = float(value)
        if name in ("bearing_noise_deg", "latency") and value < 0:
            raise ValueError(f"{name} must be >= 0")
        if name == "loss" and not 0.0 <= value < 1.0:
            raise ValueError("loss must be in [0, 1)")
        return value
    try:
        out = msgspec.convert(value, _hint(where, f), strict=False)
    except msgspec.ValidationError as e:
        raise ValueError(f"{name}={value!r}: {e}") from None
    if not isinstance(out, bool | int | float | str):
        raise ValueError(f"{name}: only numbers, booleans and strings can be swept")
    return out


def split(params: dict[str, ParamValue]) -> tuple[dict[str, object], dict[str, object]]:
    """``(runner options, agent config overrides)`` of one grid point."""
    runner: dict[str, object] = {}
    agent: dict[str, object] = {}
    for name, value in params.items():
        where, f = target(name)
        v: object = math.radians(value) if name == "bearing_noise_deg" else value  # type: ignore[arg-type]
        (runner if where == "runner" else agent)[f] = v
    return runner, agent
