"""sim.jit compiles a module's functions unchanged, with their callees compiled too."""

from __future__ import annotations

import numba

from onboard.control import active_scale
from onboard.estimation import sfm_observer
from sim.jit import compiled


def test_compiled_functions_equal_the_python_ones() -> None:
    act = compiled(active_scale)
    sfm = compiled(sfm_observer)
    beta, u = (0.6, 0.0, 0.8), (0.3, -0.2, 0.1)
    assert isinstance(sfm.excitation, numba.core.registry.CPUDispatcher)
    assert sfm.excitation(beta, u) == sfm_observer.excitation(beta, u)
    args = ((0.1, 0.2, 0.3), (0.5, -0.1, 0.2), 10.0, 0.25, 15.0)
    assert act.active_velocity_rate(*args) == active_scale.active_velocity_rate(*args)


def test_a_module_is_compiled_once() -> None:
    assert compiled(sfm_observer).excitation is compiled(sfm_observer).excitation
