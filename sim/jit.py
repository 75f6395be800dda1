"""Compile the project's pure math modules with numba, unchanged.

Every formula of the agent core is written once, as a plain Python function over floats, tuples
and small numpy arrays, in the module that owns it (``onboard/``). The daemons run those
functions as they are, and never import numba. The compiled team engine of the headless runner
(:mod:`sim.team_kernel`) runs the *same* functions compiled: :func:`compiled` returns a module's
functions as numba ``njit`` dispatchers, built from each function's own code object with a
namespace in which every function it calls (of that module or of another project module) is the
compiled one too. numba resolves a compiled function's globals from that namespace.

Only functions *defined* in the module are compiled; classes, constants and other imports keep
their values (numba treats global constants as compile-time constants). The first call of each
dispatcher compiles it; ``cache=True`` keeps the machine code in ``__pycache__`` for the next
process.
"""

from __future__ import annotations

import sys
from types import FunctionType, ModuleType, SimpleNamespace
from typing import Any

PROJECT_PACKAGES = ("onboard", "sim", "messages")
_compiled: dict[str, dict[str, Any]] = {}


def _is_project(module_name: str) -> bool:
    return module_name.split(".", 1)[0] in PROJECT_PACKAGES


def _namespace(module: ModuleType) -> dict[str, Any]:
    """The module's globals with its own and other project functions replaced by compiled ones."""
    from numba import njit

    name = module.__name__
    if name in _compiled:
        return _compiled[name]
    ns: dict[str, Any] = dict(vars(module))
    _compiled[name] = ns  # before recursing: modules may import each other's functions
    for key, obj in vars(module).items():
        if not isinstance(obj, FunctionType) or not _is_project(obj.__module__):
            continue
        if obj.__module__ == name:
            copy = FunctionType(obj.__code__, ns, obj.__name__, obj.__defaults__, obj.__closure__)
            copy.__qualname__ = obj.__qualname__
            copy.__doc__ = obj.__doc__
            ns[key] = njit(cache=True)(copy)
        else:
            ns[key] = _namespace(sys.modules[obj.__module__])[obj.__name__]
    return ns


def compiled(module: ModuleType) -> SimpleNamespace:
    """``module``'s functions compiled (see the module docstring), as attributes."""
    ns = _namespace(module)
    return SimpleNamespace(
        **{
            k: v
            for k, v in ns.items()
            if isinstance(vars(module).get(k), FunctionType)
            and vars(module)[k].__module__ == module.__name__
        }
    )
