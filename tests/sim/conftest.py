"""A bench that drives a real :class:`SimServer` step by step from the test thread.

The server's sockets are bound but its loop is not started: the test feeds messages straight to
the autopilots (after a real pack/parse round trip through pymavlink, so the messages carry a
source system and component like on the wire), calls :meth:`SimServer.tick` itself, and reads
what each autopilot sent. Deterministic and fast; the socket paths have their own tests.
"""

from __future__ import annotations

import math
from typing import Any

import pytest

from sim.server import SimConfig, SimServer
from sim.world import grid_layout

GCS_SYSID = 245
GCS_COMPID = 190


class Bench:
    def __init__(self, flavour: str = "px4", n: int = 2, **kwargs: Any) -> None:
        p, yaw = grid_layout(n, 5.0)
        transport = kwargs.pop("transport", "udp")
        # every socket on a port the kernel picks: no race with other tests (issue 23)
        self.server = SimServer(
            SimConfig(
                p,
                yaw,
                flavour=flavour,
                transport=transport,
                client_base=9,  # the vehicles send to the discard port: nobody listens
                gcs_port=None,
                bind_base=0,
                tcp_base=0,
                **kwargs,
            )
        )
        self.aps = self.server.autopilots
        self.dialect = self.aps[0].dialect
        self.outbox: list[list[Any]] = [[] for _ in range(n)]
        for ap, box in zip(self.aps, self.outbox, strict=True):
            ap.send = box.append
        self._tx = self.dialect.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
        self._rx = self.dialect.MAVLink(None, srcSystem=0, srcComponent=0)

    @property
    def t(self) -> float:
        return self.server.world.t_s

    def close(self) -> None:
        self.server.close()

    def deliver(self, i: int, msg: Any) -> None:
        """Send ``msg`` to vehicle ``i`` as a client would (wire round trip)."""
        buf = msg.pack(self._tx)
        self._tx.seq = (self._tx.seq + 1) % 256
        parsed = self._rx.parse_buffer(buf)
        assert parsed and len(parsed) == 1
        self.aps[i].handle(parsed[0])

    def command(self, i: int, command: int, *params: float, target: int | None = None) -> int:
        """COMMAND_LONG to vehicle ``i``; returns the ACK result (or -1 if no ACK)."""
        p = [*params, *([0.0] * (7 - len(params)))]
        tgt = self.aps[i].sys_id if target is None else target
        self.outbox[i].clear()
        self.deliver(i, self.dialect.MAVLink_command_long_message(tgt, 1, command, 0, *p))
        acks = [m for m in self.outbox[i] if m.get_type() == "COMMAND_ACK"]
        if not acks:
            return -1
        assert acks[-1].command == command
        assert acks[-1].target_system == GCS_SYSID and acks[-1].target_component == GCS_COMPID
        return int(acks[-1].result)

    def setpoint(
        self,
        i: int,
        v: tuple[float, float, float],
        yaw_rate: float = 0.0,
        frame: int = 8,
        mask: int = 1479,
        yaw: float = 0.0,
        target: int | None = None,
    ) -> None:
        tgt = self.aps[i].sys_id if target is None else target
        msg = self.dialect.MAVLink_set_position_target_local_ned_message(
            0, tgt, 1, frame, mask, 0, 0, 0, v[0], v[1], v[2], 0, 0, 0, yaw, yaw_rate
        )
        self.deliver(i, msg)

    def run(self, seconds: float, every: float | None = None, action: Any = None) -> None:
        """Advance ``seconds`` of simulation time; call ``action()`` every ``every`` seconds."""
        steps = round(seconds / self.server.config.dt_s)
        period = None if every is None else max(1, round(every / self.server.config.dt_s))
        for k in range(steps):
            if period is not None and k % period == 0:
                action()
            self.server.tick()

    def run_until(
        self, pred: Any, timeout_s: float, every: float | None = None, action: Any = None
    ) -> float:
        """Advance until ``pred()`` holds; returns the simulation time it took (fails on timeout)."""
        t0 = self.t
        dt = self.server.config.dt_s
        period = None if every is None else max(1, round(every / dt))
        k = 0
        while not pred():
            if self.t - t0 > timeout_s:
                raise AssertionError(f"condition not reached within {timeout_s} s")
            if period is not None and k % period == 0:
                action()
            self.server.tick()
            k += 1
        return self.t - t0

    def sent(self, i: int, kind: str) -> list[Any]:
        return [m for m in self.outbox[i] if m.get_type() == kind]

    def texts(self, i: int) -> list[str]:
        return [_text(m.text) for m in self.sent(i, "STATUSTEXT")]


def _text(raw: Any) -> str:
    return raw.decode() if isinstance(raw, bytes) else str(raw)


@pytest.fixture
def bench_factory():
    made: list[Bench] = []

    def make(flavour: str = "px4", n: int = 2, **kwargs: Any) -> Bench:
        b = Bench(flavour, n, **kwargs)
        made.append(b)
        return b

    yield make
    for b in made:
        b.close()


NAN = math.nan
