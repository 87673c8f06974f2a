"""Trained checkpoints as :class:`PoseRegressor` backends (role ``"regressor"``).

``create("regressor", "default")`` loads the checkpoint shipped in the package
(``hybridpose/regressors/weights/default.pt``, how it was made: ``weights/README.md``); every other
name needs ``checkpoint=PATH`` from ``hybridpose train --model NAME``.

Keypoint models (the path step by step: ``docs/cnn.md``): one network pass on a crop around the
``roi`` or, without one, around the object found by :mod:`.detection`; keypoints → PnP → pose. Where
PnP drops keypoints, the same crop turned in-plane by ±20°/±40° too (``turns="auto"``); a second pass
on the crop centred on the pose where the twin head is unsure (``passes="auto"``); near edge-on, a
second network trained on such views (``edge_on_expert``); the end-for-end twin chosen by the twin
head, edge fits and the twin verifier; the pose refined by an edge fit. The calibrated PnP covariance,
widened or narrowed by the measurement's quality band, is its uncertainty. Direct models (the paper's
VGGs) take the whole frame resized (and the parallel model the crop around ``roi``, else around the
detected object, else around its own translation estimate).
"""
from __future__ import annotations

import logging
import warnings
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

from ..core import LOST_COVARIANCE, Frame, Measurement
from ..geometry.crops import crop_box, crop_image
from ..geometry import Camera, Pose, as_unit_direction
from ..objects import view_elevation_deg
from ..registry import register
from .base import PoseRegressor, check_roi
from .checkpoints import WEIGHTS_DIR, load_checkpoint, shipped_checkpoint
from .detection import CROP_MARGIN, detect_bright_object, detect_dim_object
from .direct import bounded_image, direct_pose
from .calibration import PNP_THRESHOLD, SIGMA_FLOOR_PX, UNCALIBRATED_SCALE, uncalibrated_record, pnp_covariance, quality_factor
from .keypoint_pnp import solve_pnp
from .options import KeypointOptions
from .verify import MIRROR_BELOW_DEG, edge_on_mirror
from .engines import ENGINES, keypoint_engine
from .models import available_models, build_model, fold_batch_norm, model_kind, torch_device

log = logging.getLogger(__name__)

QUALITY_RMS = 0.02  # RMS reprojection error (fraction of the crop side) at which quality falls to 1/e
FOV_TOLERANCE = 0.02  # direct models: relative focal (per image size) difference still accepted
# Keypoint models crop a virtual camera around the object, so another field of view changes only the
# perspective inside the crop. Measured with the shipped checkpoint (150 in-view renders per camera,
# 640×480, distances scaled with the focal): fine from 0.5× to 2.7× the trained focal per image size
# (docs/decisions.md); outside that range a warning says it was not measured.
KEYPOINT_FOCAL_RANGE = (0.5, 2.7)
REFINE_SEARCH_PX = 16
REFINE_MIN_QUALITY = 0.5
# The twin choice (see _refine). Tuned on test views 0–399, confirmed on 400–999 (docs/decisions.md):
# the head is right whenever it is sure (no wrong twin above p = 0.99 in 400 views), so its twin alone is
# fitted from p ≥ TWIN_SURE; below, every twin is fitted and the head's belief is weighed against the
# edge support, log p + TWIN_EDGE_WEIGHT · log quality. Edge support alone picks worse than the head
# (20 % vs 9 % of views > 30°): wrong-twin fits lock onto the truss's symmetric chords.
TWIN_SURE = 0.8
TWIN_EDGE_WEIGHT = 8.0
VERIFIER_WEIGHT = 1.0
# with a twin verifier the head counts as sure only from this probability (chosen on the seed-101 test
# set)
VERIFIER_SURE = 0.95
# with a twin verifier, the weight of the edge fits' quality in the twin choice: 0 chooses by head ×
# verifier before any fit, and only the chosen twin is edge-fitted (one fit instead of four, ≈ 1.7 ms
# a view on average). Not the default: with it (and VERIFIER_WEIGHT 0.5) 98 views of 5000 were > 30°
# off against 95 with the edges weighed in (docs/decisions.md).
VERIFIER_EDGE_WEIGHT = TWIN_EDGE_WEIGHT
# passes="auto": the second, re-centred network pass only where the first pass's twin head is below
# this (≈ 15 % of views): it buys most of what two passes always would (docs/decisions.md)
# for ≈ 1 ms on average instead of 7.
SECOND_PASS_BELOW = 0.9
# PnP on near-collinear keypoints (edge-on views) can return the object several times too far away
# (13 m for a truss at 1 m in the seed-101 test set): a pose whose projected keypoints span more
# than this factor less (or more) than the box the network was shown is not a measurement
SIZE_RATIO_MAX = 3.0
# Depth gate (max_depth_m="auto"): an end-on truss near the camera and the truss lying across the view far
# away fill the same small box, and PnP on those keypoints can land on the far one (18.4 m for a truss at
# 1.19 m on seed 155): size_ratio cannot tell them apart. A keypoint network sees scale-normalised crops
# and still works somewhat beyond the depths it was trained on, so only a pose deeper than this factor
# times the far end of the training depths (recorded in the checkpoint) is refused. An option, off by
# default: on fresh sets it changed nothing under the 40° cone and, under side- and back-light,
# cut the mean translation error 0.22 → 0.14 m but lost 28 more views (one of them within 30°), +0.84°
# mean rotation as a lost view counts 180° (docs/decisions.md)
DEPTH_BEYOND_TRAINED = 3.0
# turns="auto": where the first pass's PnP keeps fewer than TURNS_BELOW_INLIERS of the keypoints, the
# network also sees its crop turned in-plane by TURNS_DEG (one batch) and the pass whose PnP keeps the
# most keypoints (then the lowest RMS) wins. The failures are keypoints in near edge-on views that a
# slightly turned crop gets right; larger turns (90°, 180°) move the sunlit side where the network
# never saw it and are worse alone (docs/decisions.md). 0.8 (≤ 9 of 12 kept: 19 %
# of the views) rather than 0.9 (≤ 10: 36 %) since PnP drops the worst keypoint: 3 ms less per view,
# and on 5000 fresh views 94 vs 97 > 30° off, 4.64° vs 4.76° mean (a test written before those views were rendered).
TURNS_DEG = (20.0, -20.0, 40.0, -40.0)
TURNS_BELOW_INLIERS = 0.8
# Sun turn: a network trained with the sun on one side of its images (the shipped default: within 40°
# of (0.6, 0.4, 0.7), light from the upper left) errs three times as often when the light crosses the
# image from elsewhere. Where the caller knows the sun (sun sensor, or ephemeris and attitude), the
# crop is turned in-plane so that the light crosses it as in training, when the light's image azimuth
# is more than SUN_TURN_BEYOND_DEG from the training sun's (nearer, the training data had such light
# and a turn only resamples the crop). Chosen among full / beyond 45° / beyond 60° / the excess beyond
# 30–60° on 800 tuning views (docs/decisions.md).
SUN_TURN_BEYOND_DEG = 60.0
# Edge-on mirror check (mirror_verifier): the returned pose is replaced by one of its box twins or of
# its edge-on mirror's only where the mirror verifier believes that one with at least this probability
# (chosen on test seeds 128–131 for the mirror verifier that was tried; lower ones broke more views than
# they fixed, and even this one did not pay on fresh sets, so none is shipped: docs/decisions.md)
MIRROR_SWITCH_P = 0.95
# expert_rule "pooled": the weight of log q_pnp (each estimate's PnP quality) added to the twin score
# when the twins of both estimates are pooled (chosen on test seeds 128–141, where 0–2 measured alike:
# 4.56° → 4.23° mean; with the first expert it did not pay on fresh seeds 146–149, 4.55° → 4.58°; with
# today's it did, but cost ≈ 1 ms more). Used by
# "pooled" and "pooled-unsure" (below)
POOLED_PNP_WEIGHT = 1.0
# expert_rule "pooled-unsure" (the default): pooled only where a twin head is unsure (below
# VERIFIER_SURE, TWIN_SURE without a verifier), the quality rule elsewhere: where both heads are sure the pooled
# rule's verifier batch is the cost that put it over 20 ms, and it changes little there. Shipped on a test written
# before its 8000 fresh views were rendered (commit 16da16f): 10.69° → 10.27° mean (CI −0.69…−0.15; 40° cone 5.46° → 4.78°), 24.1 →
# 23.6 ms a view; seed 100 3.30° → 3.05° at 17.9 ms (docs/decisions.md)


