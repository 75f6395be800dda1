"""``bearingflock demo``: a whole simulated mission on one machine, with no setup.

It plans a formation, starts the MAVLink simulator and one onboard daemon per vehicle as
separate processes (Zenoh in peer mode on loopback, no router), lets the daemons take off and
fly paper 000's bearing-constrained active scale estimation, shows a live table, lands
everything, and reports how fast the team found its metric scale and how well it holds the
formation, with plots.

The demo is the evaluator: it is the only place that reads the simulator's ground truth
(``bf/<fleet>/<id>/truth``), to score the agents' estimates. The agents never see it.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from messages.agent import VehicleStatus
from messages.codec import MessageError, decode, encode
from messages.command import COMMAND_TOPIC, FleetCommand
from messages.keys import key
from messages.sim import Truth
from messages.transport import TransportError, ZenohSettings, loopback_endpoint, open_session
from messages.vocabulary import Alarm, Phase
from onboard.daemon.config import MIN_MAINTENANCE_AGENTS
from onboard.geometry import FloatArray, IntArray, bearings_body
from onboard.graph import complete_graph, normalize_edges, reciprocal_pairs
from onboard.rigidity.angle import weighted_angle_rigidity_eigenvalue
from onboard.rigidity.bearing import ibr_r3s1
from onboard.rigidity.weights import SensingModel

LANDING_TIMEOUT_S = 30.0
"""Simulation seconds the vehicles get to land after the mission."""
WALL_SLACK = 2.0
"""The demo also stops after ``WALL_SLACK x`` the wall time its simulation time should take
(plus :data:`STARTUP_WALL_S`): a simulator slower than its speed-up, or stalled, cannot hang it."""
STARTUP_WALL_S = 30.0
CAMERA_STALE_FRAMES = 4.0
"""Camera bearings: the daemons hold when their newest frame is older than this many frame
periods (at least the fleet default, 0.5 s). Rendered frames come 5-10 per simulation second
and 0.05-0.15 s late, and the renderer drops a frame when it falls behind: with the default
0.5 s, one dropped frame at 5 Hz stopped the vehicle, and the holds stalled the scale estimate
(docs/vision.md, "Flying on camera bearings")."""
CAMERA_FOV_DEG = 360.0
CAMERA_RANGE_M = 80.0
"""The simulator's virtual camera in the demo (all-round, long range); the rigidity layer's
sensing model (``[rigidity] fov_deg, range_m``) is the same camera."""
LAMBDA_SAFE = 0.2
"""The rigidity maintenance's safe level (paper 003 scenarios' value) ..."""
LAMBDA_SAFE_FRACTION = 0.5
"""... or this fraction of the planned formation's weighted eigenvalue, if that is lower: the
barrier must not push the team away from the formation it is told to hold (a ring of 4 at
mixed heights is nearly flat: 0.088)."""
LAMBDA_MIN_FRACTION = 0.1
"""``lambda_min`` (where the barrier grows without bound) as a fraction of ``lambda_safe``."""
SITL_START_S = 90.0
"""ArduCopter SITL: simulation seconds from the first truth sample to the mission start (every
vehicle flying) before the demo gives up. SITL refuses to arm for about 24 s after boot
("Arm: Gyros inconsistent"), then the take-off to 5 m takes about 6.5 s."""
SITL_LANDING_TIMEOUT_S = 60.0
"""ArduCopter lands at 0.5 m/s below 10 m (and disarms 2 s after touchdown)."""
LANDED_HEIGHT_M = 0.2
SCALE_TOLERANCE = 0.02
"""Relative distance error below which an SfM edge counts as having the metric scale."""


@dataclass(frozen=True)
class FormationPlan:
    """Desired formation, sensing graph and start layout of a demo."""

    p_ned: FloatArray
    yaw_rad: FloatArray
    edges: IntArray
    p_start_ned: FloatArray
    yaw_start_rad: FloatArray

    @property
    def n(self) -> int:
        return len(self.p_ned)


def plan_formation(n: int, seed: int = 0) -> FormationPlan:
    """A ring of ``n`` vehicles at mixed heights, cameras toward the centre, a directed sensing
    graph with reciprocal pairs ``(2k, 2k+1)`` and chords ``i -> i+1, i+2``, IBR in R^3 x S^1.
    Vehicles start displaced from it, so the formation controller has work to do."""
    if n < 3:
        raise ValueError(f"a demo needs at least 3 vehicles, got {n}")
    rng = np.random.default_rng(seed)
    radius = max(4.0, 0.9 * n)
    ang = 2.0 * np.pi * np.arange(n) / n
    p = np.stack(
        [radius * np.cos(ang), radius * np.sin(ang), -5.0 - 1.5 * (np.arange(n) % 3) / 2.0], axis=1
    )
    yaw = np.arctan2(-p[:, 1], -p[:, 0])
    pairs = [(2 * k, 2 * k + 1) for k in range(n // 2)]
    edges = [e for a, b in pairs for e in ((a, b), (b, a))]
    edges += [(i, (i + s) % n) for i in range(n) for s in (1, 2)]
    e = normalize_edges(edges)
    if not ibr_r3s1(p, yaw, e).is_rigid:
        e = normalize_edges([(i, j) for i in range(n) for j in range(n) if i != j])
    offset = rng.uniform(0.6, 1.0, size=n)[:, None] * np.stack(
        [np.cos(ang + 1.3), np.sin(ang + 1.3), np.zeros(n)], axis=1
    )
    return FormationPlan(p, yaw, e, p + offset, yaw + rng.uniform(-0.2, 0.2, size=n))


def _formation_toml(p: FloatArray, yaw: FloatArray, edges: IntArray | None, name: str) -> str:
    lines = [f'name = "{name}"', ""]
    for k in range(len(p)):
        lines += [
            "[[agent]]",
            f"id = {k}",
            "position_ned = [" + ", ".join(f"{x:.3f}" for x in p[k]) + "]",
            f"yaw_deg = {math.degrees(yaw[k]):.2f}",
            "",
        ]
    for i, j in edges if edges is not None else []:
        lines += ["[[edge]]", f"from = {i}", f"to = {j}", ""]
    return "\n".join(lines)


def demo_lambda_safe(plan: FormationPlan) -> float:
    """The demo's ``[rigidity] lambda_safe``: :data:`LAMBDA_SAFE`, or :data:`LAMBDA_SAFE_FRACTION`
    of the planned formation's weighted angle rigidity eigenvalue (all-round camera, every
    vehicle a candidate) if that is lower."""
    model = SensingModel(CAMERA_FOV_DEG, CAMERA_RANGE_M)
    lam, _ = weighted_angle_rigidity_eigenvalue(
        plan.p_ned, plan.yaw_rad, complete_graph(len(plan.p_ned)), model
    )
    return min(LAMBDA_SAFE, LAMBDA_SAFE_FRACTION * float(lam))


@dataclass(frozen=True)
class DemoPorts:
    zenoh: int
    mavlink: int
    gcs: int


def write_demo_files(
    out: Path,
    plan: FormationPlan,
    ports: DemoPorts,
    fleet: str,
    mode: str,
    loss: float = 0.0,
    rigidity: bool = True,
    sitl_instance: int | None = None,
    localization: str = "paper000",
) -> Path:
    """Formation, start layout and fleet files for the simulator and the daemons; ``loss`` is
    the fraction of peer messages every daemon drops on purpose (``zenoh.inject_loss``),
    ``rigidity`` turns paper 003's rigidity maintenance on (``[rigidity] maintenance``; never
    for fewer than 4 vehicles, see ``onboard.daemon.config.MIN_MAINTENANCE_AGENTS``).
    ``sitl_instance``: the daemons dial ArduCopter SITL instances ``sitl_instance + id`` (TCP
    SERIAL0, 10 ports apart) instead of the simulator's UDP ports. ``localization``: the
    ``[core] localization`` the daemons fly on (written only when not the default)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "formation.toml").write_text(
        _formation_toml(plan.p_ned, plan.yaw_rad, plan.edges, "demo")
    )
    (out / "start.toml").write_text(
        _formation_toml(plan.p_start_ned, plan.yaw_start_rad, None, "demo-start")
    )
    fleet_path = out / "fleet.toml"
    rigidity = rigidity and len(plan.p_ned) >= MIN_MAINTENANCE_AGENTS  # load_fleet refuses 3
    lam_safe = demo_lambda_safe(plan)
    fleet_path.write_text(
        "\n".join(
            [
                'formation = "formation.toml"',
                f'fleet = "{fleet}"',
                f'mode = "{mode}"',
                'clock = "sim"',
                "auto_start = true",
                "takeoff_alt_m = 5.0",
                "",
                "[mavlink]",
                *(
                    [f"port_base = {ports.mavlink}"]
                    if sitl_instance is None
                    else [
                        'url = "tcp:127.0.0.1:{port}"',
                        f"port_base = {5760 + 10 * sitl_instance}",
                        "port_stride = 10",
                    ]
                ),
                "",
                "[zenoh]",
                f"port_base = {ports.zenoh}",
                f"inject_loss = {loss}",
                "",
                "[rigidity]",
                f"maintenance = {'true' if rigidity else 'false'}",
                f"fov_deg = {CAMERA_FOV_DEG}",
                f"range_m = {CAMERA_RANGE_M}",
                f"lambda_safe = {lam_safe:.6g}",
                f"lambda_min = {LAMBDA_MIN_FRACTION * lam_safe:.6g}",
                "",
                *(
                    []
                    if localization == "paper000"
                    else ["[core]", f'localization = "{localization}"', ""]
                ),
            ]
        )
    )
    return fleet_path


