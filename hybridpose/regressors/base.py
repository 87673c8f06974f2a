"""The regressor contract: one image in, a pose ``Measurement`` out, no prior needed
(:class:`PoseRegressor` fulfils :class:`hybridpose.contracts.RegressorContract`)."""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

from ..core import Frame, Measurement


class PoseRegressor(ABC):
    """A single-image pose estimator (role ``"regressor"`` in :mod:`hybridpose.registry`).

    ``predict(frame, roi)`` returns a :class:`~hybridpose.core.Measurement` whose pose is
    ``T_cam_obj`` (metres, OpenCV camera frame), whose covariance is 6×6 over the right
    perturbation ``[ω (rad), v (m)]`` and whose quality is in 0..1; ``pose`` is None (and ``lost``
    True) when the object is not found. Backends may take further keyword arguments that a caller
    can leave out (the keypoint checkpoints: ``sun_direction_cam``, the sun where it is known).
    """

    name: str = "regressor"
    # fields of the hybrid's policy (hybridpose.hybrid_config.HybridConfig) this regressor's maker
    # recommends, applied where a caller gives none: a part's fitted network carries reacquire_deg
    hybrid_config: Mapping[str, object] = MappingProxyType({})

    @abstractmethod
    def predict(self, frame: Frame, roi: tuple[int, int, int, int] | None = None) -> Measurement:
        """Pose of the object in ``frame``.

        Args:
            frame: the image (H, W, 3) uint8 RGB and its camera.
            roi: optional box ``(x, y, w, h)`` in pixels around the object (e.g. the tracker's
                predicted projection); without it the regressor finds the object itself.
        """

    def candidates(self, frame: Frame, roi: tuple[int, int, int, int] | None = None, limit: int = 4) -> Candidates:
        """:meth:`predict`'s measurement first, then up to ``limit`` other distinct poses of the object in
        ``frame`` that a start may try where the tracker refuses the first (here none, and no
        :attr:`Candidates.sightings`: backends that see several answers, as the keypoint checkpoints do,
        offer them)."""
        return Candidates([self.predict(frame, roi)])


class Candidates(list):
    """:meth:`PoseRegressor.candidates`'s answer: a list of :class:`~hybridpose.core.Measurement` (the
    regressor's own answer first), and ``sightings``: the poses (``T_cam_obj``, metres) at which the
    regressor's other looks over the same frame saw the object (a keypoint network's whole-frame and
    tile passes, its other proposals) — a tuple, empty where nothing else saw it, None where the
    regressor does not say. Where an answer stands alone, nothing else in the frame backs it."""

    def __init__(self, found=(), sightings=None):
        super().__init__(found)
        self.sightings: tuple | None = None if sightings is None else tuple(sightings)


def check_roi(roi, frame: Frame) -> tuple[float, float, float, float] | None:
    """Validate ``roi`` = (x, y, w, h) pixels: finite, positive size, overlapping the image."""
    if roi is None:
        return None
    r = np.asarray(roi, dtype=np.float64)
    if r.shape != (4,) or not np.all(np.isfinite(r)):
        raise ValueError(f"roi: expected (x, y, w, h) pixels, got {roi!r}")
    x, y, w, h = r
    W, H = frame.camera.width, frame.camera.height
    if w <= 0 or h <= 0:
        raise ValueError(f"roi: expected positive width and height in pixels, got {roi!r}")
    if x >= W or y >= H or x + w <= 0 or y + h <= 0:
        raise ValueError(f"roi: {roi!r} lies outside the {W}×{H} image")
    return float(x), float(y), float(w), float(h)
