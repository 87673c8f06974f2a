"""The shadows a model casts on itself under a known sun (hybridpose.edges.shadows): checked against
the geometry of parallel light on a plate under a cube, and against MuJoCo's shadows on the truss."""
import numpy as np
import pytest
import trimesh

from hybridpose.core import Frame
from hybridpose.edges import ModelView
from hybridpose.edges.model_view import ID_SCALE
from hybridpose.edges.shadows import facet_sun_cosine, sunlit_mask
from hybridpose.geometry import Camera, Pose
from hybridpose.objects import load_object
from hybridpose.render import Renderer, SpaceLighting, random_poses


@pytest.fixture(scope="module")
def plate_and_cube(tmp_path_factory):
    """A 40 × 40 × 2 cm plate (top at z = 1 cm) and a 10-cm cube floating above its centre (z 10–20 cm)."""
    plate = trimesh.creation.box(extents=(0.4, 0.4, 0.02))
    cube = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    cube.apply_translation((0.0, 0.0, 0.15))
    path = tmp_path_factory.mktemp("mesh") / "plate_cube.obj"
    trimesh.util.concatenate([plate, cube]).export(path)
    return load_object(str(path))


def test_a_cube_shades_the_plate_where_parallel_light_puts_its_shadow(plate_and_cube):
    view = ModelView(plate_and_cube)
    camera = Camera.default()
    pose = Pose(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 1.0]))  # 1 m above, looking down
    sun_obj = np.array([1.0, 0.0, -1.0]) / np.sqrt(2)                     # down and towards +x
    lit = sunlit_mask(view, pose, camera, pose.R @ sun_obj)
    ids = view.facet_ids(pose, camera)
    rows, cols = np.nonzero(ids)
    points, ok = view.lift(pose, camera, (np.c_[cols, rows] + 0.5) / ID_SCALE - 0.5, ids, ID_SCALE)
    on_plate = ok & np.isclose(points[:, 2], 0.01, atol=1e-4)
    x, y = points[:, 0], points[:, 1]
    # the cube's shadow on the plate's top: x + (z − 0.01) for its points, z in [0.10, 0.20]: x in [0.04, 0.24]
    clear = 0.006  # metres from the shadow's outline: a shadow-map pixel is ≈ 2 mm here
    far_in = (x > 0.04 + clear) & (x < 0.24 - clear) & (np.abs(y) < 0.05 - clear)
    far_out = ~((x > 0.04 - clear) & (x < 0.24 + clear) & (np.abs(y) < 0.05 + clear))
    shown = lit[rows, cols]
    assert on_plate[far_in].sum() > 200 and not shown[on_plate & far_in].any()
    assert shown[on_plate & far_out].all()
    # the cube's top faces the sun and nothing shades it; no face turned from the sun is lit
    on_top = ok & np.isclose(points[:, 2], 0.2, atol=1e-4)
    assert on_top.sum() > 200 and shown[on_top].all()
    from_below = pose.R @ np.array([0.0, 0.0, 1.0])  # light from below: the faces seen are all turned from it
    assert not sunlit_mask(view, pose, camera, from_below).any()


def test_each_facets_cosine_to_the_sun_is_taken_in_either_frame(plate_and_cube):
    view = ModelView(plate_and_cube)
    q = np.array([0.9, 0.3, -0.2, 0.25])
    pose = Pose.from_quat_t(q / np.linalg.norm(q), [0.05, -0.02, 1.2])
    sun_cam = np.array([0.3, -2.0, 1.1])  # any length
    cosine = facet_sun_cosine(view, pose, sun_cam)
    # the other way round: each normal turned into the camera frame against the way to the sun there
    to_sun = -sun_cam / np.linalg.norm(sun_cam)
    np.testing.assert_allclose(cosine[1:], (view.plane_normal[1:] @ pose.R.T) @ to_sun, atol=1e-12)
    assert cosine[0] == 0.0  # the background's row
    top = np.argmax(view.plane_normal[:, 2])  # the cube's top, +z in the object frame
    assert np.isclose(cosine[top], pose.R[:, 2] @ to_sun)


def test_a_sun_direction_that_is_no_direction_is_refused(plate_and_cube):
    view = ModelView(plate_and_cube)
    pose = Pose(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="sun_direction_cam"):
        sunlit_mask(view, pose, Camera.default(), (0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def close_views(truss, camera):
    """Eight sunlit 640×480 views of the truss 0.3–0.4 m away (seed 6), where its beams shade its plates."""
    lighting = SpaceLighting()
    poses = random_poses(8, camera, (0.3, 0.4), rng=6, in_view_points=truss.bbox_corners[:1])
    sun = np.asarray(lighting.sun_direction_cam)
    with Renderer(truss, camera, lighting=lighting) as r:
        return [(Frame(r.render(p, rng=i).rgb, camera, float(i), i, sun_direction_cam=sun), p)
                for i, p in enumerate(poses)]


def test_the_lit_surface_matches_mujocos_shadows(truss, close_views):
    view = ModelView(truss)
    import cv2

    agree = []
    for frame, pose in close_views:
        ids = view.facet_ids(pose, frame.camera)
        lit = sunlit_mask(view, pose, frame.camera, frame.sun_direction_cam, ids)
        small = cv2.resize(cv2.cvtColor(frame.image, cv2.COLOR_RGB2GRAY), (ids.shape[1], ids.shape[0]),
                           interpolation=cv2.INTER_AREA)
        on = ids > 0
        agree.append((lit[on] == (small[on] > 12)).mean())
    assert min(agree) > 0.95, agree


def test_the_sunlit_surface_a_pose_predicts_is_lit_in_the_image_at_the_true_pose_only(truss, close_views):
    from dataclasses import replace

    from hybridpose.edges.shadows import sunlit_agreement

    view = ModelView(truss)
    at_truth = [sunlit_agreement(view, f, p) for f, p in close_views]
    assert min(precision for precision, _ in at_truth) >= 0.99, at_truth
    assert np.median([recall for _, recall in at_truth]) >= 0.95, at_truth
    axis = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
    wrong = [sunlit_agreement(view, f, p.retract(np.r_[np.radians(5.0) * axis, 0, 0, 0]))[0] for f, p in close_views]
    assert np.median(wrong) < 0.9, wrong
    # a fading sun (an eclipse: a tenth of the light) dims the surface, not the agreement
    frame, pose = close_views[0]
    dim = replace(frame, image=(frame.image * 0.1).astype(np.uint8))
    assert sunlit_agreement(view, dim, pose)[0] >= 0.97
    # no sun, no verdict
    assert np.isnan(sunlit_agreement(view, replace(frame, sun_direction_cam=None), pose)).all()


def test_the_quality_of_a_start_asks_for_the_sunlit_surface_too(truss, close_views):
    from hybridpose.edges import fit_edges, honest_quality

    view = ModelView(truss)
    axis = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
    right, wrong = [], []
    for frame, pose in close_views:
        for truth_off, out in ((0.0, right), (8.0, wrong)):
            fit = fit_edges(view, frame, pose.retract(np.r_[np.radians(truth_off) * axis, 0, 0, 0]), search_px=12)
            if fit is None:
                continue
            plain, strict = honest_quality(view, frame, fit), honest_quality(view, frame, fit, sunlit=True)
            assert strict <= plain
            out.append(strict)
    assert np.median(right) >= 0.7 and np.median(wrong) < 0.5, (right, wrong)
