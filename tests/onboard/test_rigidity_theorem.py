"""Paper 003's theorem: for non-degenerate frameworks in SE(3), infinitesimal bearing rigidity
holds iff the framework is infinitesimally angle rigid and every robot measures >= d - 1 = 2
bearings. Checked as a property on random generic frameworks and random directed graphs."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from onboard.geometry import so3_exp
from onboard.graph import complete_graph, out_degree
from onboard.rigidity.angle import is_infinitesimally_angle_rigid
from onboard.rigidity.bearing import ibr_se3


@st.composite
def frameworks(draw):
    n = draw(st.integers(3, 6))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * 5.0  # generic: degenerate configurations have measure zero
    rot = so3_exp(rng.normal(size=(n, 3)))
    candidates = complete_graph(n)
    keep = draw(st.lists(st.booleans(), min_size=len(candidates), max_size=len(candidates)))
    edges = candidates[np.array(keep, dtype=bool)]
    return p, rot, edges


@settings(max_examples=300, deadline=None)
@given(frameworks())
def test_ibr_se3_iff_iar_and_two_bearings_each(framework):
    p, rot, edges = framework
    n = len(p)
    ibr = ibr_se3(p, rot, edges).is_rigid if len(edges) else False
    iar = bool(len(edges)) and is_infinitesimally_angle_rigid(p, edges)
    assert ibr == (iar and out_degree(edges, n).min() >= 2)


def test_theorem_is_not_vacuous():
    """Both sides of the equivalence occur: the complete graph is rigid, a sparse one is not."""
    rng = np.random.default_rng(1)
    p = rng.normal(size=(5, 3))
    rot = so3_exp(rng.normal(size=(5, 3)))
    full = complete_graph(5)
    assert ibr_se3(p, rot, full).is_rigid and is_infinitesimally_angle_rigid(p, full)
    sparse = full[::4]
    assert not ibr_se3(p, rot, sparse).is_rigid