@dataclass
class Series:
    """Time series the evaluator records (one row per sample)."""

    t_s: list[float] = field(default_factory=list)
    p_ned: list[FloatArray] = field(default_factory=list)
    scale_error: list[FloatArray] = field(default_factory=list)
    """Per reciprocal pair: ``|1/chihat - d| / d`` (NaN while unknown)."""
    bearing_error_deg: list[float] = field(default_factory=list)
    rigidity_eigenvalue: list[float] = field(default_factory=list)
    angle_eigenvalue: list[float] = field(default_factory=list)
    """The true weighted angle rigidity eigenvalue (paper 003 eq. 16-18; every vehicle a
    candidate, the demo's camera): what the rigidity layers estimate."""
    angle_eigenvalue_hat: list[FloatArray] = field(default_factory=list)
    """Per vehicle: its rigidity layer's estimate (NaN without one)."""
    p_hat_ned: list[FloatArray] = field(default_factory=list)
    """Per vehicle: its position estimate (the rigidity layer's, when it runs), NaN if unknown."""
    yaw_hat_rad: list[FloatArray] = field(default_factory=list)
    flying: list[bool] = field(default_factory=list)


TRUTH_HISTORY_S = 2.0
"""How much of each vehicle's truth the evaluator keeps (s): a status is a few tenths of a
second old when it is scored (a 5 Hz status of a 100 Hz core, then Zenoh)."""


