"""The cues of the combined tracker, each a component with one small contract (:class:`Cue`)."""
from .base import Cue
from .edges import EdgeCue
from .region import RegionCue
from .texture import TextureCue

CUES = {"edges": EdgeCue, "texture": TextureCue, "region": RegionCue}

__all__ = ["CUES", "Cue", "EdgeCue", "RegionCue", "TextureCue"]
