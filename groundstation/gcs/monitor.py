"""The monitor: one row per vehicle from MAVLink and Zenoh, alarms, a fleet line, a rich table.

:func:`snapshot` is pure: it folds a :class:`MavlinkState` and a :class:`ZenohState` into a plain
JSON-able dict at time ``now_s`` (``--once --json`` prints exactly this). Vehicles are matched
across the two links by ``sysid = agent_id + sysid_offset`` (the fleet's convention: vehicle ``i``
takes MAVLink system ``i + 1``). :func:`render` turns a snapshot into a rich table;
:class:`Monitor` owns the listeners and the live loop.

A row is red when its heartbeat is older than :data:`HEARTBEAT_LOST_S` or any alarm is active.
Alarms are the agent's own (``peer_lost:<id>``, ``rigidity_lost``, ``estimate_diverging``,
``failsafe``, ...) plus those the ground station raises itself: ``heartbeat_lost``,
``agent_lost`` (liveliness token gone, status older than :data:`AGENT_LOST_S`, or, once the
monitor has listened on Zenoh that long, an autopilot heard without any agent: one that died
before the monitor started),
``failsafe`` (HEARTBEAT system status CRITICAL or EMERGENCY) and ``battery_low``.

With a running paper 001 EKF (``ekf``: the summary of
:meth:`groundstation.gcs.ekf_loop.EkfLoop.summary`), each row also carries the EKF's view of
that vehicle (``ekf_sigma_p_m``: position standard deviation, ``ekf_disagreement_m``: distance
to the daemon's own estimate, ``ekf_alarm``: the loop's held disagreement alarm, which makes the
row red) and the snapshot the EKF's scale (``ekf``: RMS distance, its relative standard deviation
along the scale direction, the daemons' over the EKF's); the table shows two more columns.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from groundstation.gcs.mavlink_state import (
    MAV_STATE_CRITICAL,
    MavlinkState,
    SystemTelemetry,
)
from groundstation.gcs.zenoh_listener import AgentTelemetry, ZenohState
from messages.vocabulary import Alarm, alarm_kind

HEARTBEAT_LOST_S = 4.0
AGENT_LOST_S = 3.0
BATTERY_LOW_PCT = 20.0
RIGIDITY_MIN = 1e-6
"""An agent reporting a rigidity eigenvalue at or below this is counted as not rigid."""
DEFAULT_SYSID_OFFSET = 1


@dataclass(frozen=True)
class MonitorConfig:
    fleet: str = "alpha"
    sysid_offset: int = DEFAULT_SYSID_OFFSET
    heartbeat_lost_s: float = HEARTBEAT_LOST_S
    agent_lost_s: float = AGENT_LOST_S
    battery_low_pct: float = BATTERY_LOW_PCT


def _age(now_s: float, t_s: float | None) -> float | None:
    return None if t_s is None else max(0.0, now_s - t_s)


def _round(x: float | None, nd: int = 2) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


def vehicle_row(
    agent_id: int,
    sys: SystemTelemetry | None,
    agent: AgentTelemetry | None,
    now_s: float,
    config: MonitorConfig,
    expect_agent: bool = False,
) -> dict[str, Any]:
    """One vehicle's row: MAVLink values when the GCS hears the autopilot, else what its agent
    reports; estimator fields from the agent's latest status; alarms from both.
    ``expect_agent``: Zenoh has been listened to long enough that an agent that runs would have
    been heard (its liveliness token or a status), so a vehicle without one is ``agent_lost``."""
    status = agent.status if agent is not None else None
    status_age = _age(now_s, agent.status_s) if agent is not None else None
    alarms: set[str] = set()
    row: dict[str, Any] = {
        "id": agent_id,
        "sysid": agent_id + config.sysid_offset,
        "mavlink": sys is not None,
        "agent": agent is not None,
    }
    if sys is not None:
        hb_age = sys.heartbeat_age_s(now_s)
        row |= {
            "flavour": sys.flavour,
            "mode": sys.mode,
            "armed": sys.armed,
            "in_air": sys.in_air,
            "altitude_m": _round(sys.altitude_m),
            "speed_m_s": _round(sys.speed_m_s),
            "battery_pct": _round(sys.battery_pct, 1),
            "heartbeat_age_s": _round(hb_age if hb_age is not None else now_s - sys.first_seen_s),
            "loss_pct": _round(sys.loss_pct(), 1),
            "last_message_age_s": _round(now_s - sys.last_message_s),
            "statustext": sys.statustext,
        }
        if sys.system_status >= MAV_STATE_CRITICAL:
            alarms.add(Alarm.FAILSAFE)
    elif status is not None and status_age is not None:
        row |= {
            "flavour": None,
            "mode": status.autopilot_mode,
            "armed": status.armed,
            "in_air": status.in_air,
            "altitude_m": _round(status.altitude_m),
            "speed_m_s": _round(status.speed_m_s),
            "battery_pct": _round(status.battery_pct, 1),
            "heartbeat_age_s": _round(status.heartbeat_age_s + status_age),
            "loss_pct": None,
            "last_message_age_s": _round(status_age),
            "statustext": "",
        }
    else:
        row |= dict.fromkeys(
            ("flavour", "mode", "armed", "in_air", "altitude_m", "speed_m_s", "battery_pct"),
            None,
        )
        row |= {"heartbeat_age_s": None, "loss_pct": None, "last_message_age_s": None}
        row["statustext"] = ""
    hb = row["heartbeat_age_s"]
    if hb is None or hb > config.heartbeat_lost_s:
        alarms.add(Alarm.HEARTBEAT_LOST)
    battery = row["battery_pct"]
    if battery is not None and battery < config.battery_low_pct:
        alarms.add(Alarm.BATTERY_LOW)
    row |= _agent_fields(agent, status, status_age, config, alarms)
    if agent is None and expect_agent:
        alarms.add(Alarm.AGENT_LOST)
    row["alarms"] = sorted(alarms)
    row["red"] = bool(alarms)
    return row


def _agent_fields(
    agent: AgentTelemetry | None,
    status: Any,
    status_age: float | None,
    config: MonitorConfig,
    alarms: set[str],
) -> dict[str, Any]:
    if agent is None:
        return {"phase": None, "status_age_s": None, "alive": None}
    lost = agent.alive is False or (status_age is not None and status_age > config.agent_lost_s)
    if lost:
        alarms.add(Alarm.AGENT_LOST)
    out: dict[str, Any] = {
        "phase": None if status is None else status.phase,
        "status_age_s": _round(status_age),
        "alive": agent.alive,
    }
    if status is None:
        return out
    if not lost:
        alarms.update(status.alarms)
    a = status.agent
    out |= {
        "agent_mode": a.mode,
        "distance_hat_m": {
            str(j): _round(1.0 / x) for j, x in sorted(a.chi_hat_inv_m.items()) if x > 0
        },
        "chi_hat_inv_m": {str(j): _round(x, 4) for j, x in sorted(a.chi_hat_inv_m.items())},
        "e_index": _round(a.e_index, 6),
        "lambda_bar": _round(a.lambda_bar, 6),
        "scale_converged": a.scale_converged,
        "rigidity_eigenvalue": _round(a.rigidity_eigenvalue, 6),
        "neighbours": sorted(a.neighbours),
        "dropped": dict(status.dropped),
    }
    return out


def fleet_line(rows: Sequence[dict[str, Any]], zen: ZenohState | None) -> dict[str, Any]:
    """Vehicles up, rigid or not, and time to metric scale."""
    up = sum(
        1
        for r in rows
        if r["heartbeat_age_s"] is not None and Alarm.HEARTBEAT_LOST not in r["alarms"]
    )
    agents = [
        r for r in rows if r.get("agent_mode") is not None and Alarm.AGENT_LOST not in r["alarms"]
    ]
    eigs = [r["rigidity_eigenvalue"] for r in agents if r.get("rigidity_eigenvalue") is not None]
    # an agent's rigidity_lost (the same enum it raises: messages.vocabulary) is "not rigid"
    # whether or not its mode estimates a rigidity eigenvalue
    lost = any(alarm_kind(a) is Alarm.RIGIDITY_LOST for r in agents for a in r["alarms"])
    rigid: bool | None
    if lost:
        rigid = False
    elif not eigs:
        rigid = None
    else:
        rigid = all(e > RIGIDITY_MIN for e in eigs)
    scale_s = None
    if zen is not None and zen.scale_pending_s is not None and zen.scale_converged_s is not None:
        scale_s = _round(zen.scale_converged_s - zen.scale_pending_s, 1)
    return {
        "vehicles": len(rows),
        "up": up,
        "agents": len(agents),
        "red": sum(1 for r in rows if r["red"]),
        "rigid": rigid,
        "scale_converged": bool(agents) and all(r.get("scale_converged") for r in agents),
        "time_to_metric_scale_s": scale_s,
    }


def snapshot(
    mav: MavlinkState | None,
    zen: ZenohState | None,
    now_s: float,
    config: MonitorConfig,
    zenoh_listening_s: float | None = None,
    ekf: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The whole picture at ``now_s`` as a JSON-able dict (call it under the listeners' locks).
    ``zenoh_listening_s``: how long Zenoh has been listened to (``None``: unknown); from
    ``config.agent_lost_s`` on, a vehicle heard only on MAVLink is ``agent_lost``. ``ekf``: an
    EKF loop's summary (module doc), or ``None``."""
    systems = mav.systems if mav is not None else {}
    agents = zen.agents if zen is not None else {}
    ids = set(agents) | {s - config.sysid_offset for s in systems}
    expect = (
        zen is not None
        and zenoh_listening_s is not None
        and zenoh_listening_s >= config.agent_lost_s
    )
    rows = [
        vehicle_row(i, systems.get(i + config.sysid_offset), agents.get(i), now_s, config, expect)
        for i in sorted(ids)
    ]
    if ekf is not None:
        rows = [r | ekf_fields(ekf, r["id"]) for r in rows]
        for r in rows:
            r["red"] = r["red"] or r["ekf_alarm"]
    out: dict[str, Any] = {
        "fleet": config.fleet,
        "vehicles": rows,
        "fleet_status": fleet_line(rows, zen),
        "mavlink": None if mav is None else {"counters": dict(mav.counters)},
        "zenoh": None,
    }
    if zen is not None:
        out["zenoh"] = {
            "dropped": dict(zen.counters),
            "topics": dict(zen.topics),
            "last_error": zen.last_error,
            "sim_time_s": None if zen.clock is None else _round(zen.clock.t_s),
        }
    if ekf is not None:
        out["ekf"] = {
            k: _round(ekf.get(k), 3) for k in ("scale_m", "scale_rel_sigma", "daemon_scale_ratio")
        } | {"reference": ekf.get("reference"), "updates": ekf.get("updates")}
    return out


