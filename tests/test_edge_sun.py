"""Edges under a known sun (hybridpose.edges): which model edges the sun can show, the dark-background
test, and the edge fit leaving out the rest; ``Frame.sun_direction_cam`` checks its input."""
import numpy as np
import pytest
import trimesh

from hybridpose.core import Frame
from hybridpose.edges import ModelView, fit_edges
from hybridpose.edges.fit import dark_surround
from hybridpose.geometry import Camera, Pose
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import load_object
from hybridpose.render import Renderer, SpaceLighting

HALF = 0.1  # the cube's half side, m


@pytest.fixture(scope="module")
def cube(tmp_path_factory):
    path = tmp_path_factory.mktemp("cube") / "cube.stl"
    trimesh.creation.box(extents=(2 * HALF,) * 3).export(path)
    return load_object(path)


def corner_view() -> Pose:
    """The cube seen along its (−1, −1, −1) diagonal from 0.8 m: faces +x, +y and +z face the camera."""
    z = -np.ones(3) / np.sqrt(3)                       # camera's optical axis, object frame
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_obj_cam = np.stack([x, y, z], 1)                 # columns: camera axes in the object frame
    centre_cam = np.array([0.0, 0.0, 0.8])
    return Pose(R_obj_cam.T, centre_cam)               # the object's origin 0.8 m ahead


def faces_of(point: np.ndarray) -> list[np.ndarray]:
    """The outward normals of the cube faces a point on its edges lies on (the oracle: its coordinates)."""
    return [np.sign(point[i]) * np.eye(3)[i] for i in range(3) if abs(abs(point[i]) - HALF) < 1e-6]


@pytest.mark.parametrize("dark_background", [True, False])
def test_the_sun_shows_creases_with_a_lit_side_and_the_outline_of_lit_faces(cube, dark_background):
    view, pose, cam = ModelView(cube), corner_view(), Camera.default()
    towards_sun = np.array([1.0, -0.3, -0.3]) / np.linalg.norm([1.0, -0.3, -0.3])  # lights +x only
    sun_travel_cam = -(pose.R @ towards_sun)
    idx = view.visible_index(pose, cam)
    assert len(idx) > 50
    shows = view.sun_shows(idx, pose, sun_travel_cam, dark_background=dark_background)
    seen = {(1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)}
    expected = []
    for p in view.points[idx]:
        normals = [tuple(float(v) for v in n) for n in faces_of(p)]
        visible = [n for n in normals if n in seen]
        lit = [n for n in visible if np.dot(n, towards_sun) > 0]
        if len(visible) == 2:          # a crease between two faces the camera sees
            expected.append(bool(lit))
        else:                          # the outline of the one face it sees
            expected.append(bool(lit) or not dark_background)
    assert shows.tolist() == expected
    assert 0 < shows.sum() < len(shows)


def test_dark_surround_tells_black_space_from_a_lit_background():
    black = np.zeros((120, 160), np.float32)
    uv = np.array([[60.0, 40.0], [100.0, 80.0]])
    assert dark_surround(black, uv)
    earth = black.copy()
    earth[:, :50] = 120.0                              # a bright limb left of the object
    assert not dark_surround(earth, uv)
    assert not dark_surround(black, np.array([[-40.0, -40.0], [200.0, 160.0]]))  # no strip in the image


def test_dark_surround_counts_exactly_the_strip_around_the_box():
    """Against a mask of the strip drawn pixel by pixel, on random boxes (some reaching out of the
    image) over random lit pixels near the share that decides."""
    from hybridpose.edges.fit import SURROUND_GAP_PX as GAP, SURROUND_LIT_SHARE, SURROUND_WIDTH_PX as WIDTH
    from hybridpose.edges.silhouette import LIT_PIXEL_GREY

    rng = np.random.default_rng(11)
    h, w = 90, 120
    agree = []
    for _ in range(300):
        gray = np.where(rng.random((h, w)) < rng.uniform(0.02, 0.2), 200.0, 0.0).astype(np.float32)
        uv = rng.uniform([-60, -60], [w + 60, h + 60], (2, 2))
        x0, y0 = np.floor(uv.min(0)).astype(int) - GAP
        x1, y1 = np.ceil(uv.max(0)).astype(int) + GAP
        mask = np.zeros((h, w), bool)
        mask[max(y0 - WIDTH, 0):max(y1 + WIDTH, 0), max(x0 - WIDTH, 0):max(x1 + WIDTH, 0)] = True
        mask[max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = False
        expected = bool(mask.any()) and (gray[mask] > LIT_PIXEL_GREY).mean() < SURROUND_LIT_SHARE
        agree.append(dark_surround(gray, uv) == expected)
    assert all(agree)


def test_an_edge_fit_under_a_known_sun_keeps_only_the_edges_it_shows(truss):
    cam = Camera.default()
    pose = Pose.from_rotvec_t([0.4, -0.3, 0.2], [0.0, 0.0, 1.0])
    lighting = SpaceLighting()
    with Renderer(truss, cam, lighting=lighting) as r:
        image = r.render(pose, rng=0).rgb
    view = ModelView(truss)
    sun = np.asarray(lighting.sun_direction_cam)
    start = pose.retract(np.r_[np.radians(0.5), 0, 0, 0.002, 0, 0])
    plain = fit_edges(view, Frame(image, cam, 0.0), start, max_samples=100_000)
    sunlit = fit_edges(view, Frame(image, cam, 0.0, sun_direction_cam=sun), start, max_samples=100_000)
    assert plain is not None and sunlit is not None
    assert rotation_error_deg(sunlit.pose, pose) < 0.5 and rotation_error_deg(plain.pose, pose) < 0.5
    # the edges in shadow are not searched for: fewer samples, and no more than the sun shows
    idx = view.visible_index(start, cam, margin_px=2)
    assert sunlit.samples < plain.samples
    assert sunlit.samples <= int(view.sun_shows(idx, start, sun).sum())


@pytest.mark.parametrize("sun", [(0, 0, 0), (1.0, np.nan, 0), (1.0, 2.0), "up"])
def test_a_frame_refuses_a_sun_direction_that_is_no_direction(sun):
    cam = Camera.default().scaled(64)
    with pytest.raises(ValueError, match="sun_direction_cam"):
        Frame(np.zeros((cam.height, cam.width, 3), np.uint8), cam, 0.0, sun_direction_cam=sun)


def test_a_frame_keeps_the_sun_as_a_unit_vector():
    cam = Camera.default().scaled(64)
    f = Frame(np.zeros((cam.height, cam.width, 3), np.uint8), cam, 0.0, sun_direction_cam=[0.0, 0.0, 2.0])
    assert np.allclose(f.sun_direction_cam, [0, 0, 1]) and not f.sun_direction_cam.flags.writeable
