"""Camera files as calibration tools write them (ROS camera_info, OpenCV FileStorage, ViSP XML) read
into the same Camera; projections checked against cv2.projectPoints and ViSP's own formula."""
import json

import cv2
import numpy as np
import pytest
import yaml

from hybridpose.geometry import Camera, NoImageSize, load_camera

K = np.array([[612.5, 0.0, 318.2], [0.0, 610.1, 241.7], [0.0, 0.0, 1.0]])
DIST5 = [-0.21, 0.08, 0.0012, -0.0007, -0.015]


def test_our_own_json_and_yaml(tmp_path):
    data = {"width": 640, "height": 480, "K": K.tolist(), "dist": DIST5}
    (tmp_path / "cam.json").write_text(json.dumps(data))
    (tmp_path / "cam.yaml").write_text(yaml.safe_dump(data))
    want = Camera.from_K(K, 640, 480, DIST5)
    assert load_camera(tmp_path / "cam.json") == want == load_camera(tmp_path / "cam.yaml")


def test_a_ros_camera_info_file(tmp_path):
    """camera_calibration's ost.yaml: K row-major, plumb_bob coefficients in OpenCV's order."""
    info = {"image_width": 640, "image_height": 480, "camera_name": "narrow_stereo",
            "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
            "distortion_model": "plumb_bob", "distortion_coefficients": {"rows": 1, "cols": 5, "data": DIST5},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": np.eye(3).ravel().tolist()},
            "projection_matrix": {"rows": 3, "cols": 4, "data": np.c_[K, np.zeros(3)].ravel().tolist()}}
    (tmp_path / "ost.yaml").write_text(yaml.safe_dump(info))
    assert load_camera(tmp_path / "ost.yaml") == Camera.from_K(K, 640, 480, DIST5)
    info["distortion_model"] = "equidistant"
    (tmp_path / "fisheye.yaml").write_text(yaml.safe_dump(info))
    with pytest.raises(ValueError, match="fisheye.yaml: distortion_model 'equidistant' is not supported"):
        load_camera(tmp_path / "fisheye.yaml")


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
@pytest.mark.parametrize("names", [("camera_matrix", "distortion_coefficients"), ("cameraMatrix", "distCoeffs")])
def test_an_opencv_filestorage_calibration(tmp_path, suffix, names):
    """As OpenCV's calibration sample writes it (cv::FileStorage, YAML or XML)."""
    path = str(tmp_path / f"calib{suffix}")
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write(names[0], K)
    fs.write(names[1], np.array(DIST5).reshape(5, 1))
    fs.release()
    assert load_camera(path) == Camera.from_K(K, 640, 480, DIST5)


VISP_CAMERA = """<?xml version="1.0"?>
<root>
  <camera>
    <name>myCamera</name>
    <image_width>640</image_width>
    <image_height>480</image_height>
    <model>
      <type>perspectiveProjWithoutDistortion</type>
      <px>600.0</px> <py>601.0</py> <u0>320.0</u0> <v0>240.0</v0>
    </model>
    <model>
      <type>perspectiveProjWithDistortion</type>
      <px>590.0</px> <py>591.0</py> <u0>321.0</u0> <v0>239.0</v0>
      <kud>-0.196</kud> <kdu>0.204</kdu>
    </model>
  </camera>
</root>
"""


def test_a_visp_camera_file_projects_as_visp_does(tmp_path):
    """The distorted model (the raw image's) is taken; ViSP's u = u0 + px·x·(1 + kud·r²) is what
    the camera then projects."""
    (tmp_path / "camera.xml").write_text(VISP_CAMERA)
    cam = load_camera(tmp_path / "camera.xml")
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (640, 480, 590.0, 591.0, 321.0, 239.0)
    points = np.random.default_rng(0).uniform([-0.2, -0.15, 0.5], [0.2, 0.15, 1.0], size=(20, 3))
    uv = cam.project_cam(points)
    x, y = points[:, 0] / points[:, 2], points[:, 1] / points[:, 2]
    factor = 1 + (-0.196) * (x**2 + y**2)
    assert np.allclose(uv, np.c_[321.0 + 590.0 * x * factor, 239.0 + 591.0 * y * factor], atol=1e-9)
    (tmp_path / "kb.xml").write_text(VISP_CAMERA.replace("perspectiveProjWith", "ProjWithKannalaBrandt"))
    with pytest.raises(ValueError, match="kb.xml: camera model .* is not supported"):
        load_camera(tmp_path / "kb.xml")


VISP_TRACKER_CONFIG = """<?xml version="1.0"?>
<conf>
  <ecm><range><tracking>7</tracking></range></ecm>
  <camera>
    <u0>338.7036994</u0>
    <v0>234.5083345</v0>
    <px>547.7367575</px>
    <py>542.0744058</py>
  </camera>
</conf>
"""


def test_a_visp_tracker_configuration_needs_the_frames_size(tmp_path):
    (tmp_path / "cube.xml").write_text(VISP_TRACKER_CONFIG)
    with pytest.raises(NoImageSize, match="cube.xml: the file gives the intrinsics but no image size"):
        load_camera(tmp_path / "cube.xml")
    cam = load_camera(tmp_path / "cube.xml", image_size="640x480")
    assert cam == Camera(640, 480, 547.7367575, 542.0744058, 338.7036994, 234.5083345)
    # one that gives the size (<width>, <height> under <camera>, as ViSP's detection tutorial's does)
    (tmp_path / "sized.xml").write_text(VISP_TRACKER_CONFIG.replace("<camera>", "<camera><width>640</width><height>480</height>"))
    assert load_camera(tmp_path / "sized.xml") == cam


@pytest.mark.parametrize("text, message", [
    ("{}", "missing key 'width'"),
    ("[1, 2]", "expected a mapping with width, height and K"),
    ("{not json", "cannot parse camera file"),
    ('{"image_width": 640, "image_height": 480, "camera_matrix": {"data": "abc"}}', "camera_matrix: expected"),
    ("<root><lens/></root>", "no <camera> element"),
    ("<root><camera><px>1</px></camera></root>", "<py> missing from the camera"),
])
def test_unreadable_camera_files_say_what_is_wrong(tmp_path, text, message):
    path = tmp_path / ("cam.xml" if text.startswith("<") else "cam.json")
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        load_camera(path)
    with pytest.raises(FileNotFoundError, match="camera file not found"):
        load_camera(tmp_path / "missing.json")
