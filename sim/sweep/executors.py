"""The sweep's engine seam: a :class:`concurrent.futures.Executor`, chosen by name.

* ``local``: every batch in this process, one after the other (debugging, profiling);
* ``processes`` / ``processes:N``: a process pool on this machine (the default; N defaults to
  the number of CPUs);
* ``dask``: the Dask scheduler at ``DASK_SCHEDULER_ADDRESS`` when set, else a Dask
  ``LocalCluster`` of one single-threaded worker process per CPU; ``dask:N`` a LocalCluster of
  N workers;
* ``dask://HOST:PORT``: a running Dask distributed scheduler (``tcp://HOST:PORT``).

Dask (``pip install -e '.[cluster]'``) is imported only for the ``dask`` executors. Its
workers need this package importable (installed, or ``PYTHONPATH``).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

DASK_ENV = "DASK_SCHEDULER_ADDRESS"


class ExecutorError(ValueError):
    """An executor name that does not parse, or a cluster that cannot be reached."""


class InlineExecutor(Executor):
    """Runs each submitted call at once in the caller's thread (``--executor local``)."""

    def submit(self, fn: Callable, /, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as e:
            fut.set_exception(e)
        return fut


def _ignore_sigint() -> None:
    """Pool workers leave Ctrl-C to the client, which stops them (no traceback per worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@dataclass(frozen=True)
class ExecutorChoice:
    """A parsed ``--executor``: ``kind`` is local, processes, dask-local or dask-remote."""

    kind: str
    workers: int | None = None
    address: str | None = None

    def describe(self) -> str:
        if self.kind == "dask-remote":
            return f"dask scheduler {self.address}"
        if self.kind == "local":
            return "local (this process)"
        return f"{self.kind} ({self.workers} workers)"


def _count(text: str, name: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise ExecutorError(f"--executor {name}: the worker count must be an integer") from None
    if n < 1:
        raise ExecutorError(f"--executor {name}: at least 1 worker")
    return n


def parse_executor(name: str | None, env: dict[str, str] | None = None) -> ExecutorChoice:
    """``None`` is ``dask`` when ``DASK_SCHEDULER_ADDRESS`` is set, else ``processes``."""
    env = dict(os.environ) if env is None else env
    cpus = os.cpu_count() or 1
    if name is None:
        name = "dask" if env.get(DASK_ENV) else "processes"
    name = name.strip()
    head, _, arg = name.partition(":")
    if name == "local":
        return ExecutorChoice("local", 1)
    if head == "processes":
        return ExecutorChoice("processes", _count(arg, name) if arg else cpus)
    if name.startswith("dask://"):
        hostport = name.removeprefix("dask://")
        if ":" not in hostport:
            raise ExecutorError(f"--executor {name}: use dask://HOST:PORT")
        return ExecutorChoice("dask-remote", address=f"tcp://{hostport}")
    if head == "dask":
        if arg:
            return ExecutorChoice("dask-local", _count(arg, name))
        if env.get(DASK_ENV):
            return ExecutorChoice("dask-remote", address=env[DASK_ENV])
        return ExecutorChoice("dask-local", cpus)
    raise ExecutorError(
        f"unknown executor {name!r}: use local, processes[:N], dask[:N] or dask://HOST:PORT"
    )


@contextmanager
def open_executor(choice: ExecutorChoice) -> Iterator[tuple[Executor, int]]:
    """``(executor, number of parallel slots)``; shuts it down (and any cluster) on exit."""
    if choice.kind == "local":
        yield InlineExecutor(), 1
        return
    if choice.kind == "processes":
        assert choice.workers is not None
        ctx = multiprocessing.get_context("spawn")  # no fork of the progress bar's thread
        pool = ProcessPoolExecutor(choice.workers, mp_context=ctx, initializer=_ignore_sigint)
        try:
            yield pool, choice.workers
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ExecutorError(
            "the dask executors need dask[distributed]: pip install -e '.[cluster]'"
        ) from None
    if choice.kind == "dask-local":
        cluster = LocalCluster(
            n_workers=choice.workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
        )
        client = Client(cluster)
    else:
        cluster = None
        try:
            client = Client(choice.address, timeout=10)
        except OSError as e:
            raise ExecutorError(f"cannot reach the dask scheduler {choice.address}: {e}") from None
    try:
        slots = sum(client.nthreads().values()) or 1
        yield client.get_executor(pure=False), slots
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
