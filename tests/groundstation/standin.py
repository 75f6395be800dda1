"""A stand-in for the onboard daemon's Zenoh side, to try the ground station without agents.

It holds the liveliness token ``bf/<fleet>/<id>/alive`` of each id, publishes a scripted
:class:`~messages.agent.VehicleStatus` on ``bf/<fleet>/<id>/status`` at ``rate_hz`` (the SfM
index ``E`` decays as ``e0 exp(-t / tau)``, the scale converges when it drops below
``converged_e``) and answers every :class:`~messages.command.FleetCommand` with a
:class:`~messages.command.CommandAck` (ids in ``reject`` refuse). Nothing here estimates
anything: the numbers are a script, not a simulation.

    python -m tests.groundstation.standin --fleet alpha --ids 0,1,2 --connect tcp/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import math
import signal
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from messages.agent import AgentStatus, VehicleStatus
from messages.codec import MessageError, decode, encode
from messages.command import ACK_TOPIC, COMMAND_TOPIC, CommandAck, FleetCommand
from messages.keys import STATUS_TOPIC, alive_key, key
from messages.vocabulary import Phase

PHASE_OF_ACTION = {
    "start": Phase.FLYING, "hold": Phase.HOLDING, "land": Phase.LANDING, "stop": Phase.STOPPED,
}  # fmt: skip


@dataclass
class StandinConfig:
    fleet: str
    ids: Sequence[int]
    rate_hz: float = 5.0
    e0: float = 1.0
    tau_s: float = 2.0
    converged_e: float = 0.05
    distance_m: float = 5.0
    reject: Sequence[int] = ()
    alarms: dict[int, list[str]] = field(default_factory=dict)


def scripted_status(
    cfg: StandinConfig, agent_id: int, t_s: float, seq: int, phase: Phase
) -> VehicleStatus:
    """The status agent ``agent_id`` publishes ``t_s`` seconds after start (pure)."""
    e = cfg.e0 * math.exp(-t_s / cfg.tau_s)
    others = [j for j in cfg.ids if j != agent_id]
    k = list(cfg.ids).index(agent_id)
    chi = {j: 1.0 / (cfg.distance_m * (1.0 + e)) for j in others}
    agent = AgentStatus(
        sender=agent_id,
        seq=seq,
        stamp_s=t_s,
        mode="sfm",
        p_hat_ned=(cfg.distance_m * k, 0.0, -2.5),
        yaw_hat_rad=0.0,
        chi_hat_inv_m=chi,
        e_index=e,
        lambda_bar=0.5,
        neighbours=others,
        rigidity_eigenvalue=0.25 if len(others) >= 2 else 0.0,
        scale_converged=e < cfg.converged_e,
    )
    return VehicleStatus(
        sender=agent_id,
        seq=seq,
        stamp_s=t_s,
        agent=agent,
        autopilot_mode="AUTO.LOITER",
        armed=False,
        in_air=False,
        altitude_m=0.0,
        speed_m_s=0.0,
        battery_pct=90.0,
        heartbeat_age_s=0.2,
        phase=phase,
        alarms=list(cfg.alarms.get(agent_id, [])),
    )


class Standin:
    """Runs :class:`StandinConfig` on an open Zenoh session until :meth:`stop`."""

    def __init__(self, session: Any, cfg: StandinConfig) -> None:
        self.session = session
        self.cfg = cfg
        self.phase = dict.fromkeys(cfg.ids, Phase.READY)
        self.commands: list[FleetCommand] = []
        self._stop = threading.Event()
        self._tokens = [
            session.liveliness().declare_token(alive_key(cfg.fleet, i)) for i in cfg.ids
        ]
        self._subs = [
            session.declare_subscriber(key(cfg.fleet, i, COMMAND_TOPIC), self._on_command)
            for i in cfg.ids
        ]
        self._thread: threading.Thread | None = None

    def _on_command(self, sample: Any) -> None:
        try:
            cmd = decode(sample.payload.to_bytes(), FleetCommand)
        except MessageError:
            return
        if cmd.target not in self.phase:
            return
        self.commands.append(cmd)
        ok = cmd.target not in self.cfg.reject
        if ok:
            self.phase[cmd.target] = PHASE_OF_ACTION[cmd.action]
        ack = CommandAck(
            sender=cmd.target,
            request_id=cmd.request_id,
            action=cmd.action,
            accepted=ok,
            detail="" if ok else "stand-in told to refuse",
        )
        self.session.put(key(self.cfg.fleet, cmd.target, ACK_TOPIC), encode(ack))

    def run(self) -> None:
        t0 = time.monotonic()
        seq = 0
        while not self._stop.is_set():
            t = time.monotonic() - t0
            for i in self.cfg.ids:
                status = scripted_status(self.cfg, i, t, seq, self.phase[i])
                try:
                    self.session.put(key(self.cfg.fleet, i, STATUS_TOPIC), encode(status))
                except Exception:  # the session was closed under us: stop quietly
                    return
            seq += 1
            self._stop.wait(1.0 / self.cfg.rate_hz)

    def start(self) -> Standin:
        self._thread = threading.Thread(target=self.run, name="gcs-standin", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for s in self._subs:
            s.undeclare()
        for tok in self._tokens:
            tok.undeclare()


def main(argv: Sequence[str] | None = None) -> None:
    from groundstation.gcs.commands import parse_ids
    from messages.transport import ZenohSettings, open_session

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fleet", default="alpha")
    ap.add_argument("--ids", default="0,1,2")
    ap.add_argument("--connect", action="append", default=[])
    ap.add_argument("--listen", action="append", default=[])
    ap.add_argument("--rate", type=float, default=5.0)
    ap.add_argument("--tau", type=float, default=2.0)
    ap.add_argument("--reject", default="")
    args = ap.parse_args(argv)
    cfg = StandinConfig(
        args.fleet,
        parse_ids(args.ids),
        rate_hz=args.rate,
        tau_s=args.tau,
        reject=parse_ids(args.reject) if args.reject else (),
    )
    session = open_session(ZenohSettings(listen=args.listen, connect=args.connect))
    standin = Standin(session, cfg)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    standin.start()
    print(f"stand-in agents {list(cfg.ids)} of fleet {cfg.fleet!r} running", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        standin.stop()
        session.close()


if __name__ == "__main__":
    main()
