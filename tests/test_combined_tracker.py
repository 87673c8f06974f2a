"""The combined tracker on a printed part in clutter: a box whose faces carry a mosaic print (a
colour per 6-mm cell of its surface, so the print moves with the part), drawn over procedural clutter
from its facet-id raster, the camera moving 5–20 px a frame. What the renders of plain parts on
black space cannot show: the print's and the clutter's edges are no evidence against a right pose."""
import cv2
import numpy as np
import pytest
import trimesh

from hybridpose.core import Frame
from hybridpose.edges import ModelView
from hybridpose.geometry import Camera, Pose
from hybridpose.metrics import rotation_error_deg, translation_error_m
from hybridpose.objects import ObjectModel
from hybridpose.registry import create
from hybridpose.render.appearance import clutter_background
from hybridpose.edges import printed_faces

CELL_M = 0.006


def _box() -> ObjectModel:
    return ObjectModel("printed-box", trimesh.creation.box((0.085, 0.085, 0.085)))


def _draw(view: ModelView, camera: Camera, pose: Pose, background: np.ndarray, palette: np.ndarray,
          print_on: bool = True) -> np.ndarray:
    """The box at ``pose`` over ``background``: each seen pixel lifted onto the model, coloured by the
    print cell it falls in, shaded by its face's tilt."""
    ids = view.facet_ids(pose, camera, scale=1.0)
    ys, xs = np.nonzero(ids)
    X, ok = view.lift(pose, camera, np.c_[xs, ys].astype(float), ids=ids)
    cell = np.floor(X / CELL_M).astype(np.int64)
    key = (cell[:, 0] * 73856093 ^ cell[:, 1] * 19349663 ^ cell[:, 2] * 83492791) % len(palette)
    colour = palette[key] if print_on else np.full((len(xs), 3), 170.0)
    normal_cam = view.plane_normal[ids[ys, xs]] @ pose.R.T
    shade = 0.55 + 0.45 * np.abs(normal_cam[:, 2])
    image = background.copy()
    image[ys[ok], xs[ok]] = np.clip(colour[ok] * shade[ok, None], 0, 255).astype(np.uint8)
    return image


def _sequence(frames: int, seed: int, print_on: bool = True):
    """(frames, true poses, object): the box 0.35–0.45 m away, turning and sliding 5–20 px a frame."""
    rng = np.random.default_rng(seed)
    obj, camera = _box(), Camera.default()
    view = ModelView(obj)
    background = clutter_background(camera.width, camera.height, rng)
    palette = rng.uniform(30, 255, (97, 3))
    rotvec, t = rng.normal(size=3) * 0.5, np.array([0.0, 0.0, 0.4])
    spin, slide = rng.normal(size=3), rng.normal(size=3) * [1, 1, 0.3]
    spin *= np.radians(2.0) / np.linalg.norm(spin)
    slide *= 0.004 / np.linalg.norm(slide)  # 6 px at 0.4 m
    travelled = np.cumsum([0.0] + [1.0 + (k % 3) for k in range(frames - 1)])  # 6, 12, 18 px a frame in turn
    out, poses = [], []
    for k in range(frames):
        pose = Pose.from_rotvec_t(rotvec + k * spin, t + travelled[k] * slide)
        out.append(Frame(_draw(view, camera, pose, background, palette, print_on), camera, k / 30, k))
        poses.append(pose)
    return out, poses, obj


@pytest.fixture(scope="module")
def printed_box():
    return _sequence(25, seed=7)


def test_a_print_is_told_from_a_plain_part(printed_box):
    frames, poses, obj = printed_box
    view = ModelView(obj)
    plain, _, _ = _sequence(1, seed=7, print_on=False)
    assert printed_faces(view, frames[0], poses[0])
    assert not printed_faces(view, plain[0], poses[0])


def test_follows_a_printed_part_in_clutter_where_explained_edges_call_it_lost(printed_box):
    frames, poses, obj = printed_box
    combined = create("tracker", "combined", object=obj)
    combined.init(frames[0], poses[0])
    assert combined.printed
    errors, lost = [], 0
    for frame, truth in zip(frames[1:], poses[1:]):
        m = combined.track(frame)
        lost += m.lost
        errors.append(rotation_error_deg(combined.pose, truth))
        assert translation_error_m(combined.pose, truth) < 0.01
    assert lost == 0, f"combined: {lost} frames lost at a right pose"
    assert np.median(errors) < 1.0 and max(errors) < 3.0, f"median {np.median(errors):.2f}°, worst {max(errors):.2f}°"


