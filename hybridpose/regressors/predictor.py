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
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ..core import LOST_COVARIANCE, Frame, Measurement
from ..geometry import Camera, Pose, as_unit_direction
from ..objects import view_elevation_deg
from ..registry import register
from .base import Candidates, PoseRegressor, check_roi
from .checkpoints import WEIGHTS_DIR, shipped_checkpoint
from .checkpoint_checks import builtin_object, check_camera, check_object, regressor_checkpoint
from .calibration import SIGMA_FLOOR_PX, UNCALIBRATED_SCALE, pnp_covariance, quality_factor, uncalibrated_record
from .detection import detect_dim_object
from .direct import bounded_image, direct_pose
from .engines import ENGINES, keypoint_engine
from .keypoint_passes import KeypointEstimate, KeypointPasses, image_batch, pnp_quality
from .network_detection import distinct_estimates, find_object
from .options import KeypointOptions
from .sun_turn import sun_turn_deg, trained_light_azimuth_deg
from .twin_choice import TwinChoice, twin_starts
from .models import available_models, build_model, fold_batch_norm, model_kind, torch_device

log = logging.getLogger(__name__)


# Depth gate (max_depth_m="auto"): an end-on truss near the camera and the truss lying across the view far
# away fill the same small box, and PnP can land on the far one; a keypoint network still works somewhat
# beyond its training depths, so only poses deeper than this factor times their far end are refused. Off by
# default: it trades translation outliers for lost views (docs/decisions.md, "No depth gate by default").
DEPTH_BEYOND_TRAINED = 3.0
# expert_rule "pooled-unsure" (the default) pools the twins only where a twin head is unsure: where both are
# sure, pooling's verifier batch costs ≈ 1 ms a view and changes little (docs/decisions.md).


