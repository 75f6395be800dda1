"""A worker thread that dies ends its process, never leaves it half alive (issue 23).

A daemon or simulator runs several threads (the flight sequence, the autopilot link's receive
and send loops, a renderer, a capture loop). Python's default for an exception that escapes a
thread is to print it and let the thread go: the process keeps running, looks alive, and does
nothing (a simulator whose loop died on ``EMFILE`` stood still with its clock frozen).

:class:`FatalThreads` replaces :data:`threading.excepthook` for one process: the first unhandled
exception in any thread is logged with its traceback (a :class:`PermanentError` without one),
kept as a one-line :attr:`message`, and
``on_fatal`` is called (the process's own stop: the daemon's stop event, the simulator's stop
flag) so that it shuts down in order and exits nonzero. If it has not exited
``grace_s`` later (its main loop is itself stuck), the process exits at once with code
:data:`FATAL_EXIT_CODE`.
"""

from __future__ import annotations

import errno
import logging
import os
import sys
import threading
from collections.abc import Callable
from typing import Any


class PermanentError(Exception):
    """An error of the environment or the configuration that no retry cures (a port another
    process holds): a thread raises it to end its process with its one-line message and no
    traceback, as the command line's own errors do. Raise it ``from`` the cause."""


FATAL_EXIT_CODE = 70
"""Exit code of a process ended by the grace timer (EX_SOFTWARE)."""

log = logging.getLogger(__name__)


class FatalThreads:
    """Install with :meth:`install`; :attr:`message` is ``""`` until a thread dies."""

    def __init__(
        self,
        on_fatal: Callable[[str], None],
        grace_s: float = 15.0,
        exit_now: Callable[[int], None] = os._exit,
    ) -> None:
        self.on_fatal = on_fatal
        self.grace_s = grace_s
        self._exit_now = exit_now
        self.message = ""
        self._lock = threading.Lock()
        self._previous: Any = None
        self._timer: threading.Timer | None = None

    def install(self) -> FatalThreads:
        self._previous = threading.excepthook
        threading.excepthook = self._hook
        return self

    def uninstall(self) -> None:
        """Restore the previous hook and cancel the grace timer (the process stopped in time)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._previous is not None:
            threading.excepthook = self._previous
            self._previous = None

    def _hook(self, args: threading.ExceptHookArgs) -> None:
        if args.exc_type is SystemExit:
            return  # a thread that chose to end
        name = args.thread.name if args.thread is not None else "?"
        permanent = isinstance(args.exc_value, PermanentError)
        text = (str(args.exc_value) if permanent
                else f"thread {name!r} died: {args.exc_type.__name__}: {args.exc_value}")  # fmt: skip
        with self._lock:
            first = not self.message
            if first:
                self.message = text
        trace = None if permanent else (args.exc_type, args.exc_value, args.exc_traceback)
        log.critical("%s (stopping the process)", text, exc_info=trace)  # type: ignore[arg-type]
        if not first:
            return
        self._timer = threading.Timer(self.grace_s, self._give_up)
        self._timer.daemon = True
        self._timer.start()
        try:
            self.on_fatal(text)
        except Exception:  # the stop itself failed: only the timer is left
            log.exception("stopping after a dead thread failed")

    def _give_up(self) -> None:
        sys.stderr.write(f"error: {self.message}; not stopped after {self.grace_s:g} s, exiting\n")
        sys.stderr.flush()
        self._exit_now(FATAL_EXIT_CODE)


PERMANENT_ERRNOS = frozenset({errno.EADDRINUSE, errno.EADDRNOTAVAIL, errno.EACCES, errno.EINVAL})
"""Errors of opening a socket that retrying does not cure (a port another process holds, an
address not on this host, a privileged port, a bad address)."""


def is_permanent(exc: BaseException) -> bool:
    """Whether ``exc`` (or what caused it) is an error no retry can cure: an ``OSError`` with
    an errno in :data:`PERMANENT_ERRNOS`, or a ``ValueError``/``OverflowError`` (a malformed
    address). A retry loop re-raises such an error instead of retrying forever."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in PERMANENT_ERRNOS:
            return True
        if isinstance(e, (ValueError, OverflowError)) and not isinstance(e, UnicodeError):
            return True
        e = e.__cause__ or e.__context__
    return False