def ekf_fields(ekf: dict[str, Any], vehicle: int) -> dict[str, Any]:
    """The EKF columns of one vehicle's row from an EKF loop summary (module doc); the
    reference vehicle has no uncertainty of its own (``sigma`` 0: it defines the frame)."""
    pose = (ekf.get("poses") or {}).get(str(vehicle), {})
    return {
        "ekf_sigma_p_m": _round(pose.get("sigma_p_m"), 3),
        "ekf_disagreement_m": _round(pose.get("disagreement_m"), 2),
        "ekf_alarm": bool(pose.get("alarm", False)),
    }


# --- rendering ---------------------------------------------------------------------------------------
def _fmt(x: Any, spec: str = "", none: str = "-") -> str:
    if x is None:
        return none
    if isinstance(x, bool):
        return "yes" if x else "no"
    return format(x, spec) if spec else str(x)


def _link(r: dict[str, Any]) -> str:
    """Heartbeat age (s) and loss (%) in one cell, e.g. ``0.4s 2%``."""
    hb, loss = r["heartbeat_age_s"], r["loss_pct"]
    if hb is None:
        return "-"
    return f"{hb:.1f}s" + (f" {loss:.0f}%" if loss is not None else "")


def render(snap: dict[str, Any]) -> Any:
    """A rich renderable: the vehicle table, the fleet line and the counters."""
    from rich import box
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    table = Table(
        title=f"bearingflock fleet {snap['fleet']!r}",
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
        header_style="bold",
        title_justify="left",
    )
    for col, justify in (
        ("id", "right"),
        ("link", "left"),
        ("mode", "left"),
        ("arm", "left"),
        ("bat", "right"),
        ("alt", "right"),
        ("spd", "right"),
        ("phase", "left"),
        ("dist m", "left"),
        ("E", "right"),
        ("rig", "right"),
        ("nbrs", "left"),
        *((("EKF sd m", "right"), ("EKF-dmn m", "right")) if "ekf" in snap else ()),
        ("alarms", "left"),
    ):
        table.add_column(col, justify=justify, no_wrap=col != "alarms")  # type: ignore[arg-type]
    for r in snap["vehicles"]:
        dist = r.get("distance_hat_m") or {}
        table.add_row(
            str(r["id"]),
            _link(r),
            _fmt(r["mode"]),
            {None: "-", True: "ARM", False: "no"}[r["armed"]],
            _fmt(r["battery_pct"], ".0f"),
            _fmt(r["altitude_m"], ".1f"),
            _fmt(r["speed_m_s"], ".1f"),
            _fmt(r.get("phase"), none="no agent" if Alarm.AGENT_LOST in r["alarms"] else "-"),
            " ".join(f"{j}:{d:.1f}" for j, d in list(dist.items())[:3]) or "-",
            _fmt(r.get("e_index"), ".2g"),
            _fmt(r.get("rigidity_eigenvalue"), ".2g"),
            ",".join(str(j) for j in r.get("neighbours") or []) or "-",
            *(
                (_fmt(r.get("ekf_sigma_p_m"), ".2f"), _fmt(r.get("ekf_disagreement_m"), ".2f"))
                if "ekf" in snap
                else ()
            ),
            " ".join(r["alarms"] + (["ekf_disagreement"] if r.get("ekf_alarm") else [])) or "ok",
            style="bold red" if r["red"] else None,
        )
    f = snap["fleet_status"]
    rigid = {None: "rigidity unknown", True: "rigid", False: "NOT rigid"}[f["rigid"]]
    if f["time_to_metric_scale_s"] is not None:
        scale = f"metric scale after {f['time_to_metric_scale_s']:.1f} s"
    elif f["scale_converged"]:
        scale = "metric scale (converged before the monitor started)"
    else:
        scale = "metric scale: not yet" if f["agents"] else "metric scale: no agents"
    line = Text(
        f"vehicles up {f['up']}/{f['vehicles']}  agents {f['agents']}  {rigid}  {scale}",
        style="bold red" if f["red"] else "bold green",
    )
    parts: list[Any] = [table, line]
    late = [str(r["id"]) for r in snap["vehicles"] if Alarm.TICKS_LATE in r["alarms"]]
    if late:  # issue 29: say why the numbers are worse, and what to do
        parts.append(
            Text(
                f"ticks late on vehicle(s) {', '.join(late)}: this machine is too slow for the "
                "simulation speed, the estimates degrade (a lower --speedup, or fewer vehicles)",
                style="bold red",
            )
        )
    if "ekf" in snap:
        e = snap["ekf"]
        ekf_line = (
            f"EKF (paper 001, reference {e['reference']}): scale {_fmt(e['scale_m'], '.2f')} m "
            f"+-{_fmt(None if e['scale_rel_sigma'] is None else 100 * e['scale_rel_sigma'], '.1f')}%"
            f"  daemons/EKF {_fmt(e['daemon_scale_ratio'], '.3f')}  updates {_fmt(e['updates'])}"
        )
        parts.append(Text(ekf_line, style="cyan"))
    counters = []
    if snap.get("zenoh") is not None:
        z = snap["zenoh"]
        dropped = " ".join(f"{k}={v}" for k, v in sorted(z["dropped"].items())) or "none"
        clock = f"  sim t={z['sim_time_s']:.1f}s" if z["sim_time_s"] is not None else ""
        counters.append(f"zenoh dropped: {dropped}{clock}")
        if z["last_error"]:
            counters.append(f"  last: {z['last_error'][:100]}")
    if snap.get("mavlink") is not None:
        bad = " ".join(f"{k}={v}" for k, v in sorted(snap["mavlink"]["counters"].items()))
        counters.append(f"mavlink: {bad or 'clean'}")
    parts.extend(Text(c, style="yellow" if "=" in c else "dim") for c in counters)
    return Group(*parts)


