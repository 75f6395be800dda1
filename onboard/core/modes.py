"""A mode is a composition of layers: the table :data:`MODE_LAYERS` and :func:`compose`, which
builds a core's layers from its configuration (each layer gets only its own groups).

Every mode has the camera layer; paper 000's modes add its scale estimation and one motion law;
``rigidity-tracking`` (paper 003) is the rigidity layer alone, which is then also the position
estimate. ``rigidity_maintenance`` appends the rigidity layer to any other mode, its actions
added to the motion law's. ``localization = "paper002"`` inserts paper 002's distributed
localization (:mod:`onboard.core.localization002`) right after the scale layer; its estimate
becomes the scale layer's :attr:`~onboard.core.scale.Scale.pose`.
"""

from __future__ import annotations

from enum import Enum

import msgspec

from messages.vocabulary import Mode
from onboard.core.bearings import Bearings
from onboard.core.config import AgentConfig
from onboard.core.layer import Layer
from onboard.core.localization002 import GradientLocalization
from onboard.core.motion import Active, Formation, FormationActive, Hold, Random
from onboard.core.peers import Drops, PeerTable
from onboard.core.rigidity import RigidityLayer
from onboard.core.scale import Scale


class LayerKind(Enum):
    """The layers a mode can compose (in stepping order within a mode)."""

    BEARINGS = "bearings"
    SCALE = "scale"
    SCALE_ROTATION = "scale-rotation"
    """Scale estimation plus the consensus on ``pbar`` and ``d lambdabar / d w_l`` (eq. 14)."""
    HOLD = "hold"
    RANDOM = "random"
    ACTIVE = "active"
    FORMATION = "formation"
    FORMATION_ACTIVE = "formation-active"
    RIGIDITY = "rigidity"
    GRADIENT_LOCALIZATION = "gradient-localization"
    """Paper 002's localization (eq. 16-17, 22), after the scale layer when selected."""


L = LayerKind
MODE_LAYERS: dict[Mode, tuple[LayerKind, ...]] = {
    "hold": (L.BEARINGS, L.SCALE, L.HOLD),
    "random": (L.BEARINGS, L.SCALE, L.RANDOM),
    "active": (L.BEARINGS, L.SCALE, L.ACTIVE),
    "formation": (L.BEARINGS, L.SCALE, L.FORMATION),
    "formation-active": (L.BEARINGS, L.SCALE_ROTATION, L.FORMATION_ACTIVE),
    "rigidity-tracking": (L.BEARINGS, L.RIGIDITY),
}
"""The layers of each mode, in stepping order (``rigidity_maintenance`` appends
:attr:`LayerKind.RIGIDITY`)."""


def layer_kinds(config: AgentConfig) -> tuple[LayerKind, ...]:
    """The layers a core with ``config`` composes, in stepping order."""
    kinds = MODE_LAYERS[config.mode]
    if config.gradloc.localization == "paper002":
        at = next((k + 1 for k, x in enumerate(kinds) if x in (L.SCALE, L.SCALE_ROTATION)), None)
        if at is None:
            raise ValueError(f"localization 'paper002' needs the scale layer ({config.mode})")
        kinds = (*kinds[:at], L.GRADIENT_LOCALIZATION, *kinds[at:])
    if config.rigidity.rigidity_maintenance and L.RIGIDITY not in kinds:
        kinds = (*kinds, L.RIGIDITY)
    return kinds


class Composition(msgspec.Struct):
    """A core's layers, with the named ones its readers use."""

    layers: list[Layer]
    bearings: Bearings
    scale: Scale | None = None
    controller: Hold | Random | Active | Formation | None = None
    rigidity: RigidityLayer | None = None
    gradient_localization: GradientLocalization | None = None


def compose(config: AgentConfig, peers: PeerTable, drops: Drops) -> Composition:
    """Build the layers of ``config``'s mode around the core's peer table."""
    kinds = layer_kinds(config)
    g = config.graph
    me = g.agent_id
    out = {j for i, j in g.edges if i == me}
    into = {i for i, j in g.edges if j == me}
    has_scale = L.SCALE in kinds or L.SCALE_ROTATION in kinds
    reciprocal = sorted(out & into) if has_scale else []  # no SfM edges nor relative yaws
    bearings = Bearings(g, peers.neighbours, reciprocal, drops)
    comp = Composition(layers=[bearings], bearings=bearings)
    for kind in kinds:
        layer: Layer
        if kind is L.BEARINGS:
            continue
        if kind in (L.SCALE, L.SCALE_ROTATION):
            layer = comp.scale = Scale(g, config.scale, peers, bearings, reciprocal, drops,
                                       rotation_terms=kind is L.SCALE_ROTATION)  # fmt: skip
        elif kind is L.GRADIENT_LOCALIZATION:
            assert comp.scale is not None  # layer_kinds puts it after the scale layer
            layer = comp.gradient_localization = GradientLocalization(
                g, config.gradloc, peers, bearings, comp.scale, drops
            )
            comp.scale.pose = layer
        elif kind is L.RIGIDITY:
            sc = comp.scale
            layer = comp.rigidity = RigidityLayer(
                g, config.rigidity, peers, None if sc is None else sc.distances, sc is None
            )
        else:
            layer = comp.controller = _controller(kind, config, bearings, comp.scale)
        comp.layers.append(layer)
    return comp


def _controller(
    kind: LayerKind, config: AgentConfig, bearings: Bearings, scale: Scale | None
) -> Hold | Random | Active | Formation:
    g = config.graph
    if kind is L.HOLD:
        return Hold()
    if kind is L.RANDOM:
        return Random(g, config.active)
    if scale is None:
        raise ValueError(f"layer {kind.value} needs the scale layer")
    if kind is L.ACTIVE:
        return Active(g, config.active, scale)
    if kind is L.FORMATION:
        return Formation(g, config.formation, bearings, scale)
    if kind is L.FORMATION_ACTIVE:
        return FormationActive(g, config.formation, config.active, bearings, scale)
    raise ValueError(f"unknown layer {kind}")
