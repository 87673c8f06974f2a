"""Built-in desk parts for the hand-held scenes: ``cube`` (8.5 cm, the size of ViSP's tutorial cubes
and of a printed cube held in a hand) and ``box`` (18 × 11 × 7 cm, a parcel or a tea box). Plain
boxes in metres, centred on their middle, their symmetries found from the mesh
(23 and 3 turns besides the identity)."""
from __future__ import annotations

import trimesh

from ..registry import register
from .base import ObjectModel

CUBE_EDGE_M = 0.085  # the hand-held scenes' printed cube
BOX_EXTENTS_M = (0.18, 0.11, 0.07)  # a plain box of a tea box's proportions


@register("object", "cube")
def cube() -> ObjectModel:
    """An 8.5-cm cube (any print on it is not in the model: 23 symmetric turns)."""
    return ObjectModel("cube", trimesh.creation.box((CUBE_EDGE_M,) * 3))


@register("object", "box")
def box() -> ObjectModel:
    """An 18 × 11 × 7 cm box (3 symmetric turns)."""
    return ObjectModel("box", trimesh.creation.box(BOX_EXTENTS_M))