@pytest.mark.parametrize("modalities, print_on", [(("texture",), True), (("region",), True), (("edges",), False)])
def test_each_cue_alone_pulls_towards_the_part(modalities, print_on, printed_box):
    # edges alone on the plain box: on the print its own edges pull them (what the weights account for)
    frames, poses, obj = printed_box if print_on else _sequence(3, seed=7, print_on=False)
    tracker = create("tracker", "combined", object=obj, modalities=modalities)
    start = poses[1].retract(np.r_[np.radians([1.5, -1.0, 1.0]), 0.004, -0.003, 0.0])
    tracker.init(frames[0], poses[0])
    tracker.track(frames[1], prior=start)
    assert rotation_error_deg(tracker.pose, poses[1]) < rotation_error_deg(start, poses[1])
    assert translation_error_m(tracker.pose, poses[1]) < translation_error_m(start, poses[1])


def test_a_second_fit_of_a_frame_on_a_trial_leaves_the_track_as_it_was(printed_box):
    # the hybrid checks a network's pose with a second fit of the frame: on the tracker itself that
    # fit teaches it the other pose's view (texture points dropped, a keyframe lifted there) and the
    # next frame starts from it; on a trial the track goes on as if it never happened
    frames, poses, obj = printed_box
    wrong = [p.retract(np.r_[np.radians([6.0, -5.0, 4.0]), 0.006, -0.004, 0.0]) for p in poses]

    def track(second_fit_on: str | None) -> list[np.ndarray]:
        tracker = create("tracker", "combined", object=obj)
        tracker.init(frames[0], poses[0])
        out = []
        for frame in frames[1:10]:
            out.append(tracker.track(frame).pose.matrix)
            if second_fit_on is not None and frame.index % 3 == 1:
                fitter = tracker.trial() if second_fit_on == "trial" else tracker
                fitter.track(frame, prior=wrong[frame.index], search_px=12)
        return out

    alone = track(None)
    assert all(np.array_equal(a, b) for a, b in zip(alone, track("trial")))
    assert not all(np.allclose(a, b, atol=1e-6) for a, b in zip(alone, track("tracker")))


@pytest.mark.parametrize("print_on", [True, False])
def test_a_track_owes_nothing_to_the_trial_fits_of_the_starts_before_it(print_on, printed_box):
    # a hybrid's start fits the frame from several poses (the network's, its rivals) before the one it takes:
    # the track from that start must follow as a tracker started there alone would (the colour model's
    # learning and the second looks count the track's own frames)
    frames, poses, obj = printed_box if print_on else _sequence(10, seed=7, print_on=False)
    wrong = poses[0].retract(np.r_[np.radians([20.0, -15.0, 10.0]), 0.01, -0.005, 0.0])

    def track(trial_starts: int) -> list[np.ndarray]:
        tracker = create("tracker", "combined", object=obj)
        for _ in range(trial_starts):
            tracker.init(frames[0], wrong)
            tracker.track(frames[0], prior=wrong, search_px=12)
        tracker.init(frames[0], poses[0])
        return [tracker.track(frame).pose.matrix for frame in frames[1:10]]

    alone = track(0)
    assert all(np.array_equal(a, b) for a, b in zip(alone, track(1)))
    assert all(np.array_equal(a, b) for a, b in zip(alone, track(2)))


def test_the_part_covered_by_something_else_is_reported_lost(printed_box):
    frames, poses, obj = printed_box
    tracker = create("tracker", "combined", object=obj)
    tracker.init(frames[0], poses[0])
    rng = np.random.default_rng(3)
    flags = []
    for frame in frames[1:8]:
        image = frame.image.copy()
        box = frame.camera.image_box(obj.bbox_corners, poses[frame.index])
        x0, y0, x1, y1 = (int(v) for v in box)
        image[max(y0 - 10, 0):y1 + 10, max(x0 - 10, 0):x1 + 10] = rng.integers(0, 255, 3)  # a card in front
        flags.append(tracker.track(Frame(image, frame.camera, frame.timestamp, frame.index)).lost)
    assert all(flags[2:]), f"lost flags while covered: {flags}"


def test_modalities_are_checked():
    obj = _box()
    with pytest.raises(ValueError, match="modalities"):
        create("tracker", "combined", object=obj, modalities=("depth",))
    with pytest.raises(ValueError, match="modalities"):
        create("tracker", "combined", object=obj, modalities=())


