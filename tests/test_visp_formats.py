"""ViSP's files at the edge: ``.cao`` models (points, lines, faces from points or lines, ``load``
includes, attributes) become meshes; ``.pos`` poses become ``Pose``; ``.pgm`` image folders are read."""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hybridpose.geometry import Camera, Pose
from hybridpose.objects import load_object
from hybridpose.objects.visp_cao import read_cao
from hybridpose.tracking import load_pose, read_frames

# ViSP's own mbt/cube.cao (visp-images-data), comments and all
CUBE = """V1
# 3D points
8                    # Number of points (here 8 cube corners)
 0.000  0.000  0.000 # Point with index 0
-0.084  0.000  0.000
-0.084  0.084  0.000
 0.000  0.084  0.000
 0.000  0.000  0.084
-0.084  0.000  0.084
-0.084  0.084  0.084
 0.000  0.084  0.084 # point with index 7
# 3D lines
0                    # No 3D lines
# 3D faces from lines
0                    # No 3D faces from lines
# 3D faces from points
6                    # 6 faces to describe the cube
4 0 4 5 1            # Face with index 0 defined by 3D point 0, 4, 5 and 1
4 1 5 6 2
4 6 7 3 2
4 3 7 4 0
4 0 1 2 3
4 7 6 5 4            # Face with index 5
# 3D cylinders
0
# 3D circle
0                    # No 3D circle
"""
SIDE = 0.084


def test_visps_cube_is_a_closed_outward_mesh_of_its_size(tmp_path):
    (tmp_path / "cube.cao").write_text(CUBE)
    obj = load_object(tmp_path / "cube.cao")
    mesh = obj.mesh
    assert len(mesh.faces) == 12 and mesh.is_watertight and mesh.volume == pytest.approx(SIDE ** 3)
    np.testing.assert_allclose(mesh.bounds, [[-SIDE, 0, 0], [0, SIDE, SIDE]])
    assert len(obj.symmetries) == 23  # a cube: 24 rotations that look the same, the identity left out
    # the sharp edges are the cube's 12 edges (the faces' diagonals are not)
    assert len(obj.sharp_edges) == 12


def test_faces_from_lines_attributes_and_includes_give_the_same_solid(tmp_path):
    corners = CUBE.split("# 3D lines")[0]
    quads = [[0, 4, 5, 1], [1, 5, 6, 2], [6, 7, 3, 2], [3, 7, 4, 0], [0, 1, 2, 3], [7, 6, 5, 4]]
    lines = sorted({tuple(sorted((q[k], q[(k + 1) % 4]))) for q in quads for k in range(4)})
    rows = [f"{a} {b}" for a, b in lines]
    faces = [f"4 {' '.join(str(lines.index(tuple(sorted((q[k], q[(k + 1) % 4]))))) for k in range(4))} name=\"face {i}\""
             for i, q in enumerate(quads)]
    text = corners + f"# lines\n{len(rows)}\n" + "\n".join(rows) + f"\n{len(faces)}\n" + "\n".join(faces) + "\n0\n0\n0\n"
    (tmp_path / "by_lines.cao").write_text(text)
    mesh = read_cao(tmp_path / "by_lines.cao")
    assert mesh.is_watertight and mesh.volume == pytest.approx(SIDE ** 3)
    # a file that loads the cube and adds a second one 0.2 m away: two solids
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "cube.cao").write_text(CUBE)
    shifted = "\n".join(f"{float(x) + 0.2:.3f} {y} {z}" for x, y, z in
                        (r.split("#")[0].split() for r in CUBE.splitlines()[3:11]))
    second = CUBE.split("# 3D points")[0] + "# 3D points\n8\n" + shifted + "\n" + CUBE.split("# point with index 7\n")[1]
    (tmp_path / "two.cao").write_text('V1\nload("parts/cube.cao")\n' + second.replace("V1\n", "", 1))
    two = read_cao(tmp_path / "two.cao")
    assert len(two.faces) == 24 and two.volume == pytest.approx(2 * SIDE ** 3)