class CheckpointRegressor(PoseRegressor):
    """A trained network from :func:`hybridpose.training.train.train` as a regressor backend.

    Keypoint models' ``Measurement.quality`` (0..1) = PnP inlier share × exp(−RMS reprojection error
    / 2 % of the crop side) × the twin head's probability of the twin returned (no last factor
    without a head). The covariance (the calibrated PnP one, times the factor of the quality's band
    where the calibration has bands: :func:`~hybridpose.training.calibrate.quality_scale`)
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
        ck = regressor_checkpoint(self.path, expect_model)
        self.name = self.model_name = ck["config"]["model"]
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
        # the keypoints' 3D coordinates for PnP, once (the network's buffer may live on the GPU)
        self.keypoints_m = (self.net.keypoints_m.cpu().numpy().astype(np.float64)
                            if hasattr(self.net, "keypoints_m") else None)
        self.image_size = int(ck["config"]["image_size"])
        self.full_view = float(ck["config"].get("full_view", 0.0))  # share of whole-frame training crops
        self.dataset = ck.get("dataset", {})
        # the image azimuth of the training sun (None: lit from every side, or not recorded)
        self.trained_light_azimuth_deg = trained_light_azimuth_deg(self.dataset.get("lighting"))
        self.calibration = ck.get("calibration")
        self.hybrid_config = dict(ck.get("hybrid_config") or {})  # the policy its fit recommends (PoseRegressor)
        self.twins = [Pose.from_matrix(np.asarray(m)) for m in ck.get("twins", [])]
        self.has_twin_head = getattr(self.net, "twin_head", None) is not None and bool(self.twins)
        # keypoint models only: the direct (VGG) ones are GPU models, and take the whole frame
        self.passes = (KeypointPasses(keypoint_engine(engine, self.net, self.device, self.image_size, self.memory_format,
                                                      checkpoint=self.path),
                                      self.keypoints_m, self.twins, self.has_twin_head, self.image_size, opts,
                                      unlabelled=self._unlabelled())
                       if self.kind == "keypoints" else None)
        if self.calibration is None:
            log.warning("%s: no covariance calibration stored; covariances are inflated ×%g", self.path, UNCALIBRATED_SCALE)
        if object is not None:
            check_object(self.dataset, self.path, object)
        self.twin_check = None
        if (opts.check_twins or opts.refine_edges) and self.kind == "keypoints":
            obj = object if object is not None else builtin_object(self.dataset)
            if obj is not None:
                from .verify import TwinCheck

                self.twin_check = TwinCheck(obj)
        self._set_options(opts)
        self.verifier = self._load_verifier(opts.verifier)
        self.mirror_verifier = (self._load_verifier(opts.mirror_verifier, "mirror_verifier.pt") if opts.refine_edges
                                else None)
        self.twin_choice = (TwinChoice(self.twin_check, self.twins, self.verifier, self.mirror_verifier)
                            if self.twin_check is not None else None)
        self.expert_object = None  # the object whose view elevation gates the expert
        self.expert = self._load_expert(opts.edge_on_expert, object)

    def _unlabelled(self):
        """(hull planes, gauge) of an unlabelled keypoint net (:mod:`.unlabelled`), else None."""
        return self.net.pnp_geometry() if getattr(self.net, "unlabelled", False) else None

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
        if self.passes is not None:
            self.passes.options, self.passes.max_depth_m = opts, self.max_depth_m

    @property
    def engine(self):
        """What runs a keypoint network (:mod:`.engines`; None for the direct models, which run on torch)."""
        return None if self.passes is None else self.passes.engine

    @engine.setter
    def engine(self, engine) -> None:
        if self.passes is None:
            raise ValueError(f"engine: {self.path} holds a direct {self.model_name!r} model, which runs on torch")
        self.passes.engine = engine

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
            obj = self.twin_check.view.object if self.twin_check is not None else builtin_object(self.dataset)
        if obj is None:
            raise ValueError(f"edge_on_expert: gating it needs the model of the object {self.path} was trained on "
                             f"({self.dataset.get('object')!r}): pass object=")
        self.expert_object = obj
        return reg

    def _load_verifier(self, verifier, shipped: str = "twin_verifier.pt"):
        """The twin verifier ``verifier`` names (:func:`~.twin_verifier.load_verifier`), on torch with a network on
        torch, else ONNX Runtime where it runs (float32 also beside the 8-bit keypoint model); None without a twin head."""
        if self.twin_check is None or not self.has_twin_head:
            return None
        from .twin_verifier import load_verifier

        engine = "torch" if self.engine.name == "torch" else "auto"
        return load_verifier(verifier, self.twin_check.view.object, WEIGHTS_DIR / shipped, engine)

    # --- inference -------------------------------------------------------------------------------
    def tensor(self, *images: np.ndarray) -> torch.Tensor:
        """B (H, W, 3) uint8 RGB images of one size as the network's input: (B, 3, H, W) float in [0, 1]
        on its device, in its memory layout."""
        return image_batch(*images).to(self.device).contiguous(memory_format=self.memory_format)

    def _sun_turn(self, frame: Frame, sun_direction_cam) -> float:
        """The crop turn (°, :func:`sun_turn_deg`) for the caller's sun (checked), else the frame's
        own (:attr:`Frame.sun_direction_cam <hybridpose.core.Frame>`); neither: no turn. ``frame`` checked first."""
        if not isinstance(frame, Frame):
            raise TypeError(f"frame: expected a hybridpose Frame, got {type(frame).__name__}")
        if sun_direction_cam is None:
            sun_direction_cam = frame.sun_direction_cam
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
                the whole frame and ignore it. None: the frame's own
                (:attr:`Frame.sun_direction_cam <hybridpose.core.Frame>`), where it has one.
        """
        sun_turn = self._sun_turn(frame, sun_direction_cam)  # checks the frame first
        roi = check_roi(roi, frame)
        check_camera(self.dataset, self.kind, self.path, frame.camera)
        with torch.no_grad():
            if self.kind == "keypoints":
                return self._predict_keypoints(frame, roi, sun_turn)
            return self._predict_direct(frame, roi)

    def keypoint_estimates(self, frame: Frame, roi=None, sun_direction_cam=None) -> list[KeypointEstimate]:
        """The estimates a keypoint model's measurement is made from, before any twin choice or edge
        fit (``roi`` and ``sun_direction_cam`` as in :meth:`predict`): the first network's on the
        detection or ``roi`` (with ``dim_fallback``, on :func:`detect_dim_object`'s box where that gave
        none); where an edge-on expert runs (the first estimate within ``expert_below_deg`` of
        edge-on) the expert's instead (``expert_rule="replace"``) or the first and the expert's (the
        other rules); the first alone where the expert finds nothing; [] where nothing is found."""
        if self.kind != "keypoints":
            raise ValueError(f"{self.path}: keypoint estimates need a keypoint model, this is {self.model_name!r}")
        sun_turn = self._sun_turn(frame, sun_direction_cam)  # checks the frame first
        roi = check_roi(roi, frame)
        image, cam = self._undistorted(frame)
        with torch.no_grad():
            return self._estimates(image, cam, roi, sun_turn)

    def _estimates(self, image: np.ndarray, cam: Camera, roi, sun_turn: float = 0.0,
                   others: list | None = None) -> list[KeypointEstimate]:
        """:meth:`keypoint_estimates` on the undistorted ``image`` (camera ``cam``), ``sun_turn`` in °;
        ``others``: as :func:`~.network_detection.find_object`'s (the detection's other estimates)."""
        if roi is not None:
            seen, est = roi, self.passes.estimate_in(image, cam, roi, sun_turn)
        else:
            seen, est = find_object(self.passes, image, cam, sun_turn, self.detection == "network",
                                    self.options.fine_tiles, others)
        if est is None and roi is None and self.options.dim_fallback:
            # nothing bright, or its box gave no plausible pose: the faintly lit object, if any
            dim = detect_dim_object(image)
            if dim is not None and dim != seen:
                seen, est = dim, self.passes.estimate_in(image, cam, dim, sun_turn)
        if est is None:
            return []
        if (self.expert is None
                or view_elevation_deg(est.result.pose, self.expert_object) >= self.options.expert_below_deg):
            return [est]
        # near edge-on: the expert's passes on the same detection
        other = self.expert.passes.estimate_in(image, cam, seen, sun_turn)
        if other is None:
            return [est]
        return [other] if self.options.expert_rule == "replace" else [est, other]

    def twin_candidates(self, frame: Frame, roi=None, sun_direction_cam=None):
        """The box twins the twin choice weighs, before any edge fit: (poses T_cam_obj, head
        probabilities), both in the head's order (most likely first), or None when the object is
        not found. What a twin verifier is shown at inference, so what it is trained on
        (``hybridpose train-verifier --estimates-from``). Keypoint models with a twin head only;
        ``roi`` and ``sun_direction_cam`` as in :meth:`predict`. With an edge-on expert (any rule but
        "replace") these are the first network's twins (the expert's estimate gets its own)."""
        self.require_twin_head()
        sun_turn = self._sun_turn(frame, sun_direction_cam)  # checks the frame first
        roi = check_roi(roi, frame)
        image, cam = self._undistorted(frame)
        with torch.no_grad():
            ests = self._estimates(image, cam, roi, sun_turn)
        if not ests:
            return None
        est = ests[0]
        twins = self.twins or self.twin_check.twins
        return twin_starts(est.result.pose, est.order, twins), np.asarray([est.prob[k] for k in est.order])

    def require_twin_head(self) -> None:
        """Raise ValueError (naming the checkpoint) unless this is a keypoint model with a twin head."""
        if self.kind != "keypoints" or not self.has_twin_head:
            raise ValueError(f"{self.path}: twin candidates need a keypoint model with a twin head, "
                             f"this is {self.model_name!r}" + ("" if self.kind != "keypoints" else " without one"))

    def candidates(self, frame: Frame, roi=None, limit: int = 4, sun_direction_cam=None) -> Candidates:
        """:meth:`predict`'s measurement first, then, for a keypoint model finding the part itself (no
        ``roi``), up to ``limit`` other poses its passes found in the frame, distinct from it and from
        each other (:func:`~.network_detection.distinct_estimates`), best PnP fit first: where the
        tracker's edges refuse the first, a start tries these; ``sightings``: every other pass's and
        proposal's pose in the frame. Arguments as :meth:`predict`."""
        if self.kind != "keypoints" or roi is not None:
            return Candidates([self.predict(frame, roi, sun_direction_cam)])
        sun_turn = self._sun_turn(frame, sun_direction_cam)
        check_camera(self.dataset, self.kind, self.path, frame.camera)
        others: list = []
        image, cam = self._undistorted(frame)  # once: the first answer and the others' measurements share it
        undistorted = Frame(image, cam, frame.timestamp, frame.index)
        with torch.no_grad():
            first = self._predict_keypoints(undistorted, None, sun_turn, others)
            rest = distinct_estimates(others, first.pose, self.keypoints_m, cam, limit)
            return Candidates([first, *(self._measure(undistorted, undistorted, est) for est in rest)],
                              sightings=[est.result.pose for _, est in others])

    def _predict_keypoints(self, frame: Frame, roi, sun_turn: float = 0.0, others: list | None = None) -> Measurement:
        image, cam = self._undistorted(frame)
        ests = self._estimates(image, cam, roi, sun_turn, others)
        if not ests:
            return self._lost(frame)
        undistorted = Frame(image, cam, frame.timestamp, frame.index)
        if len(ests) == 2 and self._pools(ests):
            est, pose, belief = self.twin_choice.pooled(undistorted, ests)
            return self._checked_measurement(frame, undistorted, est, pose, pnp_quality(est) * belief)
        # with the expert's estimate too (expert_rule "quality"): the measurement of higher quality, the first on a
        # tie; an estimate whose quality cannot exceed the best one's is not edge-fitted at all (same result)
        best = None
        for est in ests:
            if best is not None and self._quality_bound(est) <= best.quality:
                continue
            m = self._measure(frame, undistorted, est)
            if best is None or m.quality > best.quality:
                best = m
        return best

    def _pools(self, ests: list[KeypointEstimate]) -> bool:
        """Whether ``expert_rule`` pools these two estimates' twins (see ``EXPERT_RULES``): only with
        edge fits and a twin head on every estimate."""
        can_pool = (self.twin_choice is not None and self.options.refine_edges and self.options.check_twins
                    and all(est.prob is not None for est in ests))
        if self.options.expert_rule == "pooled-unsure":
            return can_pool and any(float(np.max(est.prob)) < self.twin_choice.sure_from for est in ests)
        return self.options.expert_rule == "pooled" and can_pool

    def _checked_measurement(self, frame: Frame, undistorted: Frame, est: KeypointEstimate, pose: Pose,
                             quality: float) -> Measurement:
        """The measurement of the chosen ``pose`` after the edge-on mirror check (which, where it
        replaces the pose, puts its verifier's belief in the quality instead of the head's)."""
        checked = self.twin_choice.mirror_check(undistorted, pose)
        if checked is not None and checked[2] > 0:
            pose, belief, _ = checked
            quality = pnp_quality(est) * belief
        return self._keypoint_measurement(frame, est.result, pose, quality)

    def _keypoint_measurement(self, frame: Frame, res, pose: Pose, quality: float) -> Measurement:
        """The measurement of ``pose`` from the PnP result ``res``: the calibrated PnP covariance times
        the factor of ``quality``'s band (poorer measurements spread wider than their PnP covariance
        says: calibration.quality_scale)."""
        cal = self.calibration or uncalibrated_record(self.kind)
        cov = pnp_covariance(res.information, res.rms_px, cal["scale"], cal.get("sigma_floor_px", SIGMA_FLOOR_PX))
        return Measurement(pose=pose, covariance=cov * quality_factor(cal, quality), quality=quality,
                           source=f"regressor:{self.name}", timestamp=frame.timestamp)

    def _quality_bound(self, est: KeypointEstimate) -> float:
        """An upper bound of the quality :meth:`_measure` gives ``est``: its PnP terms times the twin
        head's largest probability (1 where a mirror verifier may replace the belief)."""
        q = pnp_quality(est)
        return q if est.prob is None or self.mirror_verifier is not None else q * float(np.max(est.prob))

    def _measure(self, frame: Frame, undistorted: Frame, est: KeypointEstimate) -> Measurement:
        """The measurement from one keypoint estimate on the ``undistorted`` frame: twin choice, edge
        fit, mirror check, calibrated covariance, quality."""
        res, order, prob, _ = est
        quality = pnp_quality(est)
        pose, twin = res.pose, order[0]
        # the covariance cannot say "maybe turned end for end" (a 180° mode, not a Gaussian spread): the
        # quality does, through the belief in the returned twin (a gate on it removes most of the gross
        # errors): the head's, or the mirror verifier's where it replaced the pose
        belief = None
        # an object with symmetries has twins no image tells apart: none to check
        check_twins = self.options.check_twins and self.passes.unlabelled is None
        if self.twin_choice is not None:
            if self.options.refine_edges:
                pose, twin = self.twin_choice.refine(undistorted, pose, order, prob, check_twins=check_twins)
                checked = self.twin_choice.mirror_check(undistorted, pose)
                if checked is not None and checked[2] > 0:
                    pose, belief, _ = checked
            elif check_twins and not self.has_twin_head:
                pose, _, flipped = self.twin_check.best(undistorted, pose)
                if flipped:  # the keypoints disagreed with the image: the pose is right, the fit is not
                    quality *= 0.5
        if belief is None and prob is not None:
            belief = float(prob[twin])
        if belief is not None:
            quality *= belief
        return self._keypoint_measurement(frame, res, pose, quality)

    def _undistorted(self, frame: Frame) -> tuple[np.ndarray, Camera]:
        pinhole = frame.undistorted()
        return pinhole.image, pinhole.camera

    def _predict_direct(self, frame: Frame, roi) -> Measurement:
        image, cam = self._undistorted(frame)
        out = direct_pose(self.net, self.model_name, image, cam, self.image_size, self.tensor, roi,
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
        return bounded_image(self.net, image, cam, self.image_size, self.tensor, None,
                             float(self.dataset.get("diameter_m") or 0.5))[1]

    def _lost(self, frame: Frame) -> Measurement:
        return Measurement(pose=None, covariance=LOST_COVARIANCE, quality=0.0, source=f"regressor:{self.name}",
                           timestamp=frame.timestamp, lost=True)


def _factory(name: str):
    def make(checkpoint=None, object=None, threads: int | None = None, **options) -> CheckpointRegressor:
        path = checkpoint if checkpoint is not None else shipped_checkpoint(name)
        return CheckpointRegressor(path, object=object, threads=threads, expect_model=name, **options)

    make.__name__ = f"make_{name.replace('-', '_')}"
    make.__doc__ = f"Regressor backend {name!r}: ``checkpoint=PATH`` (default: the shipped one, if any)."
    return make


for _name in available_models():
    register("regressor", _name)(_factory(_name))