def test_the_patch_step_finds_how_far_the_part_moved():
    from hybridpose.trackers.combined import masked_correlations, patch_shift, refine_shift

    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (120, 160)).astype(np.float32), (0, 0), 2.0)
    moved = np.roll(image, (-4, 7), axis=(0, 1))
    assert np.allclose(patch_shift(image, moved, (60, 40, 100, 80), 12), [7, -4], atol=0.1)  # sub-pixel peak
    mask = np.zeros_like(image, bool)
    mask[45:75, 65:95] = True
    assert np.allclose(patch_shift(image, moved, (60, 40, 100, 80), 12, mask), [7, -4], atol=0.1)
    assert patch_shift(image, rng.uniform(0, 255, image.shape).astype(np.float32), (60, 40, 100, 80), 12) is None
    # between pixels: the parabola through the peak finds a sub-pixel shift
    between = cv2.warpAffine(image, np.float32([[1, 0, 7.4], [0, 1, -3.7]]), image.shape[::-1], flags=cv2.INTER_CUBIC)
    assert np.allclose(patch_shift(image, between, (60, 40, 100, 80), 12), [7.4, -3.7], atol=0.15)
    # the refinement's correlations are OpenCV's masked TM_CCOEFF_NORMED at the nine shifts around a guess
    scores = masked_correlations(image, between, mask, 60, 40, 100, 80, 7, -4)
    oracle = cv2.matchTemplate(between[35:77, 66:108].copy(), image[40:80, 60:100].copy(), cv2.TM_CCOEFF_NORMED,
                               mask=mask[40:80, 60:100].astype(np.float32))
    assert np.allclose(scores, oracle, atol=1e-4)
    assert np.allclose(refine_shift(image, between, (60, 40, 100, 80), mask, [6.6, -4.2]),
                       patch_shift(image, between, (60, 40, 100, 80), 12, mask), atol=0.01)


def test_hand_held_sequences_move_like_a_hand_and_a_tracker_follows_their_truth():
    from hybridpose.render.handheld import HandheldSpec, handheld_sequence

    obj, camera = _box(), Camera.default()
    frames = handheld_sequence(HandheldSpec(frames=30, seed=4, speed_px=(5.0, 15.0)), obj, camera)
    motion = np.array([f.motion_px for f in frames[1:]])
    assert 3.0 < np.median(motion) < 20.0 and motion.max() < 30.0
    assert all(f.image.shape == (480, 640, 3) and f.image.dtype == np.uint8 for f in frames)
    tracker = create("tracker", "combined", object=obj)
    errors = []
    for f in frames:
        frame = Frame(f.image, camera, f.timestamp, f.index)
        if f.index == 0:
            tracker.init(frame, f.pose)
        tracker.track(frame)
        errors.append(rotation_error_deg(tracker.pose, f.pose))
    assert np.median(errors) < 3.0, f"median {np.median(errors):.2f}° from the renderer's own truth"


def test_hand_held_specs_are_checked():
    from hybridpose.render.handheld import HandheldSpec

    with pytest.raises(ValueError, match="background"):
        HandheldSpec(background="space")
    with pytest.raises(ValueError, match="speed_px"):
        HandheldSpec(speed_px=(20.0, 5.0))
    with pytest.raises(ValueError, match="frames"):
        HandheldSpec(frames=1)


@pytest.mark.parametrize("start_t", [[2.0, 0.0, 0.5], [0.3, 0.1, 0.06], [0.0, 0.0, 0.02]])
def test_a_start_far_off_or_partly_behind_the_camera_is_lost_not_a_crash(start_t):
    """What the hybrid hands a tracker after a CNN answer: anything, e.g. the part half behind the lens."""
    from hybridpose.objects import load_object
    from hybridpose.render.handheld import HandheldSpec, handheld_sequence

    camera, cube = Camera(320, 240, 300.0, 300.0, 159.5, 119.5), load_object("cube")
    frames = handheld_sequence(HandheldSpec(frames=2, seed=1, size_px=80.0), cube, camera)
    tracker = create("tracker", "combined", object=cube)
    tracker.init(Frame(frames[0].image, camera, 0.0, 0), frames[0].pose)
    m = tracker.track(Frame(frames[1].image, camera, 1 / 30, 1), Pose(frames[1].pose.R, np.array(start_t)))
    assert m.lost and m.pose is None


def test_a_start_checked_on_its_own_frame_keeps_its_print_for_the_frames_after(printed_box, monkeypatch):
    """The hybrid (and ViSP's castle, started 10–20 px off) fit the very frame the tracker started on,
    the texture cue sitting out: its points must be lifted again at the fitted pose, not dropped — the
    frames after were called lost until the other cues vouched for a keyframe (on the castle, a
    partial model, its edges never score the 0.5 a keyframe needs)."""
    import hybridpose.trackers.combined as combined

    monkeypatch.setattr(combined, "KEYFRAME_CUE_QUALITY", 1.01)  # no cue vouches for a new keyframe
    frames, poses, obj = printed_box
    tracker = create("tracker", "combined", object=obj)
    start = poses[0].retract(np.r_[np.radians([1.0, -1.0, 0.5]), 0.003, -0.002, 0.0])
    tracker.init(frames[0], start)
    assert not tracker.track(frames[0], start).lost
    for frame, truth in zip(frames[1:6], poses[1:6]):
        m = tracker.track(frame)
        assert not m.lost and tracker.cue_qualities["texture"] > 0.5, (frame.index, tracker.cue_qualities)
        assert rotation_error_deg(tracker.pose, truth) < 2.0


