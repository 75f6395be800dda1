"""IPOPT's derivative functions compiled to C, built once per problem shape and cached on disk.

casadi evaluates its symbolic (SX) functions in a virtual machine. At N = M = 10 one IPOPT
iteration evaluates the ~150 000 operations of the Hessian of the Lagrangian
(:mod:`groundstation.planner.hessian`) and the constraint Jacobian that way, about half of a
solve's time. casadi can also write those functions as C (``CodeGenerator``); compiled with
``-O1`` they run about 5x faster and a whole solve about 1.8x (docs/planner.md). The
compilation is slow (20-30 s with gcc at M = 10) but happens once per problem *shape*: the
numbers (setpoints, noise, radii) are parameters of the functions, so a library built for
N = 10, M = 10 serves every such problem. Libraries are cached under
:func:`default_cache_dir`, named by a hash of their C source, the compiler and its flags.

casadi is imported inside the functions so that importing this module stays cheap.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from groundstation.planner.problem import PlannerError

CFLAGS = ("-O1", "-fPIC", "-shared")
"""``-O0`` code is no faster than casadi's virtual machine; ``-O2`` compiles for minutes."""


def default_cache_dir() -> Path:
    """``$BEARINGFLOCK_CACHE_DIR/planner``, else ``$XDG_CACHE_HOME`` or ``~/.cache``."""
    root = os.environ.get("BEARINGFLOCK_CACHE_DIR")
    if root:
        return Path(root) / "planner"
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "bearingflock" / "planner"


def find_compiler() -> str:
    """The C compiler: ``$CC``, else ``cc`` or ``gcc`` on the PATH. Raises :class:`PlannerError`."""
    for name in (os.environ.get("CC"), "cc", "gcc"):
        if name and (path := shutil.which(name)):
            return path
    raise PlannerError(
        "compiled derivatives need a C compiler (set CC, or install gcc); "
        "plan without --compile to use casadi's interpreter"
    )


def library_path(source: str, compiler: str, cache_dir: Path) -> Path:
    """Where the library of ``source`` built by ``compiler`` lives in ``cache_dir``."""
    import casadi as ca

    key = "\n".join((ca.__version__, compiler, *CFLAGS, source))
    return cache_dir / f"planner_{hashlib.sha256(key.encode()).hexdigest()[:20]}.so"


def compile_functions(
    functions: Sequence[Any], *, cache_dir: Path | None = None, compiler: str | None = None
) -> list[Any]:
    """The casadi ``functions`` as compiled external functions with the same names and signatures.

    One shared library per function, so the compiler builds them side by side (at M = 10 the
    Hessian takes 20 s and the constraint Jacobian 17 s with gcc); the cache's are reused.
    Each build writes to a temporary name and is renamed when done, so concurrent planners
    never load a half-written file. Raises :class:`PlannerError` with the compiler's message if
    a build fails.
    """
    import casadi as ca

    cc = compiler or find_compiler()
    directory = cache_dir or default_cache_dir()
    libraries = []
    for f in functions:
        gen = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
        gen.add(f)
        source = gen.dump()
        libraries.append((f.name(), source, library_path(source, cc, directory)))
    _build_missing(libraries, cc, directory)
    try:
        return [ca.external(name, str(so)) for name, _, so in libraries]
    except RuntimeError:  # a damaged cache entry (a full disk, a killed copy): build it again
        for _, _, so in libraries:
            so.unlink(missing_ok=True)
        _build_missing(libraries, cc, directory)
        return [ca.external(name, str(so)) for name, _, so in libraries]


def _build_missing(libraries: list[tuple[str, str, Path]], cc: str, directory: Path) -> None:
    missing = [lib for lib in libraries if not lib[2].exists()]
    if not missing:
        return
    try:
        _build(missing, cc, directory)
    except OSError as exc:
        raise PlannerError(
            f"cannot build the planner's derivatives in {directory} ({exc}); "
            "set BEARINGFLOCK_CACHE_DIR to a writable directory"
        ) from None


def _build(missing: list[tuple[str, str, Path]], cc: str, directory: Path) -> None:
    """Compile each ``(name, source, library)`` side by side into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        builds = []
        for name, source, so in missing:
            c_file = Path(tmp) / f"{name}.c"
            c_file.write_text(source)
            built = Path(tmp) / so.name
            cmd = [cc, *CFLAGS, str(c_file), "-o", str(built), "-lm"]
            proc = subprocess.Popen(
                cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
            )
            builds.append((proc, built, so))
        errors = []
        for proc, built, so in builds:
            output, _ = proc.communicate()
            if proc.returncode == 0:
                os.replace(built, so)
            else:
                errors.append(" ".join(output.strip().splitlines()[-5:]))
        if errors:
            raise PlannerError(f"compiling the planner's derivatives failed: {errors[0]}")
