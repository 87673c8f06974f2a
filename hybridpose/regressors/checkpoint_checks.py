"""What a trained checkpoint refuses or warns about before it predicts: a file that holds no regressor,
another object than the one it was trained on, another field of view than its training camera's."""
from __future__ import annotations

import warnings

from ..geometry import Camera
from .checkpoints import load_checkpoint
from .models import available_models

FOV_TOLERANCE = 0.02  # direct models: relative focal (per image size) difference still accepted
# Keypoint models crop a virtual camera around the object, so another field of view changes only the
# perspective inside the crop. Measured with the shipped checkpoint (150 in-view renders per camera,
# 640×480, distances scaled with the focal): fine from 0.5× to 2.7× the trained focal per image size
# (docs/decisions.md); outside that range a warning says it was not measured.
KEYPOINT_FOCAL_RANGE = (0.5, 2.7)


def regressor_checkpoint(path, expect_model: str | None = None) -> dict:
    """The checkpoint at ``path`` (:func:`~hybridpose.regressors.checkpoints.load_checkpoint`); ValueError,
    naming the file, unless it holds a known regressor model (``expect_model``, where given)."""
    ck = load_checkpoint(path)
    for key in ("config", "model", "build"):
        if key not in ck:
            raise ValueError(f"{path}: not a hybridpose regressor checkpoint (no {key!r})")
    name = ck["config"]["model"]
    if name not in available_models():
        raise ValueError(f"{path}: checkpoint is for unknown model {name!r}")
    if expect_model is not None and expect_model != name:
        raise ValueError(f"{path}: checkpoint holds a {name!r} model, not {expect_model!r}")
    return ck


def builtin_object(dataset: dict):
    """The built-in object a checkpoint was trained on (``dataset``: its training set's record), or None
    where the record names none — or names one whose diameter its object did not have (a user's
    ``cube.obj`` carries the built-in cube's name, not its mesh)."""
    from ..objects import load_builtin

    obj = load_builtin(dataset.get("object"))
    d = dataset.get("diameter_m")
    return obj if obj is not None and (d is None or abs(obj.diameter - d) <= 1e-6) else None


def check_object(dataset: dict, path, obj) -> None:
    """ValueError unless ``obj`` has the diameter of the object the checkpoint at ``path`` was trained on
    (``dataset``: its training set's record)."""
    d = dataset.get("diameter_m")
    if d is not None and abs(obj.diameter - d) > 0.01 * d:
        raise ValueError(
            f"object: {path} was trained on {dataset.get('object')!r} (diameter {d:.3f} m), "
            f"not on {obj.name!r} (diameter {obj.diameter:.3f} m); fit one for your object "
            "(hybridpose fit MESH --out DIR) and pass its best.pt"
        )


def check_camera(dataset: dict, kind: str, path, camera: Camera) -> None:
    """Direct models learned one field of view (another one: ValueError); keypoint models normalise
    it away with the crop (outside ``KEYPOINT_FOCAL_RANGE`` of the trained one: a warning)."""
    cam = dataset.get("camera")
    if not cam:
        return
    if kind == "keypoints":
        ratio = (camera.fx / camera.width) / (cam["fx"] / cam["width"])
        low, high = KEYPOINT_FOCAL_RANGE
        if not low <= ratio <= high:
            warnings.warn(
                f"frame.camera: fx/width = {camera.fx / camera.width:.3f} is {ratio:.2f}× what {path} was "
                f"trained at ({cam['fx'] / cam['width']:.3f}); keypoint models were measured from {low}× to "
                f"{high}× only — check the accuracy on your camera (render data with --camera, hybridpose eval)",
                UserWarning, stacklevel=4)
        return
    for f, n, key in ((camera.fx, camera.width, "fx"), (camera.fy, camera.height, "fy")):
        trained = cam[key] / cam["width" if key == "fx" else "height"]
        if abs(f / n - trained) > FOV_TOLERANCE * trained:
            raise ValueError(
                f"frame.camera: {path} was trained for {key}/size = {trained:.4f}, the frame's camera has "
                f"{f / n:.4f}; a direct regressor only works at its training field of view (render data with --camera)"
            )
