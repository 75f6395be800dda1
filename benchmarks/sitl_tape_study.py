"""What limits the SfM distances on a real-firmware flight: its core tapes replayed with the
odometry's errors taken out one by one (issue 22).

``bench_sitl_response.py --part team`` with ``BEARINGFLOCK_CORE_TAPE=OUT/tapes`` in the
environment records each daemon's core inputs (onboard/daemon/tape.py) beside the flight's
truth (``OUT/team_<autopilot>/team_<autopilot>.npz``). This replays every agent's core on its
tape and reports each pair's distance-estimate error after the mission start, for:

* ``flown``: the tape as recorded (the flight's own estimates again);
* ``constant error removed``: each vehicle's odometry (its own samples and the ``MotionShare``
  its peers received) corrected by the flight's best constant body-frame velocity gain and
  bias, fitted against the truth: what a perfect estimate of a constant bias could give;
* ``error low-passed over T s removed``: the odometry's error low-passed causally with time
  constant ``T`` (``--slow``) taken out: what a bias estimator of that bandwidth could give;
* ``true velocity``: every body-frame velocity replaced by the truth's (yaw and yaw rate kept):
  what is left when the odometry's velocity is exact.

each with the tape's configuration and with every ``--set NAME=VALUE[,NAME=VALUE]`` of the
agent core's ``ScaleGains`` (onboard/core/config.py; default: ``alpha=1``). The truth is
used here only to take errors out of the inputs, never by an estimator in flight. Open loop: the
replayed estimates do not fly the vehicles, so the motion is the flight's.

    BEARINGFLOCK_CORE_TAPE=OUT/tapes python benchmarks/bench_sitl_response.py --part team \\
        --only sitl --duration 90 --out OUT
    python benchmarks/sitl_tape_study.py OUT
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path

import msgspec
import numpy as np

from messages.agent import OwnMeasurements
from messages.codec import Payload
from messages.peer import MotionShare, SfmEstimate
from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig
from onboard.daemon.tape import read_tape

Vec3 = tuple[float, float, float]
FIT_SKIP_S = 25.0
"""Seconds after a vehicle's first truth sample left out of the gain/bias fit (take-off)."""


class Truth:
    """Each vehicle's true position, velocity and yaw, interpolated at any stamp."""

    def __init__(self, rows: np.ndarray) -> None:
        self.rows = {}
        for k in np.unique(rows[:, 1]).astype(int):
            r = rows[rows[:, 1] == k]
            r = r[np.argsort(r[:, 0])]
            r[:, 8] = np.unwrap(r[:, 8])
            self.rows[k] = r

    def col(self, k: int, t_s: np.ndarray | float, c: int) -> np.ndarray:
        r = self.rows[k]
        return np.interp(t_s, r[:, 0], r[:, c])

    def p_ned(self, k: int, t_s: np.ndarray) -> np.ndarray:
        return np.stack([self.col(k, t_s, 2 + c) for c in range(3)], axis=-1)

    def v_body(self, k: int, t_s: float) -> Vec3:
        vn, ve, vd = (float(self.col(k, t_s, 5 + c)) for c in range(3))
        yaw = float(self.col(k, t_s, 8))
        c, s = math.cos(yaw), math.sin(yaw)
        return (c * vn + s * ve, -s * vn + c * ve, vd)


