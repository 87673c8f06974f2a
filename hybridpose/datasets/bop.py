"""BOP format, read and written exactly: the only place where millimetres meet metres.

Layout written by hybridpose (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md)::

    <root>/camera.json                      width, height, fx, fy, cx, cy, depth_scale
    <root>/models/obj_000001.ply            model in mm, models/models_info.json (diameter in mm)
    <root>/<split>/<scene:06d>/rgb/<im:06d>.png
                                /depth/<im:06d>.png            uint16, depth_mm = value · depth_scale
                                /mask/<im:06d>_000000.png      full silhouette
                                /mask_visib/<im:06d>_000000.png
                                /scene_gt.json                 cam_R_m2c (row-major), cam_t_m2c (mm), obj_id
                                /scene_camera.json             cam_K, depth_scale
                                /scene_gt_info.json            bbox_obj, bbox_visib, px counts, visib_fract
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import Camera, Pose
from ..io import atomic_write_bytes, atomic_write_json, read_image, read_json, write_image

MM_PER_M = 1000.0  # BOP files hold millimetres
DEPTH_SCALE_MM = 0.1  # one depth unit = 0.1 mm → uint16 holds up to 6.5 m
OBJ_ID = 1  # one object per scene: BOP's obj_id of it


def pose_to_bop(pose: Pose) -> dict:
    """``{"cam_R_m2c": 9 floats, "cam_t_m2c": 3 floats in mm}``."""
    return {"cam_R_m2c": pose.R.ravel().tolist(), "cam_t_m2c": (pose.t * MM_PER_M).tolist()}


def pose_from_bop(entry: dict, where: str = "scene_gt") -> Pose:
    """Inverse of :func:`pose_to_bop`; errors name ``where``."""
    try:
        R = np.asarray(entry["cam_R_m2c"], dtype=np.float64).reshape(3, 3)
        t = np.asarray(entry["cam_t_m2c"], dtype=np.float64).reshape(3) / MM_PER_M
    except (KeyError, ValueError) as exc:
        raise ValueError(f"{where}: expected cam_R_m2c (9 numbers) and cam_t_m2c (3 numbers, mm): {exc}") from exc
    try:
        return Pose(R, t)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from exc


def bbox_xywh(mask: np.ndarray) -> list[int]:
    """BOP bbox ``[x, y, w, h]`` of a boolean mask, ``[-1, -1, -1, -1]`` when empty."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


