"""The headless runner flies the demo's configurations on paper 002's localization (``[core]
localization = "paper002"``): its shares cross the runner's lossy network like every other
payload, and the recorded estimate is the layer's ``T_i``, not paper 000's filter."""

from __future__ import annotations

import numpy as np

from groundstation.demo_headless import headless_demo
from messages.peer import GradientLocalizationShare
from sim import draws
from sim.runner import PAYLOAD_KINDS


def test_the_headless_demo_flies_on_paper002_localization():
    assert PAYLOAD_KINDS[GradientLocalizationShare] == draws.KIND_GRADIENT_LOCALIZATION
    assert len(set(PAYLOAD_KINDS.values())) == len(PAYLOAD_KINDS)  # a loss stream of its own
    kw = dict(vehicles=3, seed=0, duration_s=1.5, rigidity=False, loss=0.1)
    s0, r0 = headless_demo(**kw)
    s2, r2 = headless_demo(**kw, localization="paper002")
    assert np.isfinite(r2.p_hat_ned).all() and np.isfinite(r2.yaw_hat_rad).all()
    # the same mission, another position estimate (the same first yaws: paper 000's filter is the
    # known rotation); nothing dropped as malformed or non-finite
    assert not np.allclose(r0.p_hat_ned[-1], r2.p_hat_ned[-1], atol=1e-3)
    assert np.array_equal(r0.yaw_hat_rad[0], r2.yaw_hat_rad[0])
    assert s2["dropped_messages"] == 0 and s0["dropped_messages"] == 0