def truth_at(history: Sequence[Truth], t_s: float) -> FloatArray | None:
    """The true position (NED, m) at ``t_s``, interpolated in ``history`` (oldest first);
    ``None`` outside it (a stamp on another timeline, or older than the history). A distance
    estimate stamped ``t_s`` estimates the distance at ``t_s``: scored against the newest truth
    instead, a status 0.1 s old looked 1-2 % off while the formation breathed at 2 m/s."""
    if not history or not history[0].stamp_s <= t_s <= history[-1].stamp_s:
        return None
    stamps = np.array([tr.stamp_s for tr in history])
    p = np.array([tr.p_ned for tr in history])
    return np.array([np.interp(t_s, stamps, p[:, a]) for a in range(3)])


class Evaluator:
    """Listens to every daemon's status and the simulator's truth; scores the estimates."""

    def __init__(self, fleet: str, plan: FormationPlan, settings: ZenohSettings) -> None:
        self.fleet = fleet
        self.plan = plan
        self.pairs = reciprocal_pairs(plan.edges)
        self.desired_beta, _ = bearings_body(plan.p_ned, plan.yaw_rad, plan.edges)
        self.camera = SensingModel(CAMERA_FOV_DEG, CAMERA_RANGE_M)
        try:
            self.session = open_session(settings)
        except TransportError as exc:  # the CLI prints RuntimeErrors as one line, exit 1
            raise RuntimeError(f"the demo's own Zenoh session: {exc}") from None
        self._lock = threading.Lock()
        self.status: dict[int, VehicleStatus] = {}
        self.truth: dict[int, Truth] = {}
        self._truth_hist: dict[int, deque[Truth]] = {}
        """Each vehicle's recent truth (:data:`TRUTH_HISTORY_S`): a status is scored against
        the truth as it was when the status was stamped (:func:`truth_at`): its age on its own
        vehicle's clock, taken back from each vehicle's newest truth, so SITL instances whose
        clocks differ are compared at one moment."""
        self.bad_samples = 0
        self.alarms_seen: dict[str, set[int]] = {}
        """Every alarm any daemon reported during the run, with the vehicles that did."""
        self.late_ticks: set[int] = set()
        """Vehicles whose daemon reported ``ticks_late`` after connecting (onboard/daemon/
        lateness.py): the machine was too slow for the speed, the run is degraded."""
        self.series = Series()
        self._subs = [
            self.session.declare_subscriber(f"bf/{fleet}/*/status", self._on_status),
            self.session.declare_subscriber(f"bf/{fleet}/*/truth", self._on_truth),
        ]

    def _on_status(self, sample: Any) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), VehicleStatus)
        except MessageError:
            self.bad_samples += 1
            return
        with self._lock:
            self.status[msg.sender] = msg
            for alarm in msg.alarms:
                self.alarms_seen.setdefault(alarm, set()).add(msg.sender)
            if Alarm.TICKS_LATE in msg.alarms and msg.phase != Phase.CONNECTING:
                self.late_ticks.add(msg.sender)

    def _on_truth(self, sample: Any) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), Truth)
        except MessageError:
            self.bad_samples += 1
            return
        with self._lock:
            self.truth[msg.sender] = msg
            hist = self._truth_hist.setdefault(msg.sender, deque())
            hist.append(msg)
            while hist[0].stamp_s < msg.stamp_s - TRUTH_HISTORY_S:
                hist.popleft()

    def command_all(self, action: str) -> None:
        for agent_id in range(self.plan.n):
            cmd = FleetCommand(
                sender=0, target=agent_id, action=action, request_id=int(time.time() * 1e3)
            )
            self.session.put(key(self.fleet, agent_id, COMMAND_TOPIC), encode(cmd))

    def sample(self) -> None:
        """Score the current estimates against the truth and append one row."""
        with self._lock:
            if len(self.truth) < self.plan.n:
                return
            p = np.array([self.truth[k].p_ned for k in range(self.plan.n)])
            yaw = np.array([self.truth[k].yaw_rad for k in range(self.plan.n)])
            t = max(tr.stamp_s for tr in self.truth.values())
            status = dict(self.status)
            hist = {k: list(h) for k, h in self._truth_hist.items()}
        errors = np.full(len(self.pairs), np.nan)
        for m, (i, j) in enumerate(self.pairs):
            st = status.get(int(i))
            chi = st.agent.chi_hat_inv_m.get(int(j)) if st is not None else None
            if chi and st is not None:
                # the status's age on its own vehicle's clock (SITL instances each have one)
                own = hist.get(int(i), [])
                age_s = own[-1].stamp_s - st.stamp_s if own else math.nan
                at = [
                    truth_at(h, h[-1].stamp_s - age_s) if (h := hist.get(int(k), [])) else None
                    for k in (i, j)
                ]
                pi, pj = (p[i], p[j]) if at[0] is None or at[1] is None else at
                d = float(np.linalg.norm(pj - pi))
                errors[m] = abs(1.0 / chi - d) / d
        n = self.plan.n
        beta, _ = bearings_body(p, yaw, self.plan.edges)
        cosines = np.clip(np.sum(beta * self.desired_beta, axis=1), -1.0, 1.0)
        flying = len(status) == self.plan.n and all(
            s.phase == Phase.FLYING for s in status.values()
        )
        s = self.series
        s.t_s.append(t)
        s.p_ned.append(p)
        s.scale_error.append(errors)
        s.bearing_error_deg.append(float(np.degrees(np.mean(np.arccos(cosines)))))
        s.rigidity_eigenvalue.append(ibr_r3s1(p, yaw, self.plan.edges).eigenvalue)
        complete = complete_graph(self.plan.n)
        s.angle_eigenvalue.append(
            float(weighted_angle_rigidity_eigenvalue(p, yaw, complete, self.camera)[0])
        )
        hats = [status[k].agent.rigidity_eigenvalue if k in status else None for k in range(n)]
        s.angle_eigenvalue_hat.append(np.array([np.nan if h is None else h for h in hats]))
        nan3 = (np.nan, np.nan, np.nan)
        s.p_hat_ned.append(
            np.array([status[k].agent.p_hat_ned if k in status else nan3 for k in range(n)])
        )
        s.yaw_hat_rad.append(
            np.array([status[k].agent.yaw_hat_rad if k in status else np.nan for k in range(n)])
        )
        s.flying.append(flying)

    def all_landed(self) -> bool:
        """Every vehicle on the ground, by the simulator's truth (within 0.2 m)."""
        with self._lock:
            return len(self.truth) == self.plan.n and all(
                tr.p_ned[2] > -LANDED_HEIGHT_M for tr in self.truth.values()
            )

    def snapshot(self) -> dict[int, VehicleStatus]:
        with self._lock:
            return dict(self.status)

    def close(self) -> None:
        self.session.close()