def write_models(root, obj) -> None:
    """``models/obj_000001.ply`` (mm) and ``models/models_info.json``."""
    mesh = obj.mesh.copy()
    mesh.apply_scale(MM_PER_M)
    atomic_write_bytes(Path(root) / "models" / f"obj_{OBJ_ID:06d}.ply", mesh.export(file_type="ply"))
    lo, hi = obj.bbox_min * MM_PER_M, obj.bbox_max * MM_PER_M
    info = {str(OBJ_ID): {"diameter": obj.diameter * MM_PER_M, "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
                          "size_x": hi[0] - lo[0], "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2], "name": obj.name}}
    # BOP's form: row-major 4×4, translation in mm; written also when empty, so that a reader knows the
    # object was declared asymmetric (a printed cube) rather than left to its mesh's shape
    info[str(OBJ_ID)]["symmetries_discrete"] = [
        np.r_[S.R.ravel()[:3], S.t[0] * MM_PER_M, S.R.ravel()[3:6], S.t[1] * MM_PER_M, S.R.ravel()[6:],
              S.t[2] * MM_PER_M, 0.0, 0.0, 0.0, 1.0].tolist() for S in obj.symmetries]
    atomic_write_json(Path(root) / "models" / "models_info.json", info)


def write_camera_json(root, camera: Camera) -> None:
    atomic_write_json(Path(root) / "camera.json", {
        "width": camera.width, "height": camera.height, "fx": camera.fx, "fy": camera.fy,
        "cx": camera.cx, "cy": camera.cy, "depth_scale": DEPTH_SCALE_MM,
    })


def read_camera_json(root) -> Camera:
    d = read_json(Path(root) / "camera.json")
    try:
        return Camera(d["width"], d["height"], d["fx"], d["fy"], d["cx"], d["cy"])
    except KeyError as exc:
        raise ValueError(f"{Path(root) / 'camera.json'}: missing key {exc.args[0]!r}") from None


class BopSceneWriter:
    """Writes one BOP scene image by image; JSON files are rewritten atomically on :meth:`flush`.

    Re-opening an existing scene keeps its entries (this is how an interrupted render resumes);
    ``load=False`` starts empty (a worker process whose records another writer :meth:`merge` s).
    """

    def __init__(self, scene_dir, camera: Camera, load: bool = True) -> None:
        self.dir = Path(scene_dir)
        self.camera = camera
        self.gt: dict[str, list] = {}
        self.cam: dict[str, dict] = {}
        self.info: dict[str, list] = {}
        if load and (self.dir / "scene_gt.json").exists():
            scene = BopScene(self.dir)
            self.gt, self.cam, self.info = scene.gt_raw, scene.camera_raw, scene.info_raw

    def done(self, im_id: int) -> bool:
        """True when image ``im_id`` is recorded in the JSONs and its files exist."""
        k = str(im_id)
        return k in self.gt and k in self.info and all(
            (self.dir / sub / name).is_file()
            for sub, name in (("rgb", f"{im_id:06d}.png"), ("mask_visib", f"{im_id:06d}_000000.png"))
        )

    def write(self, im_id: int, rgb, depth_m, mask, mask_visib, pose: Pose, vertices_obj=None) -> None:
        """Write one image and record its ground truth.

        Args:
            rgb: (H, W, 3) uint8. depth_m: (H, W) float metres (0 = no data).
            mask, mask_visib: (H, W) bool. pose: ``T_cam_obj``.
            vertices_obj: (N, 3) model points; their projection gives ``bbox_obj`` (may extend
                beyond the image, as in BOP). Defaults to the full-mask bbox.
        """
        self.camera.check_image(rgb, "rgb")
        name = f"{im_id:06d}"
        write_image(self.dir / "rgb" / f"{name}.png", rgb)
        depth_units = np.clip(np.round(np.asarray(depth_m) * MM_PER_M / DEPTH_SCALE_MM), 0, 65535).astype(np.uint16)
        write_image(self.dir / "depth" / f"{name}.png", depth_units)
        write_image(self.dir / "mask" / f"{name}_000000.png", mask.astype(np.uint8) * 255)
        write_image(self.dir / "mask_visib" / f"{name}_000000.png", mask_visib.astype(np.uint8) * 255)
        if vertices_obj is not None:
            uv = self.camera.project(vertices_obj, pose)
            lo, hi = np.floor(uv.min(0) + 0.5), np.floor(uv.max(0) + 0.5)
            bbox_obj = [int(lo[0]), int(lo[1]), int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)]
        else:
            bbox_obj = bbox_xywh(mask)
        n_all, n_vis = int(mask.sum()), int(mask_visib.sum())
        self.gt[str(im_id)] = [{**pose_to_bop(pose), "obj_id": OBJ_ID}]
        self.cam[str(im_id)] = {"cam_K": self.camera.K.ravel().tolist(), "depth_scale": DEPTH_SCALE_MM}
        self.info[str(im_id)] = [{
            "bbox_obj": bbox_obj, "bbox_visib": bbox_xywh(mask_visib), "px_count_all": n_all,
            "px_count_valid": n_all, "px_count_visib": n_vis, "visib_fract": (n_vis / n_all) if n_all else 0.0,
        }]

    def merge(self, other: "BopSceneWriter") -> None:
        """Take over the records of ``other`` (same scene; its image files are already written)."""
        self.gt.update(other.gt)
        self.cam.update(other.cam)
        self.info.update(other.info)

    def flush(self) -> None:
        def ordered(d):
            return {k: d[k] for k in sorted(d, key=int)}

        atomic_write_json(self.dir / "scene_camera.json", ordered(self.cam))
        atomic_write_json(self.dir / "scene_gt_info.json", ordered(self.info))
        atomic_write_json(self.dir / "scene_gt.json", ordered(self.gt))  # last: it marks images done


@dataclass(frozen=True)
class BopImage:
    """Ground truth of one image of a scene (metres)."""

    im_id: int
    pose: Pose
    camera: Camera
    visib_fract: float
    bbox_obj: tuple[int, int, int, int]
    bbox_visib: tuple[int, int, int, int]


class BopScene:
    """Read one BOP scene directory (``.../<split>/<scene_id>``) with the first object per image.

    Raises:
        FileNotFoundError: a missing scene directory or JSON file (named).
        ValueError: corrupt JSON or malformed entries (file and image named).
    """

    def __init__(self, scene_dir) -> None:
        self.dir = Path(scene_dir)
        if not self.dir.is_dir():
            raise FileNotFoundError(f"{self.dir}: BOP scene directory not found")
        self.gt_raw = read_json(self.dir / "scene_gt.json")
        self.camera_raw = read_json(self.dir / "scene_camera.json")
        info_path = self.dir / "scene_gt_info.json"
        self.info_raw = read_json(info_path) if info_path.exists() else {}
        self.image_ids = sorted(int(k) for k in self.gt_raw)
        self._size = self._image_size()
        self._meta: dict | None = None  # scene_meta.json's frames, read on first use

    def _image_size(self) -> tuple[int, int]:
        for root in (self.dir.parent.parent, self.dir.parent):
            if (root / "camera.json").is_file():
                cam = read_json(root / "camera.json")
                if "width" in cam and "height" in cam:
                    return int(cam["width"]), int(cam["height"])
        if not self.image_ids:
            return (1, 1)
        img = read_image(self.rgb_path(self.image_ids[0]))
        return img.shape[1], img.shape[0]

    def __len__(self) -> int:
        return len(self.image_ids)

    def rgb_path(self, im_id: int) -> Path:
        for ext in (".png", ".jpg"):
            p = self.dir / "rgb" / f"{im_id:06d}{ext}"
            if p.exists():
                return p
        return self.dir / "rgb" / f"{im_id:06d}.png"

    def camera(self, im_id: int) -> Camera:
        where = f"{self.dir / 'scene_camera.json'} image {im_id}"
        try:
            K = self.camera_raw[str(im_id)]["cam_K"]
        except KeyError:
            raise ValueError(f"{where}: missing cam_K") from None
        try:
            return Camera.from_K(K, *self._size)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from exc

    def image(self, im_id: int) -> BopImage:
        where = f"{self.dir / 'scene_gt.json'} image {im_id}"
        try:
            entry = self.gt_raw[str(im_id)][0]
        except (KeyError, IndexError):
            raise ValueError(f"{where}: no ground truth") from None
        info = (self.info_raw.get(str(im_id)) or [{}])[0]
        return BopImage(
            im_id=im_id,
            pose=pose_from_bop(entry, where),
            camera=self.camera(im_id),
            visib_fract=float(info.get("visib_fract", 1.0)),
            bbox_obj=tuple(info.get("bbox_obj", (-1, -1, -1, -1))),
            bbox_visib=tuple(info.get("bbox_visib", (-1, -1, -1, -1))),
        )

    def sun_direction_cam(self, im_id: int) -> np.ndarray | None:
        """(3,) unit direction the sunlight of image ``im_id`` travels, camera frame, as recorded by
        ``hybridpose render`` in ``scene_meta.json``; None for scenes without it (other BOP data)."""
        if self._meta is None:
            path = self.dir / "scene_meta.json"
            self._meta = read_json(path).get("frames", {}) if path.is_file() else {}
        d = self._meta.get(str(im_id), {}).get("sun_direction_cam")
        return None if d is None else np.asarray(d, dtype=np.float64)

    def rgb(self, im_id: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB."""
        return read_image(self.rgb_path(im_id), "rgb")

    def mask(self, im_id: int, visible: bool = True) -> np.ndarray:
        """(H, W) bool object mask (visible part by default, else the full silhouette)."""
        sub = "mask_visib" if visible else "mask"
        return read_image(self.dir / sub / f"{im_id:06d}_000000.png", "gray") > 127

    def depth_m(self, im_id: int) -> np.ndarray:
        """(H, W) float32 depth in metres (0 = no data)."""
        scale = float(self.camera_raw.get(str(im_id), {}).get("depth_scale", 1.0))
        raw = read_image(self.dir / "depth" / f"{im_id:06d}.png", "unchanged")
        return raw.astype(np.float32) * (scale / MM_PER_M)


def find_scenes(root) -> list[Path]:
    """All BOP scene directories under ``root`` (a scene, a split, a dataset root, or a folder of
    dataset roots such as several ``hybridpose render`` outputs), sorted: the shallowest level that
    holds any."""
    root = Path(root)
    if not root.exists():
        raise FileNotFoundError(f"{root}: dataset not found")
    if (root / "scene_gt.json").is_file():
        return [root]
    scenes = []
    for pattern in ("*/scene_gt.json", "*/*/scene_gt.json", "*/*/*/scene_gt.json"):
        scenes = sorted(p.parent for p in root.glob(pattern))
        if scenes:
            break
    if not scenes:
        raise FileNotFoundError(f"{root}: no BOP scene (no scene_gt.json under it)")
    return scenes


def read_symmetries(info_path, obj_id: int = OBJ_ID):
    """The object's ``symmetries_discrete`` of a BOP ``models_info.json`` as poses (metres); None where
    the file or the key is missing (then the mesh decides: :class:`~hybridpose.objects.ObjectModel`)."""
    from ..geometry import Pose

    info_path = Path(info_path)
    if not info_path.is_file():
        return None
    entry = read_json(info_path).get(str(obj_id), {})
    if "symmetries_discrete" not in entry:
        return None
    out = []
    for flat in entry.get("symmetries_discrete", []):
        T = np.asarray(flat, dtype=np.float64).reshape(4, 4)
        T[:3, 3] /= MM_PER_M
        out.append(Pose.from_matrix(T))
    return tuple(out)


def _same_model(obj, model_path: Path) -> bool:
    """Whether the BOP model ``model_path`` (mm) is ``obj``'s mesh: a user's ``cube.obj`` carries a
    built-in's name, not its mesh (the same face count and bounds, to 1 µm)."""
    import trimesh

    mesh = trimesh.load(model_path, force="mesh", process=False)
    return (len(mesh.faces) == len(obj.faces)
            and np.allclose(np.asarray(mesh.bounds) / MM_PER_M, [obj.bbox_min, obj.bbox_max], atol=1e-6))


def dataset_object(root, object_name: str | None = None):
    """The object a dataset was rendered with: ``object_name`` (built-in name or mesh path) when
    given, else the dataset's own BOP model ``models/obj_000001.ply`` (millimetres → metres).

    A dataset rendered from a registered built-in object (its name in ``hybridpose.json`` and its
    mesh in ``models/``) gets that object back, with its own keypoints, rather than the re-read mesh.
    """
    from ..objects import load_builtin, load_object

    root = Path(root)
    if object_name is not None:
        return load_object(object_name)
    config = root / "hybridpose.json"
    builtin = load_builtin(json.loads(config.read_text()).get("object")) if config.is_file() else None
    model_path = root / "models" / "obj_000001.ply"
    if builtin is not None and (not model_path.is_file() or _same_model(builtin, model_path)):
        return builtin
    if model_path.is_file():
        return load_object(model_path, scale=0.001, name="obj_000001",  # BOP models are in mm
                           symmetries=read_symmetries(root / "models" / "models_info.json"))
    raise ValueError(f"{root}: no models/obj_000001.ply; pass the object (name or mesh path) explicitly")
