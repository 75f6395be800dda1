"""The daemon's CPU split (onboard/daemon/profile.py, issue 27): timed sections land in their
category, threads by name, and the categories add up to the threads' CPU."""

from __future__ import annotations

import threading
import time

from onboard.daemon.profile import CATEGORIES, CpuSplit, instrument, thread_cpu_s


def _spin(cpu_s: float) -> None:
    t0 = time.thread_time()
    while time.thread_time() - t0 < cpu_s:
        pass


class _Layer:
    def step(self) -> None:
        _spin(0.05)


class _Core:
    def __init__(self) -> None:
        self.rigidity = _Layer()

    def step(self) -> None:
        _spin(0.05)
        self.rigidity.step()


class _Peers:
    def decode(self) -> None:
        _spin(0.03)

    def encode(self) -> None:
        _spin(0.02)


def test_sections_and_threads_are_split_by_category() -> None:
    split = CpuSplit()
    core, peers = _Core(), _Peers()
    instrument(split, core, peers)
    for _ in range(2):
        core.step()  # 0.05 core + 0.05 rigidity each
    peers.encode()
    done, release = threading.Barrier(3), threading.Event()

    def work(fn: object) -> None:
        fn()  # type: ignore[operator]
        done.wait()
        release.wait()  # alive while the split reads /proc (as the daemon's threads are)

    rx = threading.Thread(target=work, args=(lambda: _spin(0.06),), name="autopilot-rx")
    callback = threading.Thread(target=work, args=(lambda: (_spin(0.02), peers.decode()),),
                                name="Thread-1 (pyo3-closure)")  # fmt: skip
    for t in (rx, callback):
        t.start()
    done.wait()
    s = split.split()
    release.set()
    for t in (rx, callback):
        t.join()
    cpu = s["cpu_s"]
    assert set(cpu) == set(CATEGORIES)
    tick = 0.011  # /proc's CPU times count in clock ticks (10 ms)
    assert abs(cpu["rigidity"] - 0.10) < tick
    assert abs(cpu["core"] - 0.10) < tick
    assert abs(cpu["codec"] - 0.05) < tick  # the decode in the callback + the encode
    assert abs(cpu["mavlink"] - 0.06) < tick
    assert abs(cpu["zenoh"] - 0.02) < 2 * tick  # the callback's time less its decode
    assert abs(sum(s["fraction"].values()) - 1.0) < 1e-9
    assert s["total_cpu_s"] >= 0.2 - 2 * tick


def test_thread_cpu_is_per_thread() -> None:
    main = threading.main_thread().native_id
    before = thread_cpu_s()[main]
    _spin(0.05)
    assert thread_cpu_s()[main] - before >= 0.05 - 0.011