def twin_scores(prob, quality, edge_weight: float = TWIN_EDGE_WEIGHT, verifier_prob=None,
                verifier_weight: float = VERIFIER_WEIGHT) -> np.ndarray:
    """The twin choice's score ``log p + edge_weight · log quality [+ verifier_weight · log p_verifier]``
    (the higher, the likelier).

    ``prob``: the twin head's probabilities, ``quality``: the edge fits' quality in [0, 1] (0 where a
    fit failed), ``verifier_prob``: the twin verifier's probabilities (None: not used); same shape,
    (..., n_twins), any leading batch shape. The benchmark that tunes the rule calls this too, so the
    two cannot drift apart.
    """
    prob = np.asarray(prob, dtype=float)
    quality = np.asarray(quality, dtype=float)
    if prob.shape != quality.shape:
        raise ValueError(f"prob and quality: expected the same shape (..., n_twins), got {prob.shape} and "
                         f"{quality.shape}")
    score = np.log(prob + 1e-6) + edge_weight * np.log(quality + 1e-3)
    if verifier_prob is not None:
        verifier_prob = np.asarray(verifier_prob, dtype=float)
        if verifier_prob.shape != prob.shape:
            raise ValueError(f"verifier_prob: expected the shape of prob {prob.shape}, got {verifier_prob.shape}")
        score = score + verifier_weight * np.log(verifier_prob + 1e-6)
    return score


def trained_light_azimuth_deg(lighting: dict | None) -> float | None:
    """The image azimuth (°, :func:`~hybridpose.objects.light_azimuth_deg`) of a training set's sun
    (``{"sun_direction_cam", "sun_cone_deg"}`` as :func:`~hybridpose.regressors.train_data.dataset_info`
    records it), or None when the set had light from every side (its sun cone holds the optical axis)
    or no record."""
    if not lighting or lighting.get("sun_direction_cam") is None:
        return None
    from ..objects import light_azimuth_deg

    d = np.asarray(lighting["sun_direction_cam"], dtype=np.float64)
    d = d / np.linalg.norm(d)
    if np.degrees(np.arccos(np.clip(d[2], -1.0, 1.0))) <= float(lighting.get("sun_cone_deg", 0.0)):
        return None
    return light_azimuth_deg(d)


def sun_turn_deg(sun_direction_cam, trained_azimuth_deg: float | None, beyond_deg: float = SUN_TURN_BEYOND_DEG) -> float:
    """In-plane crop turn (°, OpenCV's sense: counter-clockwise on screen) that makes light travelling
    along ``sun_direction_cam`` cross the crop at ``trained_azimuth_deg``, when the two azimuths differ
    by more than ``beyond_deg`` (else 0, as without a sun or a training azimuth)."""
    if sun_direction_cam is None or trained_azimuth_deg is None:
        return 0.0
    from ..objects import light_azimuth_deg

    # turning the crop by a (counter-clockwise) moves every direction in it, the light's too, by -a in
    # light_azimuth_deg's clockwise sense
    delta = (light_azimuth_deg(sun_direction_cam) - trained_azimuth_deg + 180.0) % 360.0 - 180.0
    return float(delta) if abs(delta) > beyond_deg else 0.0


def size_ratio(pose: Pose, points_m: np.ndarray, camera: Camera, box) -> float:
    """How far the image extent of ``points_m`` under ``pose`` is from ``box``'s: ≥ 1, ∞ if behind the camera.

    Args:
        pose: T_cam_obj (metres). points_m: (N, 3) object points, metres. camera: the (undistorted)
            camera of the image. box: (x, y, w, h) pixels, the region the object was found in
            (detection or caller's ``roi``).
    Returns:
        max(d / d_box, d_box / d) for the diagonals d of the projected points' bounding box and
        d_box of ``box``.
    """
    try:
        uv = camera.project(points_m, pose)
    except ValueError:  # a point at or behind the camera plane: no pose of a visible object
        return float("inf")
    d = float(np.hypot(*(uv.max(0) - uv.min(0))))
    d_box = float(np.hypot(box[2], box[3]))
    if d <= 0 or d_box <= 0:
        return float("inf")
    return max(d / d_box, d_box / d)


def wants_turns(turns: str, res) -> bool:
    """Whether the first crop is also tried turned (``TURNS_DEG``) after a pass with PnP result ``res``
    (None: PnP failed), under the ``turns`` option (:class:`~hybridpose.regressors.options.KeypointOptions`)."""
    if turns == "auto":
        return res is None or res.inlier_ratio < TURNS_BELOW_INLIERS
    return turns == "always"


def wants_second_pass(passes, res, prob) -> bool:
    """Whether a second, re-centred network pass follows a first one with PnP result ``res`` (None:
    failed) and twin-head probabilities ``prob`` (None: no head), under the ``passes`` option."""
    if passes == "auto":
        return res is None or prob is None or float(prob.max()) < SECOND_PASS_BELOW
    return passes == 2


