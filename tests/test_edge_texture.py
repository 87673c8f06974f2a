"""The explained-edge share on a textured part (print, labels) and on clutter: texture inside the
model's faces is not held against a right pose, a wrong pose is still caught, and clutter under a
wrong pose does not pass for texture."""
import cv2
import numpy as np
import pytest
import trimesh

import hybridpose.edges.fit as edge_fit
from hybridpose.core import Frame
from hybridpose.edges import ModelView, explained_edge_share, printed_faces
from hybridpose.geometry import Camera, Pose
from hybridpose.objects.base import ObjectModel

CAMERA = Camera.default().scaled((320, 240))
POSE = Pose.from_rotvec_t([0.5, -0.6, 0.2], [0.0, 0.0, 0.45])


@pytest.fixture(scope="module")
def cube():
    return ObjectModel("cube", trimesh.creation.box((0.084, 0.084, 0.084)))


def _scribbles(shape, rng, count: int) -> np.ndarray:
    """(H, W) uint8: ``count`` random dark strokes on white, the look of a printed or cluttered surface."""
    img = np.full(shape, 255, np.uint8)
    for _ in range(count):
        p = rng.integers(0, [shape[1], shape[0]], (2, 2))
        cv2.line(img, tuple(map(int, p[0])), tuple(map(int, p[1])), int(rng.integers(0, 120)), 1, cv2.LINE_AA)
    return img