def fit_constant_error(z: np.lib.npyio.NpzFile, truth: Truth, k: int) -> tuple[float, np.ndarray]:
    """Vehicle ``k``'s odometry gain and horizontal body-frame bias: ``v_meas = g v_true + b``
    (least squares, from LOCAL_POSITION_NED and ATTITUDE against the truth)."""
    lpn = z[f"lpn{k}"][np.argsort(z[f"lpn{k}"][:, 0])]
    att = z[f"att{k}"][np.argsort(z[f"att{k}"][:, 0])]
    r = truth.rows[k]
    ts = np.arange(r[0, 0] + FIT_SKIP_S, r[-1, 0] - 5.0, 0.02)
    yaw = np.interp(ts, att[:, 0], np.unwrap(att[:, 3]))
    vn, ve = np.interp(ts, lpn[:, 0], lpn[:, 4]), np.interp(ts, lpn[:, 0], lpn[:, 5])
    c, s = np.cos(yaw), np.sin(yaw)
    meas = np.stack([c * vn + s * ve, -s * vn + c * ve], axis=1)
    true = np.array([truth.v_body(k, t)[:2] for t in ts])
    a = np.column_stack([true.ravel(), np.tile(np.eye(2), (len(ts), 1))])
    (g, bx, by), *_ = np.linalg.lstsq(a, meas.ravel(), rcond=None)
    return float(g), np.array([bx, by])


class SlowError:
    """Vehicle ``k``'s odometry velocity error (body frame, against the truth) low-passed with
    time constant ``tau_s``, causally: the part a bias estimator of that bandwidth could know."""

    def __init__(self, z: np.lib.npyio.NpzFile, truth: Truth, k: int, tau_s: float) -> None:
        lpn = z[f"lpn{k}"][np.argsort(z[f"lpn{k}"][:, 0])]
        att = z[f"att{k}"][np.argsort(z[f"att{k}"][:, 0])]
        ts = lpn[:, 0]
        yaw = np.interp(ts, att[:, 0], np.unwrap(att[:, 3]))
        c, s = np.cos(yaw), np.sin(yaw)
        meas = np.stack([c * lpn[:, 4] + s * lpn[:, 5], -s * lpn[:, 4] + c * lpn[:, 5]], axis=1)
        err = meas - np.array([truth.v_body(k, t)[:2] for t in ts])
        slow = np.zeros_like(err)
        acc = err[0]
        for m in range(len(ts)):
            dt = ts[m] - ts[m - 1] if m else 0.0
            a = math.exp(-dt / tau_s)
            acc = a * acc + (1.0 - a) * err[m]
            slow[m] = acc
        self.ts, self.slow = ts, slow

    def at(self, t_s: float) -> tuple[float, float]:
        return (float(np.interp(t_s, self.ts, self.slow[:, 0])),
                float(np.interp(t_s, self.ts, self.slow[:, 1])))  # fmt: skip


Fix = Callable[[int, float, Vec3], Vec3]


def changed(cfg: AgentConfig, change: str) -> AgentConfig:
    """``cfg`` with ``NAME=VALUE[,NAME=VALUE]`` of its ``ScaleGains`` set."""
    kw: dict[str, object] = {}
    for item in filter(None, change.split(",")):
        name, _, value = item.partition("=")
        old = getattr(cfg.scale, name)
        kw[name] = value.lower() == "true" if isinstance(old, bool) else type(old)(value)
    return msgspec.structs.replace(cfg, scale=msgspec.structs.replace(cfg.scale, **kw))


def run_variant(tapes: Path, n: int, fix: Fix | None, change: str) -> np.ndarray:
    """Replay every agent's tape; rows ``(stamp, agent, peer, chihat)`` of its SfM estimates."""
    rows = []
    for agent in range(n):
        header, steps = read_tape(tapes / f"agent{agent}.tape")
        core = AgentCore(changed(header.config, change))
        for t_s, own, inbox in steps:
            if fix is not None:
                own, inbox = _fixed(agent, t_s, own, inbox, fix)
            _, out = core.step(t_s, own, inbox)
            for m in out:
                if isinstance(m, SfmEstimate):
                    rows.extend((m.stamp_s, agent, e.peer, e.chi_hat_inv_m) for e in m.edges)
    return np.array(rows)