def test_a_texture_cue_starved_by_blur_lifts_new_points_on_the_other_cues_joint_word(printed_box, monkeypatch):
    """Motion blur kills most KLT points; a starved cue votes low (a few points short of full support)
    until it lifts new ones. Where no single other cue reaches the keyframe bar (region at 0.3–0.5 on a
    dark part over a photo), their joint quality must do, or the tracker calls right poses lost."""
    import hybridpose.trackers.combined as combined

    monkeypatch.setattr(combined, "KEYFRAME_CUE_QUALITY", 1.01)  # no cue alone vouches for a keyframe
    frames, poses, obj = printed_box
    kernel = np.full((1, 15), 1 / 15, np.float32)  # 15 px of horizontal motion blur
    tracker = create("tracker", "combined", object=obj)
    tracker.init(frames[0], poses[0])
    lost = []
    for frame in frames[1:12]:
        image = cv2.filter2D(frame.image, -1, kernel) if frame.index in (2, 3) else frame.image
        lost.append(tracker.track(Frame(image, frame.camera, frame.timestamp, frame.index)).lost)
    texture = next(c for c in tracker.cues if c.name == "texture")
    assert len(texture.X) >= texture.min_points, f"still starved: {len(texture.X)} points"
    assert not any(lost[3:]), f"lost flags after the blur: {lost}"
    assert tracker.cue_qualities["texture"] > 0.5
    assert rotation_error_deg(tracker.pose, poses[11]) < 1.0


def test_the_region_cue_splits_each_line_where_part_turns_to_background():
    from hybridpose.trackers.cues.region import BINS, best_splits, posterior_image

    L = 8
    x = np.arange(2 * L + 3) - (L + 1)  # samples from inside to outside, the line's centre at 0
    edges = np.array([-5.5, -0.5, 0.5, 3.5])
    part = (x[None] < edges[:, None]).astype(np.float32)  # posterior 1 inside the part, 0 beyond its boundary
    offset, clear = best_splits(np.vstack([part, np.full((1, len(x)), 0.5, np.float32)]), L, 0.3)
    assert np.allclose(offset[:4], edges, atol=1e-6) and clear[:4].all()
    assert not clear[4]  # one colour all along: no split to trust
    # the posterior image is the colour-bin table looked up per pixel (NumPy as the oracle)
    rng = np.random.default_rng(1)
    image, lut = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8), rng.random(BINS ** 3).astype(np.float32)
    q = image.astype(int) // (256 // BINS)
    assert np.array_equal(posterior_image(image, lut, BINS), lut[(q[..., 0] * BINS + q[..., 1]) * BINS + q[..., 2]])


def test_a_print_with_few_corners_keeps_its_keyframe(printed_box):
    """A keyframe that lifts fewer points than ``min_points`` is not starved at once (it would be lifted
    again every frame, its points then anchored to nothing older): it re-keys once half its points are gone."""
    frames, poses, obj = printed_box
    tracker = create("tracker", "combined", object=obj)
    texture = next(c for c in tracker.cues if c.name == "texture")
    texture.min_points = texture.max_points  # every keyframe of this print lifts fewer than that
    tracker.init(frames[0], poses[0])
    keyframes = set()
    for frame, truth in zip(frames[1:7], poses[1:7]):
        assert not tracker.track(frame).lost
        keyframes.add(id(texture.kf_pose))
        assert rotation_error_deg(tracker.pose, truth) < 2.0
    assert 0 < texture.kf_count < texture.min_points and len(keyframes) <= 2, (texture.kf_count, len(keyframes))