def _scene(cube, textured: bool, cluttered: bool, seed: int = 0, pose: Pose = POSE) -> Frame:
    """The cube at ``pose`` on a plain (or cluttered) grey background, its faces shaded apart and (optionally)
    scribbled over."""
    rng = np.random.default_rng(seed)
    h, w = CAMERA.height, CAMERA.width
    image = _scribbles((h, w), rng, 400) // 2 + 60 if cluttered else np.full((h, w), 90, np.uint8)
    ids = ModelView(cube).facet_ids(pose, CAMERA)
    ids = cv2.resize(ids.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST).astype(int)
    texture = _scribbles((h, w), rng, 600) if textured else np.full((h, w), 255, np.uint8)
    for k, facet in enumerate(np.unique(ids[ids > 0])):
        shade = 150 + 35 * k
        face = ids == facet
        image[face] = (texture[face].astype(int) * min(shade, 255) // 255).astype(np.uint8)
    rgb = np.repeat(cv2.GaussianBlur(image, (3, 3), 0.7)[..., None], 3, axis=2)
    return Frame(rgb, CAMERA, 0.0, 0)


def _strict(view, frame, pose, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(edge_fit, "TEXTURE_EDGE_DENSITY", np.inf)  # no texture allowance
        return explained_edge_share(view, frame, pose)


def test_texture_on_the_faces_is_not_held_against_the_right_pose(cube, monkeypatch):
    view, frame = ModelView(cube), _scene(cube, textured=True, cluttered=False)
    assert _strict(view, frame, POSE, monkeypatch) < 0.6        # without the allowance: "lost"
    assert explained_edge_share(view, frame, POSE) > 0.9


def test_a_wrong_pose_on_a_textured_part_is_still_caught(cube, monkeypatch):
    """Off by a fifth of the part's size, the share falls (the outline it should explain lies beside
    it); grossly off, the edges under its faces carry on beyond its outline and it is judged as strictly
    as without the allowance. A rotation of ~12° can hide its outline inside the faces: the allowance's
    price (docs/decisions.md)."""
    view, frame = ModelView(cube), _scene(cube, textured=True, cluttered=False)
    right = explained_edge_share(view, frame, POSE)
    assert explained_edge_share(view, frame, Pose(POSE.R, POSE.t + [0.012, 0.0, 0.0])) < right - 0.2
    for gross in (Pose(POSE.R, POSE.t + [0.025, 0.0, 0.0]), POSE @ Pose.from_rotvec_t([0.0, 0.0, np.radians(25)], [0, 0, 0])):
        share = explained_edge_share(view, frame, gross)
        assert share < 0.5 and share == pytest.approx(_strict(view, frame, gross, monkeypatch))


def test_clutter_under_a_wrong_pose_does_not_pass_for_texture(cube, monkeypatch):
    """A plain cube on a cluttered background, judged at a pose that lies over the clutter beside it:
    the edges under its faces carry on beyond its outline, so no allowance."""
    view, frame = ModelView(cube), _scene(cube, textured=False, cluttered=True)
    beside = Pose(POSE.R, POSE.t + [0.07, 0.03, 0.0])
    assert explained_edge_share(view, frame, beside) == pytest.approx(_strict(view, frame, beside, monkeypatch))
    assert explained_edge_share(view, frame, POSE) > explained_edge_share(view, frame, beside) + 0.25


def test_edge_distance_is_subpixel_on_the_part_and_grows_with_a_shift(cube):
    """``edge_distances_px``: the plain cube's visible edges at its pose lie on the image's edges (the
    faces are shaded apart); shifted 4 px sideways in the image, they lie ≈ 4 px off (at most the shift:
    an edge can meet another one)."""
    from hybridpose.edges import edge_distances_px

    view, frame = ModelView(cube), _scene(cube, textured=False, cluttered=False)
    at = edge_distances_px(view, frame, POSE)
    assert len(at) > 50 and np.median(at) < 1.0
    shift_m = 4.0 * POSE.t[2] / CAMERA.fx
    moved = edge_distances_px(view, frame, Pose(POSE.R, POSE.t + [shift_m, 0.0, 0.0]))
    assert 2.0 < np.percentile(moved, 75) <= 4.5
    blank = Frame(np.full_like(frame.image, 90), CAMERA, 0.0, 0)
    assert len(edge_distances_px(view, blank, POSE)) == 0  # no image edge: no distance


def test_a_printed_part_on_a_lit_background_is_capped_by_the_share_else_by_twice_its_shortfall(cube, monkeypatch):
    """A right fit whose surroundings leave 30 % of its edges unexplained (clutter and shadows at its
    outline): a printed part around a lit background seen from the start is capped by the share itself
    (0.7, held); a plain part there, or any part where the track saw black space, at 1 − 2 × 0.3 = 0.4
    (lost at the edge trackers' 0.5)."""
    import hybridpose.edges.quality as quality
    from hybridpose.edges import fit_edges, quality_verdict
    from hybridpose.edges.silhouette import LitVerdict

    view, frame = ModelView(cube), _scene(cube, textured=False, cluttered=True)
    fit = fit_edges(view, frame, POSE, search_px=4)
    assert fit is not None and fit.quality > 0.8
    monkeypatch.setattr(quality, "explained_edge_share", lambda *a, **k: 0.7)
    printed = quality_verdict(view, frame, fit, printed=True)
    assert printed.beside and printed.quality == pytest.approx(min(fit.quality, 0.7))
    assert quality_verdict(view, frame, fit).quality == pytest.approx(0.4)  # plain
    monkeypatch.setattr(quality, "lit_verdict", lambda *a, **k: LitVerdict(float("nan"), True))
    on_dark = quality_verdict(view, frame, fit, dark_surround=True, printed=True)
    assert on_dark.quality == pytest.approx(0.4)
    monkeypatch.setattr(quality, "lit_verdict", lambda *a, **k: LitVerdict(float("nan"), False))
    now_dark = quality_verdict(view, frame, fit, printed=True)  # a dark ring now
    assert now_dark.quality == pytest.approx(0.4)


@pytest.mark.parametrize("name", ["edges", "rapid", "klt-pnp"])
def test_a_restart_in_a_video_that_showed_black_space_keeps_its_strict_slope(name, cube, monkeypatch):
    """An edge tracker started on a printed part over a lit background caps a right fit leaving 30 % of
    the edges unexplained at 0.7; once the video has shown the part on black space, a re-init (the
    hybrid's restart while an arm stands beside it) keeps judging it as on black space (0.4: lost at the
    edge fits' 0.5), until ``reset``."""
    import hybridpose.edges.quality as quality
    from hybridpose.registry import create

    lit = _scene(cube, textured=True, cluttered=True)
    image = lit.image.copy()
    ids = ModelView(cube).facet_ids(POSE, CAMERA)
    inside = cv2.resize((ids > 0).astype(np.uint8), (CAMERA.width, CAMERA.height), interpolation=cv2.INTER_NEAREST) > 0
    image[~cv2.dilate(inside.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)] = 0
    dark = Frame(image, CAMERA, 0.0, 0)
    monkeypatch.setattr(quality, "explained_edge_share", lambda *a, **k: 0.7)
    tracker = create("tracker", name, object=cube)

    def quality():
        tracker.init(lit, POSE)
        return tracker.track(lit).quality

    assert quality() == pytest.approx(0.7, abs=0.1)
    tracker.init(dark, POSE)
    tracker.track(dark)
    assert quality() <= 0.4 + 1e-9
    tracker.reset()
    assert quality() == pytest.approx(0.7, abs=0.1)


@pytest.mark.parametrize("shift", [(0.0, 0.0), (-0.2, 0.0), (0.0, -0.15), (0.2, 0.15)])
@pytest.mark.parametrize("textured", [True, False])
def test_a_print_is_found_on_the_part_wherever_it_lies_in_the_frame(cube, shift, textured):
    """``printed_faces`` works on the part's box, not the whole frame: it answers as the whole frame's
    morphology does (computed here), the part in the middle or cut by an image border."""
    pose = Pose(POSE.R, POSE.t + [shift[0], shift[1], 0.0])
    view = ModelView(cube)
    frame = _scene(cube, textured=textured, cluttered=False, pose=pose)
    ids = view.facet_ids(pose, CAMERA, scale=1.0).astype(np.uint16)
    k = np.ones((2 * edge_fit.TEXTURE_CLEAR_PX + 1,) * 2, np.uint8)
    interior = (ids > 0) & (cv2.dilate(ids, k) == cv2.erode(ids, k))
    gray = cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY)
    density = (cv2.Canny(gray, edge_fit.CANNY_LOW, edge_fit.CANNY_HIGH) > 0)[interior].mean()
    on_border = bool((ids[:, [0, -1]] > 0).any() or (ids[[0, -1], :] > 0).any())
    assert interior.sum() > 100 and on_border == (shift != (0.0, 0.0))  # the shifted part is cut by a border
    assert printed_faces(view, frame, pose) == bool(density > edge_fit.TEXTURE_EDGE_DENSITY) == textured