def test_a_loaded_part_is_placed_where_the_load_call_puts_it(tmp_path):
    """ViSP's ``load("part.cao", t=[…], tu=[…])`` (its lego-square tutorial's assembly of four bricks):
    the part's points land at R(θu)·p + t, degrees or radians, nested placements composed."""
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "cube.cao").write_text(CUBE)
    (tmp_path / "pair.cao").write_text('V1\nload("parts/cube.cao")  # as it is\n'
                                       'load("parts/cube.cao", t=[0.3; 0.0; 0.1], tu=[0; 0; 90 deg])\n')
    (tmp_path / "assembly.cao").write_text('V1\nload("pair.cao", t=[0; -0.2; 0], tu=[0.2 rad; -0.1; 0.4])\n')
    cube = read_cao(tmp_path / "parts" / "cube.cao")
    pair = read_cao(tmp_path / "pair.cao")
    assert len(pair.faces) == 24 and pair.volume == pytest.approx(2 * SIDE ** 3)
    placed = Rotation.from_euler("z", 90, degrees=True).apply(cube.vertices) + [0.3, 0.0, 0.1]
    np.testing.assert_allclose(np.sort(pair.vertices, axis=0), np.sort(np.vstack([cube.vertices, placed]), axis=0),
                               atol=1e-12)
    assembly = read_cao(tmp_path / "assembly.cao")
    moved = Rotation.from_rotvec([0.2, -0.1, 0.4]).apply(pair.vertices) + [0, -0.2, 0]
    np.testing.assert_allclose(np.sort(assembly.vertices, axis=0), np.sort(moved, axis=0), atol=1e-12)


def test_a_non_convex_face_is_cut_into_triangles_that_keep_its_outline(tmp_path):
    """An L-shaped prism: two L faces (non-convex hexagons) and six rectangles."""
    L = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
    pts = [(x, y, 0.0) for x, y in L] + [(x, y, 0.5) for x, y in L]
    faces = ["6 5 4 3 2 1 0", "6 6 7 8 9 10 11"] + [f"4 {k} {(k + 1) % 6} {(k + 1) % 6 + 6} {k + 6}" for k in range(6)]
    text = f"V1\n{len(pts)}\n" + "\n".join(" ".join(map(str, p)) for p in pts) + f"\n0\n0\n{len(faces)}\n" + "\n".join(faces) + "\n0\n0\n"
    (tmp_path / "l.cao").write_text(text)
    mesh = read_cao(tmp_path / "l.cao")
    assert mesh.is_watertight and mesh.volume == pytest.approx(3 * 0.5)  # L area 3 × height 0.5


@pytest.mark.parametrize("text, match", [
    (CUBE.replace("0                    # No 3D circle", "1\n0.01 0 1 2"), "cylinders and circles are not supported"),
    (CUBE.replace("-0.084  0.084  0.000", "-0.084  oops  0.000"), r"cube.cao:6: cannot read this row of 3D points"),
    (CUBE.replace("4 1 5 6 2", "4 1 5 6 42"), "needs ≥ 3 existing points"),
    (CUBE.split("# 3D faces from points")[0] + "0\n0\n0\n", "no faces"),
    ('V1\nload("missing.cao")\n' + CUBE.replace("V1\n", ""), "missing.cao: .cao file not found"),
    ('V1\nload("cube.cao", tu=[0; 90 deg])\n', r"cube.cao:2: tu=\[0;90deg\]: expected three numbers"),
    ('V1\nload("cube.cao", scale=[2; 2; 2])\n', r"cube.cao:2: load\(...\) takes t=\[x; y; z\]"),
], ids=["circle", "bad-number", "missing-point", "no-faces", "missing-include", "bad-tu", "unknown-placement"])
def test_bad_cao_files_are_refused_naming_file_and_line(tmp_path, text, match):
    (tmp_path / "cube.cao").write_text(text)
    with pytest.raises((ValueError, FileNotFoundError), match=match):
        load_object(tmp_path / "cube.cao")


