"""What :class:`~hybridpose.estimator.HybridEstimator` needs of each role's backend, written once.

Each role's base class (:class:`~hybridpose.trackers.base.Tracker`,
:class:`~hybridpose.regressors.base.PoseRegressor`, :class:`~hybridpose.fusion.base.Fusion`) fulfils
its contract; a third-party backend derives from it, or gives every member of the contract itself.
The estimator checks the members once, when it is built (a ``TypeError`` names those missing), then
reads them directly: an ability is an attribute, never guessed from a method's parameters.
``isinstance(backend, TrackerContract)`` works for trackers and regressors; a fusion's ``estimate``
exists only after its first ``reset``, so :func:`check_backend` (which does not read it) is the check.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, runtime_checkable

import numpy as np

from .core import Estimate, Frame, Measurement
from .geometry import Pose
from .objects import ObjectModel


@runtime_checkable
class TrackerContract(Protocol):
    """A frame-to-frame tracker.

    Attributes:
        object: the tracked CAD model (the CNN checks are cropped around its projection), or None.
        lost_quality: the backend's own lost threshold (0..1; the estimator never asks a fit to hold
            below it), or None where it has none.
        tells_covered: whether ``track`` can tell that something stands in front of the object (the
            estimator then asks for ``covered_lost_quality`` instead of ``lost_quality``).

    ``track`` takes every keyword below and ignores those it cannot use: ``search_px``, how far
    (px) to search from a coarse ``prior`` such as a CNN pose (a backend with a fixed range ignores
    it); ``lost_quality`` / ``covered_lost_quality``, this call's lost threshold in general / where
    it sees the object covered. It returns a :class:`~hybridpose.core.Measurement` whose ``pose`` is
    None exactly when it is lost. Optional: ``trial()``, a copy whose fits leave the tracker as it is
    (:meth:`hybridpose.trackers.base.Tracker.trial`): the estimator fits a frame a second time from
    a network's pose on it, else on the tracker itself, which then learns that pose's view.
    """

    object: ObjectModel | None
    lost_quality: float | None
    tells_covered: bool

    def init(self, frame: Frame, pose: Pose) -> None: ...

    def track(self, frame: Frame, prior: Pose | None = None, search_px: float | None = None,
              lost_quality: float | None = None, covered_lost_quality: float | None = None) -> Measurement: ...

    def reset(self) -> None: ...


@runtime_checkable
class RegressorContract(Protocol):
    """A single-image pose regressor.

    Attributes:
        hybrid_config: the :class:`~hybridpose.hybrid_config.HybridConfig` fields its maker
            recommends (empty for most; a part's fitted network carries ``reacquire_deg``).

    ``predict(frame, roi)``: ``roi`` an optional box ``(x, y, w, h)`` px around the object; a
    :class:`~hybridpose.core.Measurement` with ``pose`` None where the object is not found. Optional:
    ``candidates(frame, roi, limit)``, that measurement and up to ``limit`` other poses a start may try
    (:meth:`~hybridpose.regressors.base.PoseRegressor.candidates`).
    """

    hybrid_config: Mapping[str, object]

    def predict(self, frame: Frame, roi: tuple[int, int, int, int] | None = None) -> Measurement: ...


@runtime_checkable
class FusionContract(Protocol):
    """A pose + twist filter or smoother.

    Attributes:
        estimate: the current belief (:class:`~hybridpose.core.Estimate`).
        initial_twist_covariance: (6, 6) the twist's covariance at ``reset`` ([rad/s, m/s]²): how
            far a track may have moved between two CNN answers while lost.

    ``reset(pose, covariance, timestamp, twist=None)`` starts over; ``predict(timestamp)`` returns the
    predicted :class:`~hybridpose.core.Estimate`; ``update(measurement)`` returns whether the gate
    accepted it.
    """

    estimate: Estimate
    initial_twist_covariance: np.ndarray

    def reset(self, pose: Pose, covariance: np.ndarray, timestamp: float, twist: np.ndarray | None = None) -> None: ...

    def predict(self, timestamp: float) -> Estimate: ...

    def update(self, measurement: Measurement) -> bool: ...


CONTRACTS = {"tracker": TrackerContract, "regressor": RegressorContract, "fusion": FusionContract}


def members(contract: type) -> tuple[str, ...]:
    """The attribute and method names a contract asks for, in the order written."""
    methods = [n for n, v in vars(contract).items() if callable(v) and not n.startswith("_")]
    return (*getattr(contract, "__annotations__", {}), *methods)


def check_backend(role: str, backend) -> None:
    """TypeError naming what ``backend`` lacks of ``role``'s contract (:data:`CONTRACTS`), and how
    to get it; nothing where it has every member (methods callable)."""
    contract = CONTRACTS[role]
    present = set(dir(backend))  # not hasattr: a property such as a fusion's estimate may not be ready yet
    missing = [m for m in members(contract)
               if m not in present or (m not in contract.__annotations__ and not callable(getattr(backend, m)))]
    if missing:
        base = {"tracker": "hybridpose.trackers.base.Tracker", "regressor": "hybridpose.regressors.base.PoseRegressor",
                "fusion": "hybridpose.fusion.base.Fusion"}[role]
        raise TypeError(f"{role}: {type(backend).__name__} lacks {', '.join(missing)} of the {role} contract "
                        f"(hybridpose.contracts.{contract.__name__}); derive it from {base} or give them")
