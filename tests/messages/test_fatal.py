"""A worker thread that dies stops its process (messages/fatal.py, issue 23 defect 5)."""

from __future__ import annotations

import errno
import threading
import time

from messages.fatal import FatalThreads, PermanentError, is_permanent


def _die() -> None:
    raise OverflowError("bind(): port must be 0-65535.")


def test_a_dead_thread_calls_the_stop_once_and_names_the_thread() -> None:
    stopped: list[str] = []
    exits: list[int] = []
    fatal = FatalThreads(stopped.append, grace_s=30.0, exit_now=exits.append).install()
    try:
        for name in ("autopilot-rx", "flight-0"):
            t = threading.Thread(target=_die, name=name)
            t.start()
            t.join()
    finally:
        fatal.uninstall()
    assert stopped == ["thread 'autopilot-rx' died: OverflowError: bind(): port must be 0-65535."]
    assert fatal.message == stopped[0]
    assert threading.excepthook is not fatal._hook
    time.sleep(0.05)
    assert exits == []  # uninstalled in time: the grace timer was cancelled


def test_a_process_that_does_not_stop_in_time_exits_anyway() -> None:
    exits: list[int] = []
    fatal = FatalThreads(lambda _t: None, grace_s=0.05, exit_now=exits.append).install()
    try:
        t = threading.Thread(target=_die, name="render")
        t.start()
        t.join()
        deadline = time.monotonic() + 5.0
        while not exits and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        fatal.uninstall()
    assert exits == [70]


def test_permanent_errors() -> None:
    in_use = OSError(errno.EADDRINUSE, "Address already in use")
    wrapped = RuntimeError("cannot open 'udpin:127.0.0.1:5'")
    wrapped.__cause__ = in_use
    assert is_permanent(in_use) and is_permanent(wrapped)
    assert is_permanent(OverflowError("port must be 0-65535"))
    assert not is_permanent(TimeoutError("no heartbeat"))
    assert not is_permanent(OSError(errno.ECONNREFUSED, "refused"))


def test_a_permanent_error_ends_the_process_with_its_own_line_and_no_traceback(caplog) -> None:
    stopped: list[str] = []

    def _give_up() -> None:
        raise PermanentError("cannot open 'udpin:127.0.0.1:9': Address already in use")

    fatal = FatalThreads(stopped.append, exit_now=lambda _c: None).install()
    try:
        t = threading.Thread(target=_give_up, name="flight-0")
        t.start()
        t.join()
    finally:
        fatal.uninstall()
    assert stopped == ["cannot open 'udpin:127.0.0.1:9': Address already in use"]
    assert [r.exc_info for r in caplog.records if r.name == "messages.fatal"] == [None]
