"""How a keypoint checkpoint turns one image into a pose: the options of every stage after the network,
checked once and frozen (:class:`KeypointOptions`). Direct (VGG) models take the whole frame and
ignore them.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

from .keypoint_pnp import OUTLIER_STRATEGIES

PASSES = (1, 2, "auto")
TURNS = ("auto", "always", "off")
EXPERT_RULES = ("pooled", "pooled-unsure", "quality", "replace")
DETECTIONS = ("auto", "bright", "network")
# Edge-on expert (edge_on_expert): where the first estimate is within EXPERT_BELOW_DEG of edge-on (the
# views that hold most of the gross errors), the network passes and PnP are made again by a second
# keypoint network trained on near edge-on views only; both estimates are measured and the one of
# higher quality is returned (expert_rule "quality"). Its estimate alone ("replace") fixed as many
# views as it broke; gate and rule chosen on test seeds 128–131 among 8–25° (docs/decisions.md).
EXPERT_BELOW_DEG = 8.0


@dataclass(frozen=True)
class KeypointOptions:
    """The stages after a keypoint network's pass, for :class:`~hybridpose.regressors.predictor.CheckpointRegressor`.

    Attributes:
        check_twins: compare the PnP pose with its box-symmetric twins on the
            image edges and keep the best supported (:mod:`hybridpose.regressors.verify`); needs
            the object's mesh: ``object``, or the built-in object the checkpoint names.
        refine_edges: finish with the moving-edge fit of the trackers
            (:func:`~hybridpose.edges.fit_edges`) from the CNN pose: CNN + model-based
            refinement, as pose refiners do. With a twin head the other box twins are fitted too
            when the head is unsure (p < ``TWIN_SURE``), and the head's belief is weighed against
            each fit's edge support; without one, the best-supported fit of all twins wins. A fit
            of quality < 0.5 is not used. The covariance stays the calibrated PnP one
            (conservative for a refined pose).
        passes: network passes: 1, 2 (the second on the crop re-centred on the
            first pose; the one whose PnP keeps more inliers wins) or ``"auto"`` (default: the
            second pass only where the first one's twin head is below ``SECOND_PASS_BELOW``, or
            its PnP failed; models without a twin head then always make two).
        turns: test-time in-plane turns of the first crop (``TURNS_DEG``, one
            batch; the pass whose PnP keeps the most keypoints wins): ``"auto"`` (default) only
            where the first pass's PnP keeps fewer than ``TURNS_BELOW_INLIERS`` of them or fails,
            ``"always"``, or ``"off"``.
        pnp_outliers: how PnP sets outlying keypoints aside (:func:`solve_pnp`'s
            ``outliers``): ``"drop-worst"`` (default) or ``"ransac"`` (the older path).
        turn_pnp_outliers: the same for the passes on the turned crops (``turns``):
            ``"drop-worst-only"`` (default): no RANSAC there, a turned pass
            that no majority of its keypoints agrees with gives no pose (on 6000 fresh views −0.19° mean
            rotation, 95 % CI −0.45…+0.04, and 2.2 ms/view less than RANSAC there); None: ``pnp_outliers``.
        verifier: with a twin head and ``check_twins``: a twin-verifier checkpoint
            (``hybridpose train-verifier``, :mod:`hybridpose.regressors.twin_verifier`) whose belief
            joins the twin choice where the head is unsure (``log p + TWIN_EDGE_WEIGHT · log quality
            + VERIFIER_WEIGHT · log p_verifier``); ``"auto"`` (default): the one shipped in the
            package when it was trained on this object; None: none.
        mirror_verifier: with a twin head and ``refine_edges``: a verifier trained
            with ``hybridpose train-verifier --mirrors`` that, where the returned pose is within
            ``MIRROR_BELOW_DEG`` of edge-on, scores it against its box twins and the twins of its
            edge-on mirror (:func:`~hybridpose.regressors.verify.edge_on_mirror`) and replaces it
            by one it believes with p ≥ ``MIRROR_SWITCH_P``; ``"auto"`` (default): the one shipped
            in the package (``weights/mirror_verifier.pt``) when there is one for this object;
            None: none.
        edge_on_expert: a second keypoint checkpoint for the same object and
            keypoints, trained on near edge-on views (``hybridpose render --elevation 0,25``), that
            re-estimates the pose where the first estimate is within ``expert_below_deg`` of edge-on
            (:func:`~hybridpose.objects.view_elevation_deg`), on the same detection. ``"auto"``: the
            one shipped in the package (``weights/edge_on_expert.pt``, default) when there is one for
            this object; None: none. The covariance stays this checkpoint's calibrated one.
        expert_below_deg: the view elevation (°, estimated) below which the expert runs.
        expert_rule: ``"pooled-unsure"`` (default): ``"pooled"`` where either twin head
            is below ``VERIFIER_SURE`` (``TWIN_SURE`` without a verifier), ``"quality"`` elsewhere;
            ``"quality"``: both estimates go through the twin choice and the edge fit, and the
            measurement of higher quality is returned; ``"pooled"``: the best-scored of every box
            twin of both estimates (falls back to ``"quality"`` without edge
            fits or a twin head); ``"replace"``: the expert's estimate replaces the first one.
        detection: without a ``roi``: how the object is found: ``"bright"`` (the
            sunlit pixels on black space, :mod:`.detection`), ``"network"`` (network passes on the
            whole frame and on overlapping tiles of it, then an estimate in the crop around each pose
            they give, the one PnP fits best kept (:mod:`.network_detection`): for a checkpoint
            trained with ``--full-view`` on cluttered backgrounds; the bright detection where they
            find nothing),
            ``"auto"`` (default): ``"network"`` for such a checkpoint, else ``"bright"``.
        fine_tiles: with ``"network"`` detection, where no estimate from the whole frame and its tiles
            reaches PnP quality ``FINE_BELOW``, look again at finer tiles and take an estimate found
            there from quality ``FINE_ACCEPT`` (:mod:`.network_detection`): a part a few dozen pixels
            across in a large frame. Default False: it doubles the cost of a call without a ``roi``
            for a small gain (``docs/decisions.md``).
        dim_fallback: without a ``roi``: where :func:`detect_bright_object` finds
            nothing, or its box gives no plausible pose, look for a faintly lit object
            (:func:`detect_dim_object`) and estimate on its box (default True).
        max_depth_m: an estimate whose object origin lies deeper than this (metres
            along the optical axis) is no plausible pose (like one whose size does not fit the box):
            None (default): no limit; ``"auto"``: ``DEPTH_BEYOND_TRAINED`` × the far end of the depths
            the checkpoint was trained on, where it records them (``dataset["distance_range_m"]``;
            checkpoints record them), else no limit. The edge-on expert uses the same
            limit. Trades translation outliers for lost views: see ``DEPTH_BEYOND_TRAINED``.

    Names in capitals are constants of :mod:`hybridpose.regressors.predictor`, each with its evidence.
    :meth:`run_time` lists the fields that may change on a loaded regressor
    (:meth:`~hybridpose.regressors.predictor.CheckpointRegressor.configure`).
    """

    check_twins: bool = True
    refine_edges: bool = True
    passes: int | str = "auto"
    turns: str = "auto"
    pnp_outliers: str = "drop-worst"
    turn_pnp_outliers: str | None = "drop-worst-only"
    verifier: str | Path | None = "auto"
    mirror_verifier: str | Path | None = "auto"
    edge_on_expert: str | Path | None = "auto"
    expert_below_deg: float = EXPERT_BELOW_DEG
    expert_rule: str = "pooled-unsure"
    dim_fallback: bool = True
    fine_tiles: bool = False
    max_depth_m: float | str | None = None
    detection: str = "auto"

    def __post_init__(self) -> None:
        set_ = object.__setattr__.__get__(self)  # frozen: normalise through object.__setattr__
        set_("check_twins", bool(self.check_twins))
        set_("refine_edges", bool(self.refine_edges))
        set_("dim_fallback", bool(self.dim_fallback))
        set_("fine_tiles", bool(self.fine_tiles))
        passes = int(self.passes) if isinstance(self.passes, str) and self.passes.isdigit() else self.passes
        if passes not in PASSES or isinstance(passes, bool):
            raise ValueError(f"passes: expected 1 or 2 network passes, or 'auto', got {self.passes!r}")
        set_("passes", passes)
        if self.turn_pnp_outliers is None:
            set_("turn_pnp_outliers", self.pnp_outliers)
        for name, choices, expected in (("turns", TURNS, "one of"), ("pnp_outliers", OUTLIER_STRATEGIES, "one of"),
                                        ("turn_pnp_outliers", OUTLIER_STRATEGIES, "None or one of"),
                                        ("expert_rule", EXPERT_RULES, "one of"), ("detection", DETECTIONS, "one of")):
            if getattr(self, name) not in choices:
                raise ValueError(f"{name}: expected {expected} {', '.join(choices)}, got {getattr(self, name)!r}")
        try:
            below = float(self.expert_below_deg)
        except (TypeError, ValueError):
            below = float("nan")
        if not 0.0 <= below <= 90.0:
            raise ValueError(f"expert_below_deg: expected a view elevation in [0, 90] degrees, got {self.expert_below_deg!r}")
        set_("expert_below_deg", below)
        depth = self.max_depth_m
        if depth is not None and not (isinstance(depth, str) and depth == "auto"):
            try:
                limit = float(depth)
            except (TypeError, ValueError):
                limit = float("nan")
            if isinstance(depth, bool) or not limit > 0 or limit == float("inf"):
                raise ValueError(f"max_depth_m: expected a positive depth in metres, 'auto' or None, got {depth!r}")
            set_("max_depth_m", limit)

    @staticmethod
    def run_time() -> tuple[str, ...]:
        """The fields read at each prediction (the others decide what is loaded with the checkpoint)."""
        return ("passes", "turns", "pnp_outliers", "turn_pnp_outliers", "expert_below_deg", "expert_rule",
                "dim_fallback", "fine_tiles", "max_depth_m", "detection")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))
