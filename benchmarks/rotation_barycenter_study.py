"""Why a rotating team grows: the barycenter ``pbar`` of paper 000 eq. 14 by PI consensus
(issue 22, docs/sim.md "Formation growth under the active rotation").

The active rotation (eq. 13) turns every vehicle about ``pbar``, which each agent estimates by
average consensus of the team's position estimates (onboard/estimation/consensus.py). The
flight stack's consensus couplings (``k_p = k_i = 1``, chosen for network delay) are weak
against the input term ``gamma = 50``: while the team rotates, each agent's inputs circle and
its estimate follows its own input. This flies the demo's mission in the headless runner
(groundstation/demo_headless.py, ideal kinematics, no lag) with the convergence gate held open
(``k_E = 1``: the rotation never stops, as on SITL when the SfM edges keep un-converging) and
reports, per consensus setting: agent 0's ``|pbar - centroid|`` of the estimates, the formation
law's speed ``|u_f|`` (it fights a non-rigid rotation), and the mean pair distance (the
formation's scale; a rigid rotation keeps it).

Then the plain demo mission (the gate as configured) with the default (``gamma`` 50) and with
``gamma`` 5 side by side: time to metric scale, final scale and formation errors, and the
formation's growth.

    python benchmarks/rotation_barycenter_study.py [--vehicles 3] [--seed 0]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

import onboard.core.motion as motion
from groundstation.demo_headless import headless_demo

HELD_OPEN = {"e_low": -2.0, "e_high": -1.0, "w_l_start_rad_s": 0.3, "w_l_max_rad_s": 0.3}
"""``k_E(E) = 1`` whatever ``E`` (the smooth step of eq. 16 below any index) and the rotation
at 0.3 rad/s from the start."""
CANDIDATE = {"consensus_gamma": 5.0}
"""The faster consensus measured as a candidate (not the default: docs/sim.md)."""
SETTINGS = (
    ("gamma 50, k 1 (flight stack)", {"consensus_gamma": 50.0}),
    ("gamma 5, k 1", {"consensus_gamma": 5.0}),
    ("gamma 50, k 10", {"consensus_gamma": 50.0, "consensus_k_p": 10.0, "consensus_k_i": 10.0}),
)


def forced_rotation(vehicles: int, seed: int, fields: dict[str, Any]) -> dict[str, Any]:
    """The mission with the rotation held on for 20 s; agent 0's ``pbar`` error and ``|u_f|``
    sampled every 5 s, the mean pair distance at 5 and 20 s."""
    samples: list[tuple[float, float, tuple[float, float, float]]] = []
    original = motion.Formation.formation

    def formation(self: motion.Formation, t_s: float) -> tuple[Any, float]:
        u_f, w_f = original(self, t_s)
        if self.id == 0 and round(t_s * 200) % 1000 == 0:
            samples.append((t_s, float(np.linalg.norm(u_f)), self.scale.p_bar))
        return u_f, w_f

    motion.Formation.formation = formation  # type: ignore[method-assign]
    try:
        _, rec = headless_demo(vehicles=vehicles, seed=seed, duration_s=20.5, tau_v_s=0.0,
                               tau_yaw_s=0.0, rigidity=False,
                               core_fields={**HELD_OPEN, "v_max_m_s": 10.0, **fields})  # fmt: skip
    finally:
        motion.Formation.formation = original  # type: ignore[method-assign]
    a, b = rec.pairs[:, 0], rec.pairs[:, 1]
    d = np.linalg.norm(rec.p_ned[:, b] - rec.p_ned[:, a], axis=2).mean(axis=1)
    err, u_f = [], []
    for t_s, speed, p_bar in samples[1:]:
        k = int(np.searchsorted(rec.t_s, t_s))
        err.append(float(np.linalg.norm(np.array(p_bar) - rec.p_hat_ned[k].mean(axis=0))))
        u_f.append(speed)
    at = [int(np.searchsorted(rec.t_s, t)) for t in (5.0, 20.0)]
    return {"pbar_error_m": err, "u_f_m_s": u_f, "distance_m": [float(d[k]) for k in at]}


def plain_mission(vehicles: int, seed: int, fields: dict[str, Any]) -> dict[str, Any]:
    s, rec = headless_demo(vehicles=vehicles, seed=seed, core_fields=fields or None)
    a, b = rec.pairs[:, 0], rec.pairs[:, 1]
    d = np.linalg.norm(rec.p_ned[:, b] - rec.p_ned[:, a], axis=2).mean(axis=1)
    return {**{k: s[k] for k in ("time_to_scale_s", "final_scale_error",
                                 "final_bearing_error_deg")},
            "distance_m": (float(d[0]), float(d[-1]))}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--vehicles", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"rotation held on, {args.vehicles} vehicles, ideal kinematics, 20 s")
    print(f"{'consensus':32s} {'|pbar - centroid| m (5-20 s)':30s} {'|u_f| m/s':22s} distance m")
    for name, fields in SETTINGS:
        r = forced_rotation(args.vehicles, args.seed, fields)
        e = " ".join(f"{x:.2f}" for x in r["pbar_error_m"])
        u = " ".join(f"{x:.2f}" for x in r["u_f_m_s"])
        print(f"{name:32s} {e:30s} {u:22s} {r['distance_m'][0]:.1f} -> {r['distance_m'][1]:.1f}")
    for n in sorted({args.vehicles, 6}):
        print(f"\nthe demo mission, {n} vehicles (gate as configured)")
        for name, fields in (("default", {}), ("gamma 5", CANDIDATE)):
            r = plain_mission(n, args.seed, fields)
            print(f"  {name:6s}: scale after {r['time_to_scale_s']} s, final scale error "
                  f"{100 * r['final_scale_error']:.3f} %, formation error "
                  f"{r['final_bearing_error_deg']:.3f} deg, distance "
                  f"{r['distance_m'][0]:.1f} -> {r['distance_m'][1]:.1f} m")  # fmt: skip


if __name__ == "__main__":
    main()
