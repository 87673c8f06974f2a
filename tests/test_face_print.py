"""A print on the part's faces: attached to the surface (it moves with the part), cut at the faces' edges."""
import cv2
import numpy as np
import pytest

from hybridpose.geometry import Camera, Pose
from hybridpose.objects import load_object
from hybridpose.render import Appearance, AppearanceSpec, Renderer
from hybridpose.render.appearance import TEXTURE_FLOOR
from hybridpose.render.camera_effects import camera_effects
from hybridpose.render.face_print import FACES, draw_face_prints, face_print_gain

CAM = Camera(width=200, height=160, fx=220.0, fy=220.0, cx=100.0, cy=80.0)


@pytest.fixture(scope="module")
def box():
    return load_object("box")


def _noise(seed: int = 0, size=(120, 160)) -> np.ndarray:
    img = np.random.default_rng(seed).integers(0, 256, (*size, 3), dtype=np.uint8)
    return cv2.GaussianBlur(img, (0, 0), 2.0)


def test_the_print_moves_with_the_part(box):
    """Face-on, the part moved sideways by what the camera sees as 10 px: its print moves 10 px in the
    image (an image-space print would stay where it was)."""
    faces = draw_face_prints(np.random.default_rng(1), 160, 120)
    faces[:, 4] = 0  # every face printed
    tex = _noise()
    lo, hi = box.bbox_min, box.bbox_max
    z = 0.3
    front = z + lo[2]  # the −z face, nearest the camera at identity rotation: 149 × 91 px around the centre
    depth = np.full((CAM.height, CAM.width), front, np.float32)
    mask = np.zeros((CAM.height, CAM.width), bool)
    mask[40:120, 50:150] = True   # on the face at both positions
    shift = 10
    gains = [face_print_gain(tex, faces, depth, mask, CAM, Pose(np.eye(3), [dx, 0.0, z]), lo, hi).reshape(80, 100, 3)
             for dx in (0.0, shift * front / CAM.fx)]
    assert np.abs(gains[1][:, shift:] - gains[0][:, :-shift]).mean() < 0.01 < np.abs(gains[1] - gains[0]).mean()


def test_each_face_gets_its_own_patch_cut_at_its_edges(box):
    """A box seen over a corner, one face printed black and the rest plain: the pixels inside that face's
    projected outline (cv2.projectPoints, 2 px in from its edges) are all ink, those inside the other
    visible faces' outlines all plain."""
    pose = Pose.from_rotvec_t([0.5, -0.6, 0.1], [0.0, 0.0, 0.6])
    with Renderer(box, CAM) as r:
        res = r.render(pose, rng=0)
    lo, hi = box.bbox_min, box.bbox_max
    tex = np.zeros((50, 50, 3), np.uint8)
    seen_faces = 0
    for k in range(FACES):
        axis, positive = divmod(k, 2)
        faces = draw_face_prints(np.random.default_rng(0), 50, 50)
        faces[:, 4] = 1
        faces[k, 4] = 0
        gain = np.ones((CAM.height, CAM.width))
        gain[res.mask_visib] = face_print_gain(tex, faces, res.depth, res.mask_visib, CAM, pose, lo, hi)[:, 0]
        corners = box.bbox_corners
        on_face = corners[np.isclose(corners[:, axis], hi[axis] if positive else lo[axis])]
        normal = np.zeros(3)
        normal[axis] = 1.0 if positive else -1.0
        centre = on_face.mean(0)
        if (pose.R @ normal) @ (pose.R @ centre + pose.t) >= 0:
            continue  # the face turns away from the camera
        seen_faces += 1
        uv, _ = cv2.projectPoints(on_face, cv2.Rodrigues(pose.R)[0], pose.t, CAM.K, None)
        inside = np.zeros((CAM.height, CAM.width), np.uint8)
        cv2.fillConvexPoly(inside, cv2.convexHull(uv.reshape(-1, 2).astype(np.float32)).astype(np.int32), 1)
        inside = cv2.erode(inside, np.ones((5, 5), np.uint8)).astype(bool) & res.mask_visib
        assert inside.sum() > 50 and np.all(gain[inside] == 0.0)
        others = cv2.erode((res.mask_visib & ~cv2.dilate(inside.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool))
                           .astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        assert others.sum() > 50 and np.all(gain[others] == 1.0)
    assert seen_faces == 3


def test_a_spec_lays_the_print_on_the_faces_and_records_it(box):
    """``print_on="faces"``: the same looks and prints as before, now with face patches; the render darkens
    only the part, and the dataset config says so."""
    image, faces = AppearanceSpec("random", texture_share=1.0), AppearanceSpec("random", texture_share=1.0, print_on="faces")
    a, b = image.draw(CAM.width, CAM.height, 3, 0), faces.draw(CAM.width, CAM.height, 3, 0)
    assert np.array_equal(a.object_texture, b.object_texture) and a.print_faces is None and b.print_faces.shape == (FACES, 5)
    assert "print_on" not in image.record() and faces.record()["print_on"] == "faces"
    pose = Pose.from_rotvec_t([0.5, -0.6, 0.1], [0.0, 0.0, 0.6])
    with Renderer(box, CAM) as r:
        bare = r.render(pose, rng=0, appearance=Appearance(ambient=0.3, background=a.background))
        seen = r.render(pose, rng=0, appearance=Appearance(ambient=0.3, background=a.background,
                                                           object_texture=b.object_texture, print_faces=b.print_faces))
    assert np.array_equal(bare.rgb[~bare.mask], seen.rgb[~bare.mask])
    on = bare.mask_visib
    assert (seen.rgb[on].astype(int) <= bare.rgb[on].astype(int) + 2).all()
    lowest = seen.rgb[on].astype(float) / np.maximum(bare.rgb[on].astype(float), 1.0)
    assert lowest[bare.rgb[on] > 40].min() >= TEXTURE_FLOOR - 0.05


def test_bad_print_input_names_the_argument():
    with pytest.raises(ValueError, match="print_on: expected one of image, faces"):
        AppearanceSpec("random", print_on="mesh")
    with pytest.raises(ValueError, match="print_faces: a print on the faces needs the picture"):
        Appearance(print_faces=np.zeros((FACES, 5)))
    with pytest.raises(ValueError, match=r"print_faces: expected \(6, 5\)"):
        Appearance(object_texture=np.zeros((4, 4, 3), np.uint8), print_faces=np.zeros((4, 5)))
    with pytest.raises(ValueError, match="grey_share: grey images are drawn among the camera effects"):
        AppearanceSpec("random", grey_share=0.5)
    with pytest.raises(ValueError, match=r"grey_share: expected a share of the images in \[0, 1\]"):
        AppearanceSpec("random", camera_effects=True, grey_share=2.0)


def test_a_monochrome_camera_share_leaves_the_other_draws_alone():
    img = _noise(3, (40, 50))
    for seed in range(20):
        colour = camera_effects(img, seed)
        assert np.array_equal(camera_effects(img, seed, 0.0), colour)
        grey = camera_effects(img, seed, 1.0)
        assert np.array_equal(grey[..., 0], grey[..., 1]) and np.array_equal(grey[..., 1], grey[..., 2])
        assert np.abs(grey[..., 0].astype(int) - cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY)).max() <= 1
    spec = AppearanceSpec("random", camera_effects=True, grey_share=0.3)
    assert spec.record()["grey_share"] == 0.3 and "grey_share" not in AppearanceSpec("random", camera_effects=True).record()
