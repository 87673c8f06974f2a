"""Camera files as the tools users calibrate with write them, read at the edge into a :class:`Camera`.

- hybridpose's own JSON or YAML: ``{"width", "height", "K" | "fx", "fy", "cx", "cy", "dist"?}``;
- ROS ``sensor_msgs/CameraInfo`` YAML, as ``camera_calibration`` writes it (``image_width``,
  ``image_height``, ``camera_matrix.data``, ``distortion_model`` ``plumb_bob`` or
  ``rational_polynomial``, ``distortion_coefficients.data``);
- OpenCV ``cv::FileStorage`` YAML (``%YAML:1.0``) or XML (``<opencv_storage>``), as OpenCV's
  calibration sample writes it (``image_width``, ``image_height``, ``camera_matrix``,
  ``distortion_coefficients``; also ``cameraMatrix`` / ``distCoeffs`` and ``K`` / ``D``);
- ViSP XML: a ``vpXmlParserCamera`` file (``<root><camera>`` with ``image_width``, ``image_height``
  and ``<model>`` entries: ``perspectiveProjWithDistortion`` is taken where present, since it models
  the raw image — ViSP's ``u = u0 + px·x·(1 + kud·r²)`` is OpenCV's model with ``k1 = kud``), or a
  model-based tracker's configuration (``<conf><camera>`` with ``u0 v0 px py``), which gives the image
  size only at times (``<width>``, ``<height>``): else ``image_size`` does (``hybridpose track`` takes it
  from the first frame).

Fisheye models (ROS ``equidistant``, ViSP Kannala–Brandt) are refused: rectify the images first.
"""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .camera import Camera, parse_size

ROS_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")
# names OpenCV's calibration samples and common scripts give the matrices, first found wins
OPENCV_MATRIX_NAMES = ("camera_matrix", "cameraMatrix", "K")
OPENCV_DIST_NAMES = ("distortion_coefficients", "distCoeffs", "dist_coeffs", "D")


class NoImageSize(ValueError):
    """The camera file gives intrinsics but no image size (a ViSP tracker configuration)."""


def load_camera(path, image_size=None) -> Camera:
    """Read a camera file of any format above (told apart by content, not by suffix).

    Args:
        path: the file.
        image_size: (W, H) pixels (or ``"WxH"``) for a file that gives no image size; ignored
            where the file gives one.

    Raises:
        FileNotFoundError: no such file. NoImageSize (a ValueError): the file gives no size and
        ``image_size`` is None. ValueError: anything else unreadable, naming the file and what
        was expected.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    text = path.read_text(errors="replace")
    head = text.lstrip()[:200]
    try:
        if head.startswith("%YAML") or "<opencv_storage" in head:
            data = _opencv_storage(path)
        elif head.startswith("<"):
            data = _visp_xml(path)
        elif path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = _ros_camera_info(yaml.safe_load(text), path)
        else:
            data = _ros_camera_info(json.loads(text), path)
    except (NoImageSize, FileNotFoundError):
        raise
    except ValueError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise ValueError(f"{path}: cannot parse camera file ({exc})") from exc
    except Exception as exc:  # noqa: BLE001 — any parser error becomes one message naming the file
        raise ValueError(f"{path}: cannot parse camera file ({exc})") from exc
    # the formats that know about an image size say None where the file gives none
    if ("width" in data and data["width"] is None) or ("height" in data and data["height"] is None):
        if image_size is None:
            raise NoImageSize(f"{path}: the file gives the intrinsics but no image size (width, height); "
                              "give the size of the frames it calibrates")
        data["width"], data["height"] = parse_size(image_size)
    return Camera.from_dict(data)


def _ros_camera_info(data, path: Path) -> dict:
    """Our own keys as they are, or a ROS ``CameraInfo`` YAML's mapped onto them."""
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping with width, height and K (or a ROS camera_info file)")
    if "camera_matrix" not in data:
        return data
    model = str(data.get("distortion_model", "plumb_bob"))
    if model not in ROS_DISTORTION_MODELS:
        raise ValueError(f"{path}: distortion_model {model!r} is not supported (expected "
                         f"{' or '.join(ROS_DISTORTION_MODELS)}, OpenCV's model); rectify fisheye images first")
    K = _ros_matrix(data["camera_matrix"], "camera_matrix", path)
    dist = _ros_matrix(data.get("distortion_coefficients") or {"data": []}, "distortion_coefficients", path)
    return {"width": data.get("image_width"), "height": data.get("image_height"), "K": K.reshape(3, 3).tolist(),
            "dist": dist.ravel().tolist()}


def _ros_matrix(entry, name: str, path: Path) -> np.ndarray:
    values = entry.get("data") if isinstance(entry, dict) else entry
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: {name}: expected {{rows, cols, data: [numbers]}}, got {entry!r}") from None


def _opencv_storage(path: Path) -> dict:
    """An OpenCV ``FileStorage`` calibration (YAML with ``!!opencv-matrix`` tags, or XML)."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise ValueError(f"{path}: OpenCV cannot open this FileStorage file")
    try:
        def node(names):
            return next((fs.getNode(n) for n in names if not fs.getNode(n).empty()), None)

        K = node(OPENCV_MATRIX_NAMES)
        if K is None or K.mat() is None:
            raise ValueError(f"{path}: no camera matrix (expected one of {', '.join(OPENCV_MATRIX_NAMES)})")
        dist = node(OPENCV_DIST_NAMES)
        size = {key: fs.getNode(name) for key, name in (("width", "image_width"), ("height", "image_height"))}
        return {"K": K.mat().tolist(), "dist": [] if dist is None or dist.mat() is None else dist.mat().ravel().tolist(),
                **{key: None if n.empty() else int(n.real()) for key, n in size.items()}}
    finally:
        fs.release()


def _visp_xml(path: Path) -> dict:
    """A ViSP camera file (``vpXmlParserCamera``) or a model-based tracker's configuration."""
    root = ET.parse(path).getroot()
    camera = root if root.tag == "camera" else root.find("camera")
    if camera is None:
        raise ValueError(f"{path}: no <camera> element (expected a ViSP camera file or tracker configuration)")
    models = {(m.findtext("type") or "").strip(): m for m in camera.findall("model")}
    if models:
        if "perspectiveProjWithDistortion" in models:
            model = models["perspectiveProjWithDistortion"]
        elif "perspectiveProjWithoutDistortion" in models:
            model = models["perspectiveProjWithoutDistortion"]
        else:
            raise ValueError(f"{path}: camera model {', '.join(models)} is not supported (expected "
                             "perspectiveProjWithDistortion or perspectiveProjWithoutDistortion); rectify fisheye "
                             "images first")
    else:
        model = camera  # a tracker configuration: px, py, u0, v0 right under <camera>

    def number(element, name):
        text = element.findtext(name)
        if text is None:
            raise ValueError(f"{path}: <{name}> missing from the camera (expected px, py, u0, v0)")
        return float(text)

    kud = float(model.findtext("kud") or 0.0)
    # a tracker configuration may give the frames' size as <width> and <height> (ViSP's detection tutorial's)
    size = {key: camera.findtext(name) or camera.findtext(key) for key, name in (("width", "image_width"),
                                                                                 ("height", "image_height"))}
    return {"fx": number(model, "px"), "fy": number(model, "py"), "cx": number(model, "u0"), "cy": number(model, "v0"),
            "dist": [kud, 0.0, 0.0, 0.0] if kud else [], **{k: None if v is None else int(v) for k, v in size.items()}}