# --- runtime -----------------------------------------------------------------------------------------
class Monitor:
    """Listeners + snapshot; ``mavlink``/``zenoh`` are started listeners or ``None``."""

    def __init__(
        self,
        config: MonitorConfig,
        mavlink: Any = None,
        zenoh: Any = None,
        clock: Callable[[], float] = time.monotonic,
        ekf: Callable[[], dict[str, Any]] | None = None,
    ) -> None:
        """``ekf``: returns a running EKF loop's summary (thread-safe), or ``None``."""
        self.config = config
        self.ekf = ekf
        self.mavlink = mavlink
        self.zenoh = zenoh
        self.clock = clock
        self.started_s = clock()

    def snapshot(self) -> dict[str, Any]:
        mav_lock = self.mavlink.lock if self.mavlink is not None else threading.Lock()
        zen_lock = self.zenoh.lock if self.zenoh is not None else threading.Lock()
        with mav_lock, zen_lock:
            return snapshot(
                self.mavlink.state if self.mavlink is not None else None,
                self.zenoh.state if self.zenoh is not None else None,
                self.clock(),
                self.config,
                self.clock() - self.started_s,
                self.ekf() if self.ekf is not None else None,
            )

    def live(self, refresh_hz: float = 4.0, stop: threading.Event | None = None) -> None:
        """Full-screen live table until Ctrl-C (or ``stop`` is set)."""
        from rich.live import Live

        stop = stop or threading.Event()
        with Live(render(self.snapshot()), screen=True, auto_refresh=False) as live:
            try:
                while not stop.wait(1.0 / refresh_hz):
                    live.update(render(self.snapshot()), refresh=True)
            except KeyboardInterrupt:
                pass