def _fixed(
    agent: int, t_s: float, own: OwnMeasurements, inbox: list[Payload], fix: Fix
) -> tuple[OwnMeasurements, list[Payload]]:
    stamp = own.odometry_stamp_s if own.odometry_stamp_s is not None else t_s
    own = msgspec.structs.replace(own, v_body=fix(agent, stamp, own.v_body))
    inbox = [
        msgspec.structs.replace(m, v_body=fix(m.sender, m.stamp_s, m.v_body))
        if isinstance(m, MotionShare)
        else m
        for m in inbox
    ]
    return own, inbox


def errors(rows: np.ndarray, truth: Truth, start_s: float, pairs: np.ndarray) -> np.ndarray:
    """``(pair, t - start, relative error)`` of every SfM estimate."""
    out = []
    for p, (a, b) in enumerate(pairs):
        r = rows[(rows[:, 1] == a) & (rows[:, 2] == b)]
        d = np.linalg.norm(truth.p_ned(int(a), r[:, 0]) - truth.p_ned(int(b), r[:, 0]), axis=1)
        out.append(np.column_stack([np.full(len(r), p), r[:, 0] - start_s, (1 / r[:, 3] - d) / d]))
    return np.concatenate(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="the benchmark's --out directory (with tapes/)")
    ap.add_argument("--set", action="append", default=None, dest="changes",
                    help="ScaleGains NAME=VALUE[,...] to replay with besides the tape's; "
                    "repeatable (default: alpha=1.0)")  # fmt: skip
    ap.add_argument("--slow", type=float, nargs="*", default=[5.0],
                    help="time constants of the slow-error variants (s)")  # fmt: skip
    args = ap.parse_args()
    npz = next(args.out.glob("team_*/team_*.npz"))
    z = np.load(npz)
    truth = Truth(z["truth"])
    t, flying = z["t_s"], z["flying"]
    start_s = float(t[np.argmax(flying)])
    n = len(truth.rows)
    fits = (
        {k: fit_constant_error(z, truth, k) for k in range(n)}
        if "lpn0" in z and z["lpn0"].ndim == 2
        else {}
    )
    for k, (g, b) in fits.items():
        print(f"vehicle {k}: odometry gain {g:.4f}, body bias {100 * b[0]:+.1f} / "
              f"{100 * b[1]:+.1f} cm/s (forward / right)")  # fmt: skip

    def constant(k: int, _s: float, v: Vec3) -> Vec3:
        g, b = fits[k]
        return ((v[0] - b[0]) / g, (v[1] - b[1]) / g, v[2] / g)

    def true_velocity(k: int, s: float, _v: Vec3) -> Vec3:
        return truth.v_body(k, s)

    variants: dict[str, Fix | None] = {"flown": None}
    if fits:
        variants["constant error removed"] = constant
        for tau_s in args.slow:
            slow = {k: SlowError(z, truth, k, tau_s) for k in range(n)}

            def remove_slow(k: int, s: float, v: Vec3, slow: dict = slow) -> Vec3:
                ex, ey = slow[k].at(s)
                return (v[0] - ex, v[1] - ey, v[2])

            variants[f"error low-passed over {tau_s:g} s removed"] = remove_slow
    variants["true velocity"] = true_velocity
    changes = ["", *(args.changes or ["alpha=1.0"])]
    print(f"\n{npz.parent.name}: every pair's distance error, 30 s after the mission start "
          "to its end (median / p90 / max of |error|)")  # fmt: skip
    print("| odometry | configuration | 30-60 s | 60-90 s |\n|---|---|---|---|")
    for name, fix in variants.items():
        for change in changes:
            e = errors(run_variant(npz.parent.parent / "tapes", n, fix, change), truth, start_s,
                       z["pairs"])  # fmt: skip
            cells = []
            for lo, hi in ((30, 60), (60, 90)):
                x = np.abs(e[(e[:, 1] >= lo) & (e[:, 1] < hi), 2]) * 100
                cells.append(f"{np.median(x):.1f} / {np.percentile(x, 90):.1f} / {x.max():.1f} %"
                             if len(x) else "-")  # fmt: skip
            label = change or "the tape's"
            print(f"| {name} | {label} | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main()
