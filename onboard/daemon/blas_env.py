"""Single-threaded BLAS for the daemon (issue 27: onboard footprint).

numpy's OpenBLAS starts a pool of one thread per core when it is loaded and may hand a product
to it; a daemon's matrices are 3x3 to 30x30, where the pool only adds threads, their buffers
and wake-ups. The daemon's entry point (``groundstation/cli.py``) therefore asks for one BLAS
thread before anything imports numpy, unless the user set the variable: an explicit
``OPENBLAS_NUM_THREADS`` or ``OMP_NUM_THREADS`` always wins. Only the ``agent`` subcommand is
affected; the simulator, planner and studies keep every core.

No numpy here: this module must be importable before numpy is.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
"""Read when OpenBLAS (numpy's BLAS) and an OpenMP runtime are loaded, never afterwards."""

DAEMON_SUBCOMMAND = "agent"


def daemon_blas_defaults(args: Sequence[str], environ: Mapping[str, str]) -> dict[str, str]:
    """The variables to add to ``environ`` for a command line ``args`` (``sys.argv[1:]``):
    one thread for each of :data:`BLAS_THREAD_VARIABLES` the user left unset when the
    subcommand is ``agent``, nothing otherwise."""
    if not args or args[0] != DAEMON_SUBCOMMAND:
        return {}
    return {name: "1" for name in BLAS_THREAD_VARIABLES if name not in environ}