def test_a_visp_pose_file_is_translation_then_rotation_vector(tmp_path):
    (tmp_path / "cube.0.pos").write_text("0.02231950571  \n0.1071368004  \n0.5071128378  \n2.100485509  \n"
                                         "1.146812236  \n-0.4560126437  ")
    pose = load_pose(tmp_path / "cube.0.pos")
    np.testing.assert_allclose(pose.t, [0.02231950571, 0.1071368004, 0.5071128378])
    np.testing.assert_allclose(pose.R, Rotation.from_rotvec([2.100485509, 1.146812236, -0.4560126437]).as_matrix(), atol=1e-12)
    (tmp_path / "bad.pos").write_text("0 0 0.5 0 0")
    with pytest.raises(ValueError, match="bad.pos: expected a ViSP pose, six numbers"):
        load_pose(tmp_path / "bad.pos")


def test_a_folder_of_pgm_images_is_read_as_rgb_frames(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"image{i:04d}.pgm"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    frames = list(read_frames(tmp_path, Camera.default().scaled((64, 48)), fps=25))
    assert [f.index for f in frames] == [0, 1, 2] and frames[2].timestamp == pytest.approx(2 / 25)
    assert frames[0].image.shape == (48, 64, 3)
    np.testing.assert_array_equal(frames[1].image[..., 0], cv2.imread(str(tmp_path / "image0001.pgm"), cv2.IMREAD_GRAYSCALE))


def test_visps_tracker_camera_reads_and_the_real_video_benchmark_says_where_to_get_the_data(tmp_path, monkeypatch):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import real_video

    (tmp_path / "cube.xml").write_text("<?xml version='1.0'?><conf><camera><u0>338.7</u0><v0>234.5</v0>"
                                       "<px>547.7</px><py>542.1</py></camera></conf>")
    from hybridpose.geometry import load_camera

    cam = load_camera(tmp_path / "cube.xml", image_size=(640, 480))
    np.testing.assert_allclose(cam.K, [[547.7, 0, 338.7], [0, 542.1, 234.5], [0, 0, 1]])
    monkeypatch.delenv("VISP_INPUT_IMAGE_PATH", raising=False)
    with pytest.raises(SystemExit, match="apt-get download visp-images-data"):
        real_video.find_visp_images(str(tmp_path))
    (tmp_path / "mbt").mkdir()
    (tmp_path / "mbt" / "cube.cao").write_text(CUBE)
    assert real_video.find_visp_images(str(tmp_path)) == tmp_path


# two separate faces, as ViSP's castle (mbt-depth/castel/chateau.cao) is: a floor and a wall beside it
# that share no edge, each an open outline
PLATES = """V1
8
-0.10 0.00 -0.10
 0.10 0.00 -0.10
 0.10 0.00  0.10
-0.10 0.00  0.10
 0.14 -0.12 -0.10
 0.26 -0.12 -0.10
 0.26 -0.02 -0.10
 0.14 -0.02 -0.10
0
0
2
4 0 3 2 1 name=floor
4 4 5 6 7 name=wall
0
0
"""


def test_an_open_model_of_separate_faces_is_tracked_on_its_outlines(tmp_path):
    from hybridpose.core import Frame
    from hybridpose.edges import ModelView
    from hybridpose.metrics import rotation_error_deg
    from hybridpose.registry import create

    (tmp_path / "plates.cao").write_text(PLATES)
    obj = load_object(tmp_path / "plates.cao")
    view = ModelView(obj)
    # every sample on one of the two outlines (8 edges, 0.2 + 0.12 m long), none across a face
    on_edge = [np.any([np.isclose(np.linalg.norm(p - a) + np.linalg.norm(p - b), np.linalg.norm(b - a))
                       for a, b in obj.sharp_edges]) for p in view.points]
    assert all(on_edge) and len(view.points) >= (4 * 0.2 + 2 * (0.12 + 0.1)) / view.step_m - 1
    cam = Camera(320, 240, 300.0, 300.0, 159.5, 119.5)
    truth = Pose.from_rotvec_t([-0.5, 0.3, 0.05], [-0.05, 0.03, 0.45])
    # drawn 8× larger and shrunk (pixel areas averaged), pixel centres at integer coordinates
    fine = np.zeros((240 * 8, 320 * 8, 3), np.uint8)
    corners = read_cao_points(PLATES)
    for face, grey in (([0, 3, 2, 1], 200), ([4, 5, 6, 7], 120)):
        uv = (cam.project(corners[face], truth) + 0.5) * 8 - 0.5
        cv2.fillPoly(fine, [np.round(uv * 16).astype(np.int32)], (grey, grey, grey), cv2.LINE_8, shift=4)
    frame = Frame(cv2.resize(fine, (320, 240), interpolation=cv2.INTER_AREA), cam, 0.0, 0)
    tracker = create("tracker", "edges", object=obj, explain=False)
    start = truth.retract(np.r_[np.radians([1.0, -0.8, 0.5]), 0.003, -0.002, 0.004])
    tracker.init(frame, start)
    m = tracker.track(frame, start)
    assert not m.lost and rotation_error_deg(m.pose, truth) < 0.3 and np.linalg.norm(m.pose.t - truth.t) < 0.002


def read_cao_points(text: str) -> np.ndarray:
    lines = [ln for ln in text.splitlines()[1:] if ln.strip()]
    n = int(lines[0])
    return np.array([[float(x) for x in ln.split()[:3]] for ln in lines[1:1 + n]])


def test_the_real_video_benchmark_scores_the_cnn_alone_to_the_nearest_equivalent_pose(tmp_path, monkeypatch):
    """The cube's CNN-alone line: a pose that is the reference turned by one of the cube's symmetries
    counts as right, one 20° off or with no pose as a miss, from the whole frame and given the box."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import real_video

    from hybridpose.core import LOST_COVARIANCE, Frame, Measurement
    import hybridpose.regressors.predictor as predictor

    (tmp_path / "cube.cao").write_text(CUBE)
    cube = load_object(tmp_path / "cube.cao")
    cam = Camera.default().scaled((640, 480))
    ref = Pose.from_rotvec_t([0.4, -0.3, 0.2], [0.02, 0.01, 0.5])
    frames = [Frame(np.zeros((480, 640, 3), np.uint8), cam, k / 30, k) for k in range(12)]
    turned = ref @ cube.symmetries[0]  # the same cube, another corner at the origin
    off = ref @ Pose.from_rotvec_t([np.radians(20), 0, 0], [0, 0, 0])

    class FakeRegressor:
        def __init__(self, path, object=None):
            assert path == "fit.pt" and object is cube

        def predict(self, frame, roi=None):
            if roi is not None:  # given the box: right, but for frame 6
                x, y, w, h = roi
                u, v = cam.project(cube.bbox_corners, ref).T
                assert x <= u.min() + 1 and y <= v.min() + 1 and x + w >= u.max() - 1 and y + h >= v.max() - 1
                return Measurement(off if frame.index == 6 else ref, np.eye(6), 1.0, "cnn", frame.timestamp)
            if frame.index == 6:
                return Measurement(None, LOST_COVARIANCE, 0.0, "cnn", frame.timestamp, lost=True)
            return Measurement(turned if frame.index == 0 else off, np.eye(6), 1.0, "cnn", frame.timestamp)

    monkeypatch.setattr(predictor, "CheckpointRegressor", FakeRegressor)
    reference = {"poses": [ref] * 12, "lost_per_frame": [k == 9 for k in range(12)]}
    alone = real_video.cnn_alone(frames, cube, "fit.pt", reference, every=3)
    assert alone["frames"] == [0, 3, 6]  # frame 9 was sampled too, but the reference lost it
    assert alone["whole"]["in_basin"] == [0] and alone["whole"]["found"] == 2
    assert alone["box"]["in_basin"] == [0, 3] and alone["box"]["found"] == 3
    line = real_video.cnn_alone_lines(alone, "edges")[0]
    assert "one frame in 3" in line and "on 1 of 3 (" in line and "on 2 of 3 (" in line
