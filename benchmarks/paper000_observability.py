"""Paper 000's observability comparison of case 4 against case 3 (README, "Paper 000 case 4").

The paper reports ``lambdabar`` about 25x larger in case 4 than in case 3 over the interval in
which the active term is mostly on (``k_E > 0.5``), and plots ``lambda_6^B``, the smallest
non-zero eigenvalue of ``B^T B`` (``R^3 x S^1``: five trivial motions), in fig. 3d / 4f. This
prints both per seed range, on the compiled engine::

    python benchmarks/paper000_observability.py --seeds 1000:1019 [--eq15]

``--eq15`` runs case 4 with paper 000's eq. 15 and the flight stack's consensus gains instead
of ``sim.scenarios.CASE4_GAINS``.
"""

from __future__ import annotations

import argparse

import numpy as np

from onboard.rigidity.bearing import r3s1_rigidity_matrix_body
from sim.runner import Recording
from sim.scenarios import run_scenario

EQ15 = {"w_l_start_rad_s": 0.0, "w_l_max_rad_s": 0.3, "consensus_k_p": 1.0, "consensus_k_i": 1.0}


def lambda6_b(rec: Recording, every: int = 20) -> np.ndarray:
    """``lambda_6^B`` of the true configuration at every ``every``-th recorded sample."""
    out = []
    for k in range(0, len(rec.t_s), every):
        b = r3s1_rigidity_matrix_body(rec.p_ned[k], rec.yaw_rad[k], rec.edges)
        out.append(np.linalg.eigvalsh(b.T @ b)[5])
    return np.asarray(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1000:1019", help="A:B inclusive")
    ap.add_argument("--eq15", action="store_true")
    args = ap.parse_args()
    a, b = (int(x) for x in args.seeds.split(":"))
    over = EQ15 if args.eq15 else {}
    ratio, ratio_all, ends, l3, l4 = [], [], [], [], []
    for seed in range(a, b + 1):
        r3 = run_scenario("scale-formation", seed=seed, engine="compiled")
        r4 = run_scenario("scale-formation-active", seed=seed, engine="compiled",
                          config_overrides=over)  # fmt: skip
        on = np.flatnonzero(r4.k_e.mean(axis=1) > 0.5)
        i, j = on[0], on[-1] + 1
        lb3, lb4 = r3.lambda_bar_true(), r4.lambda_bar_true()
        ratio.append(lb4[i:j].mean() / lb3[i:j].mean())
        ratio_all.append(lb4.mean() / lb3.mean())
        ends.append((r4.t_s[i], r4.t_s[j - 1]))
        l3.append(lambda6_b(r3))
        l4.append(lambda6_b(r4))
    r = np.asarray(ratio)
    t0, t1 = np.median(np.asarray(ends), axis=0)
    print(f"lambdabar case 4 / case 3 while k_E > 0.5 (median interval {t0:.2f}-{t1:.2f} s): "
          f"median {np.median(r):.2f}x, range {r.min():.2f}-{r.max():.2f}x")  # fmt: skip
    print(f"over the whole run: median {np.median(ratio_all):.2f}x")
    for name, lam in (("case 3", l3), ("case 4", l4)):
        print(f"lambda_6^B {name}: minimum {min(x.min() for x in lam):.4f}, "
              f"median of the time means {np.median([x.mean() for x in lam]):.4f}")  # fmt: skip


if __name__ == "__main__":
    main()