def summarize(ev: Evaluator, vehicles: int) -> dict[str, Any]:
    """The demo's summary: time to metric scale, final errors, rigidity, dropped messages,
    every alarm a daemon raised (``{alarm: [vehicles]}``; e.g. ``altitude_floor`` while a vehicle
    climbs to the envelope after take-off), and ``degraded`` when a daemon's ticks ran late
    (``late_tick_vehicles``: the machine was too slow for the speed, so the numbers are worse
    than the method's)."""
    s = ev.series
    t = np.array(s.t_s)
    err = np.array(s.scale_error) if s.scale_error else np.zeros((0, len(ev.pairs)))
    flying = np.array(s.flying, dtype=bool)
    start = float(t[np.argmax(flying)]) if flying.any() else None
    time_to_scale = None
    if start is not None and len(err):
        ok = np.all(err < SCALE_TOLERANCE, axis=1) & flying
        bad_after = np.nonzero(~ok)[0]
        first_good = bad_after[-1] + 1 if len(bad_after) else 0
        if first_good < len(t) and t[first_good] >= start:
            time_to_scale = float(t[first_good] - start)
    tail = t >= (t[-1] - 2.0) if len(t) else np.zeros(0, dtype=bool)
    tail_err = err[tail] if tail.any() else np.zeros((0, err.shape[1]))
    estimated = np.isfinite(tail_err).any(axis=0)  # pairs with an estimate at the end
    final_scale = (
        float(np.max(np.nanmean(tail_err[:, estimated], axis=0))) if estimated.any() else None
    )
    final_bearing = float(np.mean(np.array(s.bearing_error_deg)[tail])) if tail.any() else None
    status = ev.snapshot()
    by_reason: dict[str, int] = {}
    for st in status.values():
        for reason, count in st.dropped.items():
            by_reason[reason] = by_reason.get(reason, 0) + int(count)
    dropped = sum(by_reason.values())
    eig = np.array(s.rigidity_eigenvalue)[flying] if flying.any() else np.array([])
    lam = np.array(s.angle_eigenvalue)
    lam_hat = np.array(s.angle_eigenvalue_hat).reshape(len(lam), -1 if len(lam) else vehicles)
    final_lam_error = None
    if tail.any() and np.isfinite(lam_hat[tail]).any():
        rel = np.abs(lam_hat[tail] - lam[tail, None]) / lam[tail, None]
        final_lam_error = float(np.nanmax(np.nanmean(rel, axis=0)))
    return {
        "vehicles": vehicles,
        "time_to_scale_s": time_to_scale,
        "final_scale_error": None
        if final_scale is None or math.isnan(final_scale)
        else final_scale,
        "final_bearing_error_deg": final_bearing,
        "min_rigidity_eigenvalue": float(eig.min()) if len(eig) else None,
        "min_angle_rigidity_eigenvalue": float(lam[flying].min()) if flying.any() else None,
        "final_angle_eigenvalue_error": final_lam_error,
        "dropped_messages": int(dropped),
        "dropped_by_reason": dict(sorted(by_reason.items())),
        "bad_samples": ev.bad_samples,
        "mission_start_s": start,
        "reciprocal_pairs": ev.pairs.tolist(),
        "alarms_seen": {a: sorted(ids) for a, ids in sorted(ev.alarms_seen.items())},
        "degraded": bool(ev.late_ticks),
        "late_tick_vehicles": sorted(ev.late_ticks),
    }