def _to_tensor(img: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float().div_(255.0)[None]


class CheckpointRegressor(PoseRegressor):
    """A trained network from :func:`hybridpose.regressors.train.train` as a regressor backend.

    Keypoint models' ``Measurement.quality`` (0..1) = PnP inlier share × exp(−RMS reprojection error
    / 2 % of the crop side) × the twin head's probability of the twin returned (no last factor
    without a head). The covariance (the calibrated PnP one, times the factor of the quality's band
    where the calibration has bands: :func:`~hybridpose.regressors.calibration.quality_scale`)
    covers the error up to the object's box twins; the quality is
    what says a pose may be turned end for end: on the held-out truss test set a gate at 0.3 keeps
    ≈ 88 % of the views with almost none > 30° off (``hybridpose eval``, "accuracy by quality").

    Args:
        checkpoint: ``best.pt`` of a training run.
        object: the :class:`ObjectModel` the caller tracks; refused when it is not the object the
            checkpoint was trained on (diameter differs by more than 1 %).
        threads: torch intra-op threads for inference (None = leave torch's setting).
        expect_model: refuse a checkpoint of another architecture (used by the named backends).
        device: where the network runs: ``"cpu"`` (default; the small models are fastest there,
            one image at a time) or ``"cuda"`` / ``"cuda:N"`` (the VGG models). Detection, PnP and
            the edge fit always run on the CPU.
        options: a :class:`~hybridpose.regressors.options.KeypointOptions` (keypoint models: every
            stage after the network; direct models ignore it); None: the defaults.
        **overrides: fields of ``options`` to change (``passes=2``, ``edge_on_expert=None`` ...).
        engine: keypoint models — what runs the network (:mod:`hybridpose.regressors.engines`):
            ``"auto"`` (default): ONNX Runtime on the CPU — on the 8-bit model ``hybridpose quantize``
            wrote beside the checkpoint where it was made from this very file (shipped for the ``default``
            and its expert; non-inferior to float32 on 48 000 fresh views, 3.6 ms/view faster), else in float32
            (≈ 1.6× as fast as torch at batch 1 on an AVX2 CPU, same outputs to float rounding,
            equivalent accuracy on 16 000 fresh views) —, torch where it cannot run or on a GPU; ``"onnxruntime"``
            (float32; an error where it cannot run); ``"torch"``; ``"onnxruntime-int8"`` (the 8-bit model;
            an error without one). The edge-on expert is asked for the same engine (with ``"auto"`` it
            resolves it on its own file); the twin verifiers run on torch with ``"torch"``, else on ONNX Runtime in
            float32 (:class:`~hybridpose.regressors.twin_verifier.TwinVerifier`'s ``engine="auto"``). Direct models always run on torch.
    """

    def __init__(self, checkpoint, object=None, threads: int | None = None, expect_model: str | None = None,
                 device="cpu", engine: str = "auto", options: KeypointOptions | None = None, **overrides) -> None:
        if options is not None and not isinstance(options, KeypointOptions):
            raise TypeError(f"options: expected a KeypointOptions, got {type(options).__name__}")
        unknown = sorted(set(overrides) - set(KeypointOptions.names()))
        if unknown:
            raise TypeError(f"{', '.join(unknown)}: not an option of a checkpoint regressor (KeypointOptions fields: "
                            f"{', '.join(KeypointOptions.names())})")
        opts = replace(options or KeypointOptions(), **overrides)
        self.path = Path(checkpoint)
        ck = load_checkpoint(self.path)
        for key in ("config", "model", "build"):
            if key not in ck:
                raise ValueError(f"{self.path}: not a hybridpose regressor checkpoint (no {key!r})")
        self.model_name = ck["config"]["model"]
        if self.model_name not in available_models():
            raise ValueError(f"{self.path}: checkpoint is for unknown model {self.model_name!r}")
        if expect_model is not None and expect_model != self.model_name:
            raise ValueError(f"{self.path}: checkpoint holds a {self.model_name!r} model, not {expect_model!r}")
        self.name = self.model_name
        self.kind = model_kind(self.model_name)
        # built without weights (the meta device), then given the checkpoint's tensors: initialising a
        # parallel VGG-19's 200 M weights only to overwrite them took 6 of the 8 s of its load here
        with torch.device("meta"):
            self.net = build_model(self.model_name, **ck["build"])
        try:
            self.net.load_state_dict(ck["model"], assign=True)
        except RuntimeError as exc:
            raise ValueError(f"{self.path}: weights do not fit the {self.model_name!r} network ({exc})") from exc
        self.device = torch_device(device)
        # channels-last convolutions are ≈ 15 % faster on the CPU at batch 1 (same weights, same math)
        self.memory_format = torch.channels_last if self.device.type == "cpu" else torch.contiguous_format
        fold_batch_norm(self.net.eval()).to(self.device, memory_format=self.memory_format)
        if threads is not None:  # before the engine: its first session is made at this thread count
            torch.set_num_threads(int(threads))
        if engine not in ENGINES:
            raise ValueError(f"engine: expected one of {', '.join(ENGINES)}, got {engine!r}")
        if engine.startswith("onnxruntime") and self.kind != "keypoints":
            raise ValueError(f"engine={engine!r}: {self.path} holds a direct {self.model_name!r} model, which "
                             "runs on torch (engine='torch' or 'auto'; device='cuda' where there is a GPU)")
        # what the caller asked for: the edge-on expert resolves "auto" on its own file (its 8-bit model, or not)
        self.engine_request = engine
        # keypoint models only: the direct (VGG) ones are GPU models, and take the whole frame
        self.engine = (keypoint_engine(engine, self.net, self.device, int(ck["config"]["image_size"]), self.memory_format,
                                       checkpoint=self.path) if self.kind == "keypoints" else None)
        # the keypoints' 3D coordinates for PnP, once (the network's buffer may live on the GPU)
        self.keypoints_m = (self.net.keypoints_m.cpu().numpy().astype(np.float64)
                            if hasattr(self.net, "keypoints_m") else None)
        self.image_size = int(ck["config"]["image_size"])
        self.full_view = float(ck["config"].get("full_view", 0.0))  # share of whole-frame training crops
        self.dataset = ck.get("dataset", {})
        # the image azimuth of the training sun (None: lit from every side, or not recorded)
        self.trained_light_azimuth_deg = trained_light_azimuth_deg(self.dataset.get("lighting"))
        self.calibration = ck.get("calibration")
        self.twins = [Pose.from_matrix(np.asarray(m)) for m in ck.get("twins", [])]
        self.has_twin_head = getattr(self.net, "twin_head", None) is not None and bool(self.twins)
        if self.calibration is None:
            log.warning("%s: no covariance calibration stored; covariances are inflated ×%g", self.path, UNCALIBRATED_SCALE)
        if object is not None:
            self._check_object(object)
        self.twin_check = None
        if (opts.check_twins or opts.refine_edges) and self.kind == "keypoints":
            from ..objects import load_builtin

            obj = object if object is not None else load_builtin(self.dataset.get("object"))
            if obj is not None:
                from .verify import TwinCheck

                self.twin_check = TwinCheck(obj)
        self._set_options(opts)
        self.verifier = self._load_verifier(opts.verifier)
        self.mirror_verifier = (self._load_verifier(opts.mirror_verifier, "mirror_verifier.pt") if opts.refine_edges
                                else None)
        self.expert_object = None  # the object whose view elevation gates the expert
        self.expert = self._load_expert(opts.edge_on_expert, object)

    def configure(self, **changes) -> None:
        """Change run-time options (:meth:`KeypointOptions.run_time`: passes, turns, ...) of this loaded
        regressor; those that decide what is loaded with the checkpoint (twin check, edge fit,
        verifiers, expert) need a new regressor. The edge-on expert keeps the options it was loaded with."""
        loaded = sorted(set(changes) - set(KeypointOptions.run_time()))
        if loaded:
            raise ValueError(f"{', '.join(loaded)}: decided when the checkpoint is loaded; make a new regressor "
                             f"(configure changes {', '.join(KeypointOptions.run_time())})")
        self._set_options(replace(self.options, **changes))

    def _set_options(self, opts: KeypointOptions) -> None:
        """Keep ``opts`` and resolve what depends on the checkpoint: the detection and the depth gate."""
        self.options = opts
        detection = opts.detection
        if detection == "auto":
            detection = "network" if self.full_view > 0 else "bright"
        self.detection = detection
        self.max_depth_m = self._depth_limit(opts.max_depth_m)

    def _depth_limit(self, max_depth_m) -> float | None:
        """The depth gate in metres (None: none) from the (checked) ``max_depth_m`` option."""
        if isinstance(max_depth_m, str):  # "auto"
            trained = self.dataset.get("distance_range_m")
            return None if not trained else DEPTH_BEYOND_TRAINED * float(max(trained))
        return max_depth_m

    def _load_expert(self, expert, obj) -> "CheckpointRegressor | None":
        """The edge-on expert as a bare keypoint estimator (no twin check, edge fit or verifiers of its
        own: this regressor's run on its estimate), or None. Refused, naming the file, unless it is a
        keypoint model with a twin head for the same keypoints and twins as this one."""
        if expert is None or expert is False or self.kind != "keypoints":
            return None
        if isinstance(expert, str) and expert == "auto":
            path = WEIGHTS_DIR / "edge_on_expert.pt"
            if not path.is_file():
                return None
            try:
                return self._load_expert(path, obj)
            except ValueError as exc:  # the shipped one is for the built-in truss's keypoints
                log.info("shipped edge_on_expert.pt not used: %s", exc)
                return None
        path = Path(expert)
        bare = replace(self.options, check_twins=False, refine_edges=False, verifier=None, mirror_verifier=None,
                       edge_on_expert=None, max_depth_m=self.max_depth_m)
        reg = CheckpointRegressor(path, object=obj, device=self.device, engine=self.engine_request, options=bare)
        same = (reg.kind == "keypoints" and reg.keypoints_m is not None and self.keypoints_m is not None
                and reg.keypoints_m.shape == self.keypoints_m.shape and np.allclose(reg.keypoints_m, self.keypoints_m)
                and len(reg.twins) == len(self.twins)
                and all(a.allclose(b, atol=1e-6) for a, b in zip(reg.twins, self.twins)))
        if not same or (self.has_twin_head and not reg.has_twin_head):
            raise ValueError(f"edge_on_expert: {path} is not a keypoint model for the keypoints and twins of "
                             f"{self.path}" + ("" if reg.has_twin_head or not self.has_twin_head else " (no twin head)"))
        if obj is None:
            from ..objects import load_builtin

            obj = self.twin_check.view.object if self.twin_check is not None else load_builtin(self.dataset.get("object"))
        if obj is None:
            raise ValueError(f"edge_on_expert: gating it needs the model of the object {self.path} was trained on "
                             f"({self.dataset.get('object')!r}): pass object=")
        self.expert_object = obj
        return reg

    def _load_verifier(self, verifier, shipped: str = "twin_verifier.pt"):
        if verifier is None or verifier is False or self.twin_check is None or not self.has_twin_head:
            return None
        from .twin_verifier import TwinVerifier

        obj = self.twin_check.view.object
        if isinstance(verifier, str) and verifier == "auto":
            path = WEIGHTS_DIR / shipped
            if not path.is_file():
                return None
            try:
                return TwinVerifier(path, obj, engine=self._verifier_engine())
            except ValueError as exc:  # the shipped ones are for the built-in truss
                log.info("shipped %s not used: %s", shipped, exc)
                return None
        return TwinVerifier(verifier, obj, engine=self._verifier_engine())

    def _verifier_engine(self) -> str:
        """The twin verifiers' engine: torch with a network on torch, else ONNX Runtime where it runs
        (float32 also beside the 8-bit keypoint model)."""
        return "torch" if self.engine.name == "torch" else "auto"

    # --- checks ----------------------------------------------------------------------------------
    def _check_object(self, obj) -> None:
        d = self.dataset.get("diameter_m")
        if d is not None and abs(obj.diameter - d) > 0.01 * d:
            raise ValueError(
                f"object: {self.path} was trained on {self.dataset.get('object')!r} (diameter {d:.3f} m), "
                f"not on {obj.name!r} (diameter {obj.diameter:.3f} m); train a checkpoint for your object"
            )

    def _check_camera(self, camera: Camera) -> None:
        """Direct models learned one field of view (another one: ValueError); keypoint models normalise
        it away with the crop (outside ``KEYPOINT_FOCAL_RANGE`` of the trained one: a warning)."""
        cam = self.dataset.get("camera")
        if not cam:
            return
        if self.kind == "keypoints":
            ratio = (camera.fx / camera.width) / (cam["fx"] / cam["width"])
            low, high = KEYPOINT_FOCAL_RANGE
            if not low <= ratio <= high:
                warnings.warn(
                    f"frame.camera: fx/width = {camera.fx / camera.width:.3f} is {ratio:.2f}× what {self.path} was "
                    f"trained at ({cam['fx'] / cam['width']:.3f}); keypoint models were measured from {low}× to "
                    f"{high}× only — check the accuracy on your camera (render data with --camera, hybridpose eval)",
                    UserWarning, stacklevel=3)
            return
        for f, n, key in ((camera.fx, camera.width, "fx"), (camera.fy, camera.height, "fy")):
            trained = cam[key] / cam["width" if key == "fx" else "height"]
            if abs(f / n - trained) > FOV_TOLERANCE * trained:
                raise ValueError(
                    f"frame.camera: {self.path} was trained for {key}/size = {trained:.4f}, the frame's camera has "
                    f"{f / n:.4f}; a direct regressor only works at its training field of view (render data with --camera)"
                )

    # --- inference -------------------------------------------------------------------------------
    @staticmethod
    def _batch(*images: np.ndarray) -> torch.Tensor:
        """(B, 3, H, W) float in [0, 1] on the CPU from B (H, W, 3) uint8 RGB images of one size."""
        return torch.cat([_to_tensor(img) for img in images]) if len(images) > 1 else _to_tensor(images[0])

    def _tensor(self, *images: np.ndarray) -> torch.Tensor:
        """:meth:`_batch` on the network's device, in its memory layout."""
        return self._batch(*images).to(self.device).contiguous(memory_format=self.memory_format)

    def _sun_turn(self, sun_direction_cam) -> float:
        """The crop turn (°, :func:`sun_turn_deg`) for the caller's sun (checked; None: no turn)."""
        if sun_direction_cam is None:
            return 0.0
        sun = as_unit_direction(sun_direction_cam, "sun_direction_cam",
                                "the sunlight travels in the camera frame (x right, y down, z forward)")
        return sun_turn_deg(sun, self.trained_light_azimuth_deg)

    def predict(self, frame: Frame, roi=None, sun_direction_cam=None) -> Measurement:
        """The pose of the object in ``frame`` (no prior needed).

        Args:
            frame: the image (H, W, 3) uint8 RGB and its camera.
            roi: (x, y, w, h) pixels where the object is (e.g. a tracker's predicted box); None: found
                by detection.
            sun_direction_cam: where known (sun sensor, or ephemeris and attitude), the (3,) direction
                the sunlight travels in the camera frame (x right, y down, z forward; any length).
                Keypoint models then turn their crop so that the light crosses it from the side
                their training data was lit from (:func:`sun_turn_deg`; checkpoints that record
                their training sun, as the shipped ``default`` does). The direct (VGG) models take
                the whole frame and ignore it.
        """
        if not isinstance(frame, Frame):
            raise TypeError(f"frame: expected a hybridpose Frame, got {type(frame).__name__}")
        roi = check_roi(roi, frame)
        sun_turn = self._sun_turn(sun_direction_cam)
        self._check_camera(frame.camera)
        with torch.no_grad():
            if self.kind == "keypoints":
                return self._predict_keypoints(frame, roi, sun_turn)
            return self._predict_direct(frame, roi)

    def _crop(self, image: np.ndarray, K: np.ndarray, cx: float, cy: float, side: float):
        return crop_image(image, K, cx, cy, side, (self.image_size, self.image_size))

    def _keypoint_pass(self, image, K, box, turns: bool = False, sun_turn: float = 0.0):
        """One network pass on ``box``: (PnP result in the head's most likely twin, keypoints (N, 2)
        in crop pixels, crop K, twin order, twin probabilities). The order lists the symmetry
        indices (0 = the keypoints' own pose, k = ``twins[k-1]``) most likely first by the twin head
        (fixed 0, 1, 2, 3 without one); the result's pose is already turned to the first. The
        probabilities (T,), indexed like the symmetries, are the head's softmax (None without one).
        With ``turns`` the crop turned by ``TURNS_DEG`` is tried too where :func:`wants_turns` says
        so, and the pass whose PnP keeps the most keypoints (then the lowest RMS) is returned. Every
        turn starts from ``sun_turn`` (°, :func:`sun_turn_deg`)."""
        crop, K_crop = self._crop(image, K, *box)
        best = self._solve_turned(crop, K_crop, (sun_turn,))[0]
        if turns and wants_turns(self.options.turns, best[0]):
            turned = self._solve_turned(crop, K_crop, [sun_turn + a for a in TURNS_DEG], self.options.turn_pnp_outliers)
            best = min([best, *turned], key=_pass_rank)
        res, uv, order, prob = best
        return res, uv, K_crop, order, prob

    def _solve_turned(self, crop: np.ndarray, K_crop: np.ndarray, angles_deg, outliers: str | None = None) -> list:
        """Network passes on ``crop`` turned in-plane by each of ``angles_deg`` (about its centre, one
        batch), keypoints mapped back to the unturned crop, then PnP (``outliers``: :func:`solve_pnp`'s,
        default ``pnp_outliers``): [(result or None, keypoints (N, 2) in crop pixels, twin order, twin
        probabilities)] per angle."""
        outliers = self.options.pnp_outliers if outliers is None else outliers
        centre = ((self.image_size - 1) / 2.0,) * 2
        turns = [np.vstack([cv2.getRotationMatrix2D(centre, float(a), 1.0), [0.0, 0.0, 1.0]]) for a in angles_deg]
        crops = [crop if a == 0 else cv2.warpAffine(crop, A[:2], crop.shape[1::-1], flags=cv2.INTER_LINEAR,
                                                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
                 for a, A in zip(angles_deg, turns)]
        uv_all, _, twin = self.engine(self._batch(*crops))
        out = []
        for i, A in enumerate(turns):
            back = np.linalg.inv(A)
            uv = uv_all[i].float().cpu().numpy().astype(np.float64) @ back[:2, :2].T + back[:2, 2]
            res = solve_pnp(uv, self.keypoints_m, K_crop, threshold_px=PNP_THRESHOLD * self.image_size,
                            outliers=outliers)
            order, prob = list(range(len(self.twins) + 1)), None
            if self.has_twin_head:
                prob = torch.softmax(twin[i].float(), 0).cpu().numpy()
                order = [int(k) for k in np.argsort(-prob, kind="stable")]
                if res is not None and order[0] > 0:  # undo the twin the keypoints follow (half-turns are their own inverses)
                    res = replace(res, pose=res.pose @ self.twins[order[0] - 1])
            out.append((res, uv, order, prob))
        return out

    def _box_around(self, pose: Pose | None, uv, K_crop, K) -> tuple[float, float, float] | None:
        """Crop box (cx, cy, side) in frame pixels around the projected keypoints."""
        if pose is not None:
            p = (pose @ self.keypoints_m) @ K.T
            pts = p[:, :2] / p[:, 2:3]
        else:  # PnP failed: the raw coarse keypoints, mapped back to the frame
            A = K @ np.linalg.inv(K_crop)
            pts = uv @ A[:2, :2].T + A[:2, 2]
        lo, hi = pts.min(0), pts.max(0)
        if not np.all(np.isfinite(lo)) or np.any(hi - lo < 1):
            return None
        return crop_box((lo[0], lo[1], hi[0] - lo[0] + 1, hi[1] - lo[1] + 1), CROP_MARGIN)

    def _keypoint_estimate(self, image: np.ndarray, cam: Camera, roi, sun_turn: float = 0.0):
        """The network passes and PnP before any twin check or edge fit on an undistorted ``image``:
        (PnP result turned to the head's twin, twin order, twin probabilities, crop side in pixels),
        or None when nothing is found or PnP gives no plausible pose (see :meth:`_keypoint_pass` for
        order and probabilities; ``sun_turn``: its crop turn, °). With an edge-on expert: its
        estimate under ``expert_rule="replace"``, the first one under the other rules."""
        ests = self._keypoint_estimates(image, cam, roi, sun_turn)
        return ests[0] if ests else None

    def _keypoint_estimates(self, image: np.ndarray, cam: Camera, roi, sun_turn: float = 0.0) -> list:
        """The estimates (as :meth:`_keypoint_estimate`) a measurement is made from: the first one
        (on the bright detection or ``roi``; with ``dim_fallback``, on :func:`detect_dim_object`'s box
        where that gave none); where an edge-on expert runs (the first estimate within
        ``expert_below_deg`` of edge-on) the expert's instead (``expert_rule="replace"``) or the first
        and the expert's (the other rules); the first alone where the expert finds nothing;
        [] where nothing is found."""
        seen = roi if roi is not None else self._detect(image, cam)
        est = None if seen is None else self._estimate_in(image, cam, seen, sun_turn)
        if est is None and roi is None and self.options.dim_fallback:
            # nothing bright, or its box gave no plausible pose: the faintly lit object, if any
            dim = detect_dim_object(image)
            if dim is not None and dim != seen:
                seen, est = dim, self._estimate_in(image, cam, dim, sun_turn)
        if est is None:
            return []
        if self.expert is None or view_elevation_deg(est[0].pose, self.expert_object) >= self.options.expert_below_deg:
            return [est]
        # near edge-on: the expert's passes on the same detection
        other = self.expert._estimate_in(image, cam, seen, sun_turn)
        if other is None:
            return [est]
        return [other] if self.options.expert_rule == "replace" else [est, other]

    def _detect(self, image: np.ndarray, cam: Camera):
        """Box (x, y, w, h) px where the object is, without a prior (``detection``), or None."""
        if self.detection == "network":
            box = self._network_box(image, cam)
            if box is not None:
                return box
        return detect_bright_object(image)

    def _network_box(self, image: np.ndarray, cam: Camera):
        """Box of the keypoints' projection at the pose one network pass on the whole frame gives
        (coarse: the object may be a few dozen pixels of the network's input), or None."""
        whole = ((cam.width - 1) / 2, (cam.height - 1) / 2, float(max(cam.width, cam.height)))
        res = self._keypoint_pass(image, cam.K, whole)[0]
        if res is None:
            return None
        pts = res.pose @ self.keypoints_m
        if np.any(pts[:, 2] <= 0.05):
            return None
        uv = cam.project(self.keypoints_m, res.pose)
        (x0, y0), (x1, y1) = np.maximum(uv.min(0), 0.0), np.minimum(uv.max(0), [cam.width - 1.0, cam.height - 1.0])
        if x1 - x0 < 2 or y1 - y0 < 2:
            return None
        return float(x0), float(y0), float(x1 - x0), float(y1 - y0)

    def _estimate_in(self, image: np.ndarray, cam: Camera, seen, sun_turn: float = 0.0):
        """:meth:`_keypoint_estimate` on a box ``seen`` (x, y, w, h, pixels) where the object was found."""
        K = cam.K
        box = crop_box(seen, CROP_MARGIN)
        res, uv, K_crop, order, prob = self._keypoint_pass(image, K, box, turns=True, sun_turn=sun_turn)
        # second pass on the crop centred on the first pose (the crop the network knows best)
        again = (self._box_around(res.pose if res is not None else None, uv, K_crop, K)
                 if wants_second_pass(self.options.passes, res, prob) else None)
        if again is not None:
            res2, _, _, order2, prob2 = self._keypoint_pass(image, K, again, sun_turn=sun_turn)
            if res2 is not None and (res is None or res2.inlier_ratio >= res.inlier_ratio):
                res, order, prob = res2, order2, prob2
        if res is None or size_ratio(res.pose, self.keypoints_m, cam, seen) > SIZE_RATIO_MAX:
            return None
        if self.max_depth_m is not None and res.pose.t[2] > self.max_depth_m:
            return None
        return res, order, prob, self.image_size

    def twin_candidates(self, frame: Frame, roi=None, sun_direction_cam=None):
        """The box twins the twin choice weighs, before any edge fit: (poses T_cam_obj, head
        probabilities), both in the head's order (most likely first), or None when the object is
        not found. What a twin verifier is shown at inference, so what it is trained on
        (``hybridpose train-verifier --estimates-from``). Keypoint models with a twin head only;
        ``roi`` and ``sun_direction_cam`` as in :meth:`predict`. With an edge-on expert (any rule but
        "replace") these are the first network's twins (the expert's estimate gets its own)."""
        if not isinstance(frame, Frame):
            raise TypeError(f"frame: expected a hybridpose Frame, got {type(frame).__name__}")
        self.require_twin_head()
        roi = check_roi(roi, frame)
        sun_turn = self._sun_turn(sun_direction_cam)
        image, cam = self._undistorted(frame)
        with torch.no_grad():
            est = self._keypoint_estimate(image, cam, roi, sun_turn)
        if est is None:
            return None
        res, order, prob, _ = est
        return self._twin_starts(res.pose, order), np.asarray([prob[k] for k in order])

    def require_twin_head(self) -> None:
        """Raise ValueError (naming the checkpoint) unless this is a keypoint model with a twin head."""
        if self.kind != "keypoints" or not self.has_twin_head:
            raise ValueError(f"{self.path}: twin candidates need a keypoint model with a twin head, "
                             f"this is {self.model_name!r}" + ("" if self.kind != "keypoints" else " without one"))

    def _twin_starts(self, pose: Pose, order) -> list[Pose]:
        """Every box twin of ``pose`` (which is twin ``order[0]`` of the keypoints' pose P), in
        ``order``: twin k of P is pose @ S[order[0]] @ S[k]."""
        S = [Pose.identity(), *(self.twins or self.twin_check.twins)]
        first = S[order[0]]
        return [pose] + [pose @ first @ S[k] for k in order[1:]]

    def _predict_keypoints(self, frame: Frame, roi, sun_turn: float = 0.0) -> Measurement:
        image, cam = self._undistorted(frame)
        ests = self._keypoint_estimates(image, cam, roi, sun_turn)
        if not ests:
            return self._lost(frame)
        if len(ests) == 2 and self._pools(ests):
            return self._pooled_measure(frame, image, cam, ests)
        # with the expert's estimate too (expert_rule "quality"): the measurement of higher quality, the first on a
        # tie; an estimate whose quality cannot exceed the best one's is not edge-fitted at all (same result)
        best = None
        for est in ests:
            if best is not None and self._quality_bound(est) <= best.quality:
                continue
            m = self._measure(frame, image, cam, est)
            if best is None or m.quality > best.quality:
                best = m
        return best

    def _pools(self, ests) -> bool:
        """Whether ``expert_rule`` pools these two estimates' twins (see ``EXPERT_RULES``)."""
        if self.options.expert_rule == "pooled-unsure":
            sure = TWIN_SURE if self.verifier is None else VERIFIER_SURE
            return self._can_pool(ests) and any(float(np.max(est[2])) < sure for est in ests)
        return self.options.expert_rule == "pooled" and self._can_pool(ests)

    def _can_pool(self, ests) -> bool:
        """Whether the pooled twin choice applies: edge fits and a twin head on every estimate."""
        return self.twin_check is not None and self.options.refine_edges and self.options.check_twins and all(
            est[2] is not None for est in ests)

    def _pooled_measure(self, frame: Frame, image: np.ndarray, cam: Camera, ests) -> Measurement:
        """The measurement from the best of every box twin of every estimate (``expert_rule="pooled"``):
        the candidate of highest ``log p_head + VERIFIER_EDGE_WEIGHT · log q_fit + VERIFIER_WEIGHT ·
        log p_verifier + POOLED_PNP_WEIGHT · log q_pnp`` (:func:`twin_scores` of its own estimate's head
        and verifier, plus its estimate's PnP quality :func:`_pnp_quality`). Candidates are edge-fitted in order of their
        score with a perfect fit (an upper bound) until no unfitted one can win: the result is that of
        fitting all of them (≈ 2.3 fits instead of 8 near edge-on views). Quality and covariance are
        those :meth:`_measure` gives the chosen estimate and twin."""
        from ..edges.fit import fit_edges, to_gray

        undistorted = Frame(image, cam, frame.timestamp, frame.index)
        view = self.twin_check.view
        edge_weight = TWIN_EDGE_WEIGHT if self.verifier is None else VERIFIER_EDGE_WEIGHT
        candidates = []  # (upper bound, estimate, start pose, head p, verifier p, q_pnp)
        starts_of = [self._twin_starts(est[0].pose, est[1]) for est in ests]
        # both estimates' twins in one verifier batch
        vers = (self.verifier.probabilities_of_sets(image, cam.K, starts_of) if self.verifier is not None
                else [None] * len(ests))
        for est, starts, ver in zip(ests, starts_of, vers):
            _, order, prob, _ = est
            head = np.array([prob[k] for k in order])
            q_pnp = _pnp_quality(est)
            bound = (twin_scores(head, np.ones(len(starts)), edge_weight=edge_weight, verifier_prob=ver)
                     + POOLED_PNP_WEIGHT * np.log(q_pnp + 1e-3))
            for j, start in enumerate(starts):
                candidates.append((float(bound[j]), est, start, head[j], None if ver is None else ver[j], q_pnp))
        candidates.sort(key=lambda c: -c[0])
        gray = to_gray(image)
        best, best_score = None, -np.inf
        for bound, est, start, head_p, ver_p, q_pnp in candidates:
            if best_score >= bound:
                break
            fit = fit_edges(view, undistorted, start, gray=gray, search_px=REFINE_SEARCH_PX)
            score = float(twin_scores([head_p], [0.0 if fit is None else fit.quality], edge_weight=edge_weight,
                                      verifier_prob=None if ver_p is None else [ver_p])[0]
                         + POOLED_PNP_WEIGHT * np.log(q_pnp + 1e-3))
            if score > best_score:
                pose = fit.pose if fit is not None and fit.quality >= REFINE_MIN_QUALITY else start
                best, best_score = (est, pose, head_p, q_pnp), score
        est, pose, belief, quality = best
        checked = self._mirror_check(undistorted, pose)
        if checked is not None and checked[2] > 0:
            pose, belief, _ = checked
        return self._keypoint_measurement(frame, est[0], pose, quality * belief)

    def _keypoint_measurement(self, frame: Frame, res, pose: Pose, quality: float) -> Measurement:
        """The measurement of ``pose`` from the PnP result ``res``: the calibrated PnP covariance times
        the factor of ``quality``'s band (poorer measurements spread wider than their PnP covariance
        says: calibration.quality_scale)."""
        cal = self.calibration or uncalibrated_record(self.kind)
        cov = pnp_covariance(res.information, res.rms_px, cal["scale"], cal.get("sigma_floor_px", SIGMA_FLOOR_PX))
        return Measurement(pose=pose, covariance=cov * quality_factor(cal, quality), quality=quality,
                           source=f"regressor:{self.name}", timestamp=frame.timestamp)

    def _quality_bound(self, est) -> float:
        """An upper bound of the quality :meth:`_measure` gives ``est``: its PnP terms times the twin
        head's largest probability (1 where a mirror verifier may replace the belief)."""
        q, prob = _pnp_quality(est), est[2]
        return q if prob is None or self.mirror_verifier is not None else q * float(np.max(prob))

    def _measure(self, frame: Frame, image: np.ndarray, cam: Camera, est) -> Measurement:
        """The measurement from one keypoint estimate on the undistorted ``image`` (camera ``cam``):
        twin choice, edge fit, mirror check, calibrated covariance, quality."""
        res, order, prob, _ = est
        quality = _pnp_quality(est)
        pose, twin = res.pose, order[0]
        # the covariance cannot say "maybe turned end for end" (a 180° mode, not a Gaussian spread): the
        # quality does, through the belief in the returned twin (a gate on it removes most of the gross
        # errors): the head's, or the mirror verifier's where it replaced the pose
        belief = None
        if self.twin_check is not None:
            undistorted = Frame(image, cam, frame.timestamp, frame.index)
            if self.options.refine_edges:
                pose, twin = self._refine(undistorted, pose, order, prob)
                checked = self._mirror_check(undistorted, pose)
                if checked is not None and checked[2] > 0:
                    pose, belief, _ = checked
            elif self.options.check_twins and not self.has_twin_head:
                pose, _, flipped = self.twin_check.best(undistorted, pose)
                if flipped:  # the keypoints disagreed with the image: the pose is right, the fit is not
                    quality *= 0.5
        if belief is None and prob is not None:
            belief = float(prob[twin])
        if belief is not None:
            quality *= belief
        return self._keypoint_measurement(frame, res, pose, quality)

    def _refine(self, frame: Frame, pose: Pose, order, prob=None) -> tuple[Pose, int]:
        """Edge fit from the CNN pose and, with ``check_twins``, from its box twins: (pose, the
        symmetry index of the twin it settled on, as in ``order``).

        With a twin head (``prob``): when the head is sure (p ≥ ``TWIN_SURE``, ``VERIFIER_SURE``
        with a verifier) only its twin is fitted; else every twin is weighed (fitted until none left
        can win: :meth:`_best_fitted_twin`), and the one with the best
        ``log p + TWIN_EDGE_WEIGHT · log quality`` wins (with a verifier: ``log p +
        VERIFIER_EDGE_WEIGHT · log quality + VERIFIER_WEIGHT · log p_verifier``, and where
        ``VERIFIER_EDGE_WEIGHT`` is 0 the twin is chosen before fitting and only it is fitted).
        Without one, the fit most model edges agree with (inliers × quality) wins. A winning fit
        below ``REFINE_MIN_QUALITY`` is not used (the unrefined pose of its twin with a head, the CNN
        pose without).
        """
        from ..edges.fit import fit_edges, to_gray

        view = self.twin_check.view
        gray = to_gray(frame.image)
        if not self.options.check_twins:
            starts = [pose]
        else:
            starts = self._twin_starts(pose, order)
            if prob is not None and prob[order[0]] >= (TWIN_SURE if self.verifier is None else VERIFIER_SURE):
                starts = starts[:1]
        twin_of = list(order[:len(starts)])  # symmetry index of each start
        head_prob = None if prob is None else [prob[k] for k in twin_of]
        # the verifier's strip is cut along the head's choice, as in its training (any twin gives it)
        ver = (self.verifier.probabilities(frame.image, frame.camera.K, starts)
               if prob is not None and self.verifier is not None and len(starts) > 1 else None)
        edge_weight = TWIN_EDGE_WEIGHT if ver is None else VERIFIER_EDGE_WEIGHT
        if ver is not None and edge_weight == 0:  # the fits would not change the choice: fit the chosen twin only
            k = int(np.argmax(twin_scores(head_prob, np.ones(len(starts)), edge_weight=0.0, verifier_prob=ver)))
            starts, twin_of, head_prob, ver = [starts[k]], [twin_of[k]], [head_prob[k]], None
        if prob is not None:
            best, fit = self._best_fitted_twin(view, frame, gray, starts, head_prob, ver, edge_weight)
        else:
            fits = [fit_edges(view, frame, p, gray=gray, search_px=REFINE_SEARCH_PX) for p in starts]
            ranked = [(f.samples * f.quality, i) for i, f in enumerate(fits) if f]
            best = max(ranked)[1] if ranked else 0
            fit = fits[best]
        if fit is not None and fit.quality >= REFINE_MIN_QUALITY:
            return fit.pose, twin_of[best]
        # a poor fit: the twin the head and edges chose, unrefined; without a head, the CNN's own pose
        return (starts[best], twin_of[best]) if prob is not None else (pose, order[0])

    @staticmethod
    def _best_fitted_twin(view, frame: Frame, gray, starts, head_prob, ver, edge_weight: float):
        """(index, fit) of the start of highest :func:`twin_scores` after its edge fit — what fitting every
        start and taking the first best score gives, with fewer fits: a fit's quality is at most 1, so
        ``twin_scores`` at quality 1 bounds what a start can reach, and the starts are fitted in the order
        of that bound until the best score so far beats every bound left (where the head is unsure
        ≈ 2 fits instead of 4; the pooled choice prunes its candidates alike)."""
        from ..edges.fit import fit_edges

        # a weight that rewards poor fits has no such bound: then they are all fitted
        bound = (twin_scores(head_prob, np.ones(len(starts)), edge_weight=edge_weight, verifier_prob=ver)
                 if edge_weight >= 0 else np.full(len(starts), np.inf))
        best, best_fit, best_score = 0, None, -np.inf
        for i in sorted(range(len(starts)), key=lambda k: (-bound[k], k)):
            if best_score > bound[i]:
                break
            fit = fit_edges(view, frame, starts[i], gray=gray, search_px=REFINE_SEARCH_PX)
            score = twin_scores([head_prob[i]], [fit.quality if fit else 0.0], edge_weight=edge_weight,
                                verifier_prob=None if ver is None else [ver[i]])[0]
            # the lower index wins a tie, as np.argmax over all of them would
            if score > best_score or (score == best_score and i < best):
                best, best_fit, best_score = i, fit, score
        return best, best_fit

    def _mirror_check(self, frame: Frame, pose: Pose, switch_p: float = MIRROR_SWITCH_P
                      ) -> tuple[Pose, float, int] | None:
        """Where ``pose`` is within ``MIRROR_BELOW_DEG`` of edge-on and a mirror verifier is loaded:
        (pose returned, the verifier's probability of it, its index among the candidates); else None.
        The candidates are ``pose``'s box twins (index 0: ``pose`` itself, 1–3) and those of its
        edge-on mirror (4–7), the strip cut along ``pose``, as ``train-verifier --mirrors`` cuts them
        around the regressor's estimate. The verifier's favourite is returned, edge-fitted where the
        fit reaches ``REFINE_MIN_QUALITY``, when its probability is ≥ ``switch_p``; else ``pose``
        (index 0)."""
        if self.mirror_verifier is None:
            return None
        obj = self.twin_check.view.object
        if view_elevation_deg(pose, obj) >= MIRROR_BELOW_DEG:
            return None
        S = [Pose.identity(), *self.twin_check.twins]
        mirror = edge_on_mirror(pose, obj)
        cands = [pose @ s for s in S] + [mirror @ s for s in S]
        p = self.mirror_verifier.probabilities(frame.image, frame.camera.K, cands, strip_pose=pose)
        k = int(np.argmax(p))
        if k == 0 or p[k] < switch_p:
            return pose, float(p[0]), 0
        from ..edges.fit import fit_edges

        fit = fit_edges(self.twin_check.view, frame, cands[k], search_px=REFINE_SEARCH_PX)
        return (fit.pose if fit is not None and fit.quality >= REFINE_MIN_QUALITY else cands[k]), float(p[k]), k

    def _undistorted(self, frame: Frame) -> tuple[np.ndarray, Camera]:
        cam = frame.camera
        if not any(cam.dist):
            return frame.image, cam
        image = cv2.undistort(frame.image, cam.K, np.asarray(cam.dist))
        return image, Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)

    def _predict_direct(self, frame: Frame, roi) -> Measurement:
        image, cam = self._undistorted(frame)
        out = direct_pose(self.net, self.model_name, image, cam, self.image_size, self._tensor, roi,
                          float(self.dataset.get("diameter_m") or 0.5))
        if out is None:
            return self._lost(frame)
        t, q = out
        cal = self.calibration
        cov = np.asarray((cal if cal and "covariance" in cal else uncalibrated_record(self.kind))["covariance"])
        return Measurement(pose=Pose.from_quat_t(q, t), covariance=cov, quality=1.0, source=f"regressor:{self.name}",
                           timestamp=frame.timestamp)

    def bounded_image(self, frame: Frame) -> np.ndarray:
        """The crop a parallel VGG-19's rotation stream sees in ``frame`` without a roi ((S, S, 3) uint8)."""
        image, cam = self._undistorted(frame)
        return bounded_image(self.net, image, cam, self.image_size, self._tensor, None,
                             float(self.dataset.get("diameter_m") or 0.5))[1]

    def _lost(self, frame: Frame) -> Measurement:
        return Measurement(pose=None, covariance=LOST_COVARIANCE, quality=0.0, source=f"regressor:{self.name}",
                           timestamp=frame.timestamp, lost=True)


def _pnp_quality(est) -> float:
    """The PnP part of a keypoint estimate's quality: inlier share × exp(−RMS / ``QUALITY_RMS`` of its
    own crop side, so estimates at different crop sizes compare)."""
    res, _, _, crop_px = est
    return res.inlier_ratio * float(np.exp(-res.rms_px / (QUALITY_RMS * crop_px)))


def _pass_rank(candidate) -> tuple:
    """Sort key of a network pass (:meth:`CheckpointRegressor._solve_turned`): a PnP pose first, then
    the most keypoints kept, then the lowest RMS reprojection error."""
    res = candidate[0]
    return (1, 0.0, 0.0) if res is None else (0, -res.inlier_ratio, res.rms_px)


def _factory(name: str):
    def make(checkpoint=None, object=None, threads: int | None = None, **options) -> CheckpointRegressor:
        path = checkpoint if checkpoint is not None else shipped_checkpoint(name)
        return CheckpointRegressor(path, object=object, threads=threads, expect_model=name, **options)

    make.__name__ = f"make_{name.replace('-', '_')}"
    make.__doc__ = f"Regressor backend {name!r}: ``checkpoint=PATH`` (default: the shipped one, if any)."
    return make


for _name in available_models():
    register("regressor", _name)(_factory(_name))
