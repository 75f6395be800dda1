"""Optional dependencies: which install extra brings each one, and one clear error without it.

The base install (``pip install bearingflock``) holds what an onboard daemon needs (numpy,
scipy, Zenoh, pymavlink, pyserial, msgspec, typer, rich, cryptography). Everything else is an
extra of ``pyproject.toml``; a code path that needs one imports it through :func:`require` (or
is reached through the ``bearingflock`` command, whose entry point turns a missing extra into
the same one-line message via :func:`missing_extra_message`), so that a vehicle's lean install
says ``pip install 'bearingflock[vision]'`` instead of a traceback.
"""

from __future__ import annotations

import importlib
from types import ModuleType

EXTRAS: dict[str, tuple[str, str]] = {
    "cv2": ("vision", "the camera pipeline and image rendering (OpenCV)"),
    "matplotlib": ("sim", "figures"),
    "numba": ("sim", "the compiled team engine of the headless runner"),
    "llvmlite": ("sim", "the compiled team engine of the headless runner"),
    "mcap": ("sim", "flight recordings (MCAP)"),
    "foxglove": ("sim", "the live 3D view (gcs view, Foxglove WebSocket)"),
    "pyarrow": ("sim", "sweep results (Parquet)"),
    "casadi": ("planner", "the landmark planner (IPOPT)"),
    "nlopt": ("planner", "the landmark planner's ISRES baseline"),
    "mavsdk": ("mavsdk", "the MAVSDK autopilot backend"),
    "dask": ("cluster", "the sweep's Dask executor"),
    "distributed": ("cluster", "the sweep's Dask executor"),
}
"""Top-level module name -> (install extra, what needs it)."""


class MissingExtraError(ModuleNotFoundError):
    """An optional dependency is not installed; the message names the extra that brings it."""


def missing_extra_message(module: str) -> str | None:
    """The one-line message for a missing ``module`` (any dotted name), or None when it is
    not an optional dependency of the project."""
    top = module.split(".", 1)[0]
    if top not in EXTRAS:
        return None
    extra, what = EXTRAS[top]
    return (
        f"{top} is not installed (needed for {what}): pip install 'bearingflock[{extra}]' "
        f"(or bearingflock[all])"
    )


def require(module: str) -> ModuleType:
    """Import ``module`` (an optional dependency, listed in :data:`EXTRAS`) and return it.

    Raises :class:`MissingExtraError` with :func:`missing_extra_message` when the package is
    not installed; an error raised *inside* an installed package propagates unchanged."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        message = missing_extra_message(exc.name or module)
        if message is None or (exc.name or "").split(".", 1)[0] != module.split(".", 1)[0]:
            raise
        raise MissingExtraError(message, name=exc.name) from None