class Processes:
    """The processes a demo started; :meth:`stop` ends every one of them."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: list[tuple[str, subprocess.Popen[bytes]]] = []

    def start(self, name: str, args: list[str]) -> subprocess.Popen[bytes]:
        log = open(self.log_dir / f"{name}.log", "wb")
        proc = subprocess.Popen(
            [sys.executable, *args], stdout=log, stderr=subprocess.STDOUT, start_new_session=True
        )
        self.procs.append((name, proc))
        return proc

    def dead(self) -> list[str]:
        return [name for name, p in self.procs if p.poll() is not None]

    def stop(self, timeout_s: float = 5.0) -> None:
        for _, p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        for _, p in self.procs:
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def simulator_args(
    vehicles: int,
    flavour: str,
    out: Path,
    ports: DemoPorts,
    fleet: str,
    seed: int = 0,
    speedup: float = 1.0,
    dynamics: str = "ideal",
) -> list[str]:
    """``python`` arguments of the demo's simulator: the layout of :func:`write_demo_files`,
    MAVLink over UDP where the fleet file's daemons dial (for either flavour: the ArduPilot
    flavour would listen on TCP like SITL), the virtual camera on Zenoh."""
    return [
        "-m", "sim.cli", "--vehicles", str(vehicles), "--flavour", flavour,
        "--layout", str(out / "start.toml"), "--zenoh", loopback_endpoint(ports.zenoh),
        "--fleet", fleet, "--transport", "udp",
        "--port-base", str(ports.mavlink), "--gcs-port", str(ports.gcs),
        "--bind-base", str(ports.mavlink + vehicles + 5),
        "--camera-fov", str(CAMERA_FOV_DEG), "--camera-range", str(CAMERA_RANGE_M),
        "--seed", str(seed), "--quiet", "--speedup", str(speedup), "--dynamics", dynamics,
    ]  # fmt: skip


def run_demo(
    vehicles: int,
    flavour: str,
    duration_s: float,
    out: Path,
    seed: int = 0,
    mode: str = "formation-active",
    on_tick: Callable[[Evaluator, float, str], None] | None = None,
    bearings: str = "sim",
    camera_files: Sequence[Path] = (),
    markers_file: Path | None = None,
    speedup: float = 1.0,
    render_rate_hz: float = 10.0,
    loss: float = 0.0,
    rigidity: bool = True,
    autopilot: str = "builtin",
    sitl: Path | None = None,
    sitl_sensors: str = "flow",
    sitl_params: Sequence[str] = (),
    record: bool = True,
    dynamics: str = "ideal",
    secure: bool = False,
    localization: str = "paper000",
) -> dict[str, Any]:
    """Run the whole mission (module docstring) and return its summary.

    ``localization``: the fleet file's ``[core] localization`` (``"paper002"``: paper 002's
    distributed gradient localization, docs/distributed.md).

    ``record``: the ground station's recording of the run goes to ``out/recording.mcap``
    (every Zenoh sample of the fleet, Foxglove's scene of the team) and ``out/recording.tlog``
    (the MAVLink the simulator sends to the ground-station port), as ``gcs record`` writes them.

    ``secure``: the fleet's keys are made in ``out/keys`` (``bearingflock keys init``), the
    fleet file points at them (``[security] dir``), the simulator plays autopilots that
    require signed MAVLink (``--keys``), and every Zenoh session runs over mutual TLS with the
    fleet CA; built-in autopilots only.

    ``autopilot = "ardupilot-sitl"``: real ArduCopter SITL processes instead of the simulated
    autopilots (``bearingflock sim --autopilot ardupilot-sitl``; binary ``sitl`` or
    ``$BEARINGFLOCK_SITL``), the daemons in GUIDED. Their boot takes tens of simulated seconds
    (SITL refuses to arm for ~24 s), so ``duration_s`` then counts from the mission start
    (every vehicle flying), within :data:`SITL_START_S` of the first truth sample.

    ``bearings = "camera"``: the simulator renders every vehicle's camera rig (``camera_files``,
    camera_id = order) with the markers of ``markers_file`` at ``render_rate_hz`` of simulation
    time, and the agents take their bearings from those images. ``speedup`` is the simulator's
    (< 1 gives rendering the wall time it needs). ``duration_s`` (mission, from the first truth
    sample) and the landing timeout are simulation time; ``on_tick`` gets the mission's
    simulation seconds so far. ``dynamics`` is the built-in simulator's model (``ideal`` or
    ``realistic``, :mod:`sim.dynamics`)."""
    from sim.server import free_port_base

    base = free_port_base(vehicles + 2, span=60, seed=None)
    ports = DemoPorts(zenoh=base, mavlink=base + 10 + vehicles, gcs=base + 9)
    plan = plan_formation(vehicles, seed)
    fleet = f"demo{base}"
    sitl_args: list[str] = []
    instance = None
    if autopilot == "ardupilot-sitl":
        if bearings != "sim":
            raise ValueError("ArduCopter SITL flies with the virtual camera only (--bearings sim)")
        from sim.sitl import find_sitl, free_instances

        binary = find_sitl(sitl)  # a missing binary is a one-line error before anything starts
        instance = free_instances(vehicles)
        sitl_args = ["--autopilot", "ardupilot-sitl", "--sitl", str(binary),
                     "--sitl-sensors", sitl_sensors, "--sitl-instance", str(instance),
                     *(a for p in sitl_params for a in ("--sitl-param", p))]  # fmt: skip
    elif autopilot != "builtin":
        raise ValueError(f"unknown autopilot {autopilot!r}: builtin or ardupilot-sitl")
    if secure and autopilot != "builtin":
        raise ValueError("--secure: the simulated autopilots only (SITL keys are not provisioned)")
    # the rigidity layer's sensing model is one camera cone; rendered rigs (a forward camera or
    # a ring of them) are not modelled yet, so camera bearings fly without the maintenance
    rigidity = rigidity and bearings == "sim"
    fleet_path = write_demo_files(
        out, plan, ports, fleet, mode, loss, rigidity, instance, localization=localization
    )
    secure_args: list[str] = []
    if secure:
        from messages.fleetkeys import init_fleet

        init_fleet(out / "keys", fleet, vehicles, force=True)  # a fresh identity per run
        with fleet_path.open("a") as f:
            f.write('\n[security]\ndir = "keys"\n')
        secure_args = ["--keys", str(out / "keys")]
    if bearings == "camera":
        stale_s = max(0.5, CAMERA_STALE_FRAMES / render_rate_hz)
        with fleet_path.open("a") as f:
            f.write(f"[limits]\nstale_s = {stale_s:.3f}\n")
    procs = Processes(out)
    evaluator: Evaluator | None = None
    stack = ExitStack()
    rig = [a for f in camera_files for a in ("--camera", str(f))]
    marker_args = ["--markers", str(markers_file)] if markers_file is not None else []
    agent_camera_args = [*rig, *marker_args] if bearings == "camera" else []
    render_rig = [a for f in camera_files for a in ("--render-camera", str(f))]
    camera_args = (
        [*render_rig, *marker_args, "--render-rate", str(render_rate_hz)]
        if bearings == "camera"
        else []
    )
    try:
        procs.start(
            "sim",
            [*simulator_args(vehicles, flavour, out, ports, fleet, seed, speedup, dynamics),
             *camera_args,
             *sitl_args,
             *secure_args],
        )  # fmt: skip
        for i in range(vehicles):
            procs.start(
                f"agent{i}",
                ["-m", "onboard.daemon", "--id", str(i), "--config", str(fleet_path),
                 "--bearings", bearings, *agent_camera_args],
            )  # fmt: skip
        zsettings = ZenohSettings(
            connect=[loopback_endpoint(ports.zenoh + k) for k in range(vehicles + 1)]
        )
        if secure:  # the evaluator joins as the ground station, over mutual TLS
            from messages.fleetkeys import GCS_NAME, identity_files
            from messages.transport import with_mutual_tls
            from messages.zenoh_acl import fleet_access_control

            zsettings = with_mutual_tls(
                zsettings,
                *identity_files(out / "keys", GCS_NAME),
                access_control=fleet_access_control(fleet, vehicles, fleet),
            )
        evaluator = Evaluator(fleet, plan, zsettings)
        ev = evaluator
        if record:
            keys = out / "keys" if secure else None
            recording = _start_recording(
                stack, out / RECORDING_NAME, fleet, ev.session, ports, keys
            )

        def sim_now() -> float | None:
            stamps = [tr.stamp_s for tr in list(ev.truth.values())]
            return max(stamps) if stamps else None

        def wall_deadline(sim_s: float) -> float:
            return time.monotonic() + STARTUP_WALL_S + WALL_SLACK * sim_s / speedup

        t0_sim: float | None = None
        first_sim: float | None = None
        from_start = instance is not None  # SITL: the mission counts from the mission start
        deadline = wall_deadline(duration_s + (SITL_START_S if from_start else 0.0))
        phase = "mission"
        while time.monotonic() < deadline:
            time.sleep(0.1)
            evaluator.sample()
            if dead := procs.dead():
                raise RuntimeError(f"process(es) died: {', '.join(dead)} (logs in {out})")
            now = sim_now()
            first_sim = now if first_sim is None else first_sim
            flying = bool(evaluator.series.flying) and evaluator.series.flying[-1]
            if t0_sim is None and now is not None and (flying or not from_start):
                t0_sim = now
            elapsed = 0.0 if now is None or t0_sim is None else now - t0_sim
            if on_tick is not None:
                on_tick(evaluator, elapsed, phase)
            if elapsed >= duration_s:
                break
            if t0_sim is None and now is not None and first_sim is not None:
                if now - first_sim > SITL_START_S:
                    break  # never started: reported below
        summary = summarize(evaluator, vehicles)
        evaluator.command_all("land")
        phase = "landing"
        land_from = sim_now()
        landing_s = SITL_LANDING_TIMEOUT_S if from_start else LANDING_TIMEOUT_S
        deadline = wall_deadline(landing_s)
        while time.monotonic() < deadline and not evaluator.all_landed():
            time.sleep(0.2)
            now = sim_now()
            if land_from is not None and now is not None and now - land_from >= landing_s:
                break
            if on_tick is not None:
                on_tick(evaluator, duration_s, phase)
        summary["landed"] = evaluator.all_landed()
        if record:
            summary["recording"] = str(recording)
        if summary["mission_start_s"] is None:
            phases = ", ".join(f"{k}: {st.phase}" for k, st in sorted(evaluator.snapshot().items()))
            raise RuntimeError(
                f"the mission never started: the vehicles were not all flying within "
                f"{SITL_START_S if from_start else duration_s:g} s of simulation (daemon "
                f"phases: {phases or 'none reported'}); "
                f"agent*.log and sim.log in {out} say why"
            )
        return summary
    finally:
        stack.close()  # the recording first: its listeners use the evaluator's session
        if evaluator is not None:
            _save(evaluator, out)
            evaluator.close()
        procs.stop()


RECORDING_NAME = "recording.mcap"


def _start_recording(
    stack: ExitStack,
    path: Path,
    fleet: str,
    session: Any,
    ports: DemoPorts,
    keys: Path | None = None,
) -> Path:
    """Record the run as ``gcs record`` does, on the evaluator's Zenoh session and the
    ground-station MAVLink port (a listening ground station: heartbeats, no stream requests).
    With the fleet's ``keys`` (``--secure``) its heartbeats are signed with each vehicle's key,
    as ``gcs record --keys`` signs them (system id = agent id + 1, the fleet file's default).
    Everything is closed by ``stack``, the file last."""
    from groundstation.gcs.foxglove_scene import SceneBuilder
    from groundstation.gcs.mavlink_listener import MavlinkListener, parse_endpoint
    from groundstation.gcs.record import Recorder
    from groundstation.gcs.zenoh_listener import ZenohListener

    camera = SensingModel(CAMERA_FOV_DEG, CAMERA_RANGE_M)  # the demo's, for weights and frusta
    recorder = Recorder(path, fleet, scene=SceneBuilder(camera=camera))
    stack.callback(recorder.close)
    listener = ZenohListener(session, fleet)
    listener.sample_hooks.append(recorder.zenoh_sample)
    listener.alive_hooks.append(recorder.alive)
    stack.callback(listener.close)
    listener.start()
    signing = None
    if keys is not None:
        from messages.fleetkeys import load_signing_keys

        signing = {i + 1: k for i, k in load_signing_keys(keys).items()}
    mav = MavlinkListener(
        [parse_endpoint(f"udp:127.0.0.1:{ports.gcs}")],
        request_streams=False,
        signing_keys=signing,
    )
    mav.hooks.append(recorder.mavlink)
    stack.callback(mav.close)
    mav.start()
    return path


def _save(ev: Evaluator, out: Path) -> None:
    s = ev.series
    if not s.t_s:
        return
    np.savez_compressed(
        out / "demo_series.npz",
        t_s=np.array(s.t_s),
        p_ned=np.array(s.p_ned),
        scale_error=np.array(s.scale_error),
        bearing_error_deg=np.array(s.bearing_error_deg),
        rigidity_eigenvalue=np.array(s.rigidity_eigenvalue),
        angle_eigenvalue=np.array(s.angle_eigenvalue),
        angle_eigenvalue_hat=np.array(s.angle_eigenvalue_hat),
        p_hat_ned=np.array(s.p_hat_ned),
        yaw_hat_rad=np.array(s.yaw_hat_rad),
        flying=np.array(s.flying),
        pairs=ev.pairs,
        p_desired_ned=ev.plan.p_ned,
        lambda_safe=demo_lambda_safe(ev.plan),
    )