def test_the_patch_steps_part_mask_picks_the_pixels_opencvs_nearest_resize_picks():
    """The stride shortcut against its oracle, ``cv2.resize`` with ``INTER_NEAREST``, at whole and
    non-whole ratios."""
    from hybridpose.trackers.combined import _nearest_mask

    rng = np.random.default_rng(3)
    for (H, W), (h, w) in [((240, 320), (240, 320)), ((240, 320), (120, 160)), ((480, 640), (120, 160)),
                           ((241, 321), (120, 160)), ((240, 320), (70, 90))]:
        ids = rng.integers(0, 3, (H, W)).astype(np.int32)
        oracle = cv2.resize((ids > 0).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
        assert np.array_equal(_nearest_mask(ids, (h, w)), oracle), ((H, W), (h, w))


def _plain_box_frames(seed: int, poses: list[Pose]):
    """(frames, object): the plain 180 × 110 × 70 mm box at ``poses`` over procedural clutter."""
    rng = np.random.default_rng(seed)
    obj, camera = ObjectModel("plain-box", trimesh.creation.box((0.18, 0.11, 0.07))), Camera.default()
    view = ModelView(obj)
    background, palette = clutter_background(camera.width, camera.height, rng), rng.uniform(30, 255, (97, 3))
    frames = [Frame(_draw(view, camera, p, background, palette, print_on=False), camera, k / 30, k)
              for k, p in enumerate(poses)]
    return frames, obj


@pytest.mark.parametrize("hypotheses", [True, False])
def test_a_plain_box_seen_near_head_on_is_fitted_again_from_the_mirrored_tilt(hypotheses, monkeypatch):
    """The planar ambiguity: a plain box's large face seen 15° from head-on, the fit started from the
    other pose of the ambiguity (33° off). Its outline fits that pose fair enough to be trusted; the
    tracker's second fit from the mirrored tilt finds the right one. Without it (the control) the wrong
    pose stays."""
    from hybridpose.geometry import mirrored_tilt
    import hybridpose.trackers.combined as combined_module

    if not hypotheses:
        monkeypatch.setattr(combined_module, "SECOND_LOOK_BELOW", 0.0)
    poses = [Pose.from_rotvec_t(np.radians([14 + k, 6, 3]), [0.01 * k, 0.0, 0.6]) for k in range(3)]
    frames, obj = _plain_box_frames(3, poses)
    tracker = create("tracker", "combined", object=obj)
    tracker.init(frames[0], poses[0])
    assert not tracker.track(frames[1]).lost  # a track held, then the ambiguous start
    start = mirrored_tilt(poses[2], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    assert rotation_error_deg(start, poses[2]) > 30
    m = tracker.track(frames[2], prior=start)
    if hypotheses:
        assert not m.lost and rotation_error_deg(m.pose, poses[2]) < 1.0
    else:
        assert not m.lost and rotation_error_deg(m.pose, poses[2]) > 30


@pytest.mark.parametrize("second_look", [True, False])
def test_where_an_occluders_edges_pull_the_edge_search_the_region_alone_finds_the_plain_part(second_look, monkeypatch):
    """An arm sliding over a plain part brings edges of its own beside the part's, and the edge
    cue's search locks onto them: here, from the third frame on, every edge search finds its edge where
    the part would stand 15° turned (a decoy), while the frame itself shows the part where it is, so
    the qualities read what the image shows. Every fit of all the cues is pulled towards the decoy;
    the second look's fit on the region cue alone, from the frame's start, is not, and all the cues
    judge it the better. Without the second look (the control) the pulled fit stays."""
    from hybridpose.geometry import turned_about
    from hybridpose.trackers.cues.edges import EdgeCue
    import hybridpose.trackers.combined as combined_module

    if not second_look:
        monkeypatch.setattr(combined_module, "SECOND_LOOK_BELOW", 0.0)
    poses = [Pose.from_rotvec_t(np.radians([25 + k, 30, 5]), [0.003 * k, 0.0, 0.6]) for k in range(4)]
    frames, obj = _plain_box_frames(5, poses)
    decoys = {k: turned_about(p, np.radians([15.0, 0, 0]), np.zeros(3)) for k, p in enumerate(poses)}
    correspond = EdgeCue.correspond

    def pulled(cue, frame, gray, pose, search_px):
        correspond(cue, frame, gray, pose, search_px)
        if frame.index >= 2 and len(cue.X):
            cue.m = frame.camera.project(cue.X, decoys[frame.index])  # the decoy's edge, found along the line

    monkeypatch.setattr(EdgeCue, "correspond", pulled)
    tracker = create("tracker", "combined", object=obj)
    tracker.init(frames[0], poses[0])
    assert not tracker.track(frames[1]).lost and not tracker.printed
    errors = []
    for frame, truth in zip(frames[2:], poses[2:]):
        m = tracker.track(frame)
        errors.append(rotation_error_deg(tracker.pose, truth) if not m.lost else None)
    if second_look:
        assert all(e is not None and e < 1.5 for e in errors), errors
    else:
        assert any(e is not None and e > 3.0 for e in errors), errors
