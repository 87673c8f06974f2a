"""Load an :class:`ObjectModel` by built-in name or from a mesh file (anything trimesh reads, and
ViSP's ``.cao`` models)."""
from __future__ import annotations

import logging
import warnings
from pathlib import Path

import cv2
import numpy as np
import trimesh

from .. import registry
from .base import ObjectModel, boundary_edges

log = logging.getLogger(__name__)

# A rigid object that a monocular camera tracks at arm's reach is centimetres to metres across;
# outside these bounds the file is almost surely in other units.
MAX_PLAUSIBLE_DIAMETER_M = 5.0
MIN_PLAUSIBLE_DIAMETER_M = 0.005  # smaller: the file is in other units (see above)
# a mesh's print is kept at most this many pixels along its longer side: a part filling a 640 × 480 frame
# shows a face a few hundred pixels across, and every render process holds its own copy
MAX_TEXTURE_SIDE = 2048


def load_builtin(name) -> ObjectModel | None:
    """The registered built-in object called ``name``, or None when it is not one (a user's mesh
    recorded in a dataset or checkpoint by its file name, say)."""
    return registry.create("object", name) if name in registry.available("object") else None


def _load_mesh(path: Path) -> trimesh.Trimesh:
    try:
        return trimesh.load(path, force="mesh")
    except Exception as exc:  # noqa: BLE001 — any loader error becomes one message naming the file
        raise ValueError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from exc


def mesh_print(mesh: trimesh.Trimesh) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The image a textured mesh carries and its faces' corners on it: ((H, W, 3) uint8 RGB, (M, 3, 2)
    texture coordinates), or (None, None) for a mesh without one — no UV coordinates, no image, or a
    uniform one (trimesh gives an OBJ whose material file is missing a 2 × 2 grey stand-in)."""
    visual = getattr(mesh, "visual", None)
    uv = getattr(visual, "uv", None)
    image = getattr(getattr(visual, "material", None), "image", None)
    if uv is None or image is None or len(uv) != len(mesh.vertices):
        return None, None
    rgb = np.asarray(image.convert("RGB"), dtype=np.uint8)
    if rgb.size == 0 or np.all(rgb == rgb.reshape(-1, 3)[0]):
        return None, None
    if max(rgb.shape[:2]) > MAX_TEXTURE_SIDE:
        f = MAX_TEXTURE_SIDE / max(rgb.shape[:2])
        rgb = cv2.resize(rgb, (max(1, round(rgb.shape[1] * f)), max(1, round(rgb.shape[0] * f))), interpolation=cv2.INTER_AREA)
    return rgb, np.asarray(uv, dtype=np.float64)[np.asarray(mesh.faces)]


def load_object(name_or_path, scale: float = 1.0, name: str | None = None, symmetries=None) -> ObjectModel:
    """A built-in object (``"truss"``) or a mesh file (.obj, .ply, .stl, ..., or a ViSP .cao model).

    Args:
        name_or_path: registered object name or path to a mesh file.
        scale: multiplies the file's coordinates to get metres (``0.001`` for a file in mm).
        symmetries: a mesh file's symmetries (poses in metres) when known; None: detected from the mesh.
        name: model name; defaults to the registered name or the file stem.
    Raises:
        FileNotFoundError: neither a built-in name nor an existing file.
        ValueError: unreadable file, empty mesh, or non-positive ``scale``.
    Warns:
        UserWarning: when the diameter suggests the file is not in metres.
    """
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"scale: expected a positive factor to metres (e.g. 0.001 for mm), got {scale}")
    key = str(name_or_path)
    if key in registry.available("object"):
        model = registry.create("object", key)
        if scale != 1.0:
            mesh = model.mesh.copy()
            mesh.apply_scale(scale)
            model = ObjectModel(name or model.name, mesh, symmetries=None if model.symmetries else ())
        return model
    path = Path(key)
    if not path.exists():
        raise FileNotFoundError(
            f"object: {key!r} is neither a built-in object ({', '.join(registry.available('object'))}) "
            "nor an existing mesh file"
        )
    if path.suffix.lower() == ".cao":
        from .visp_cao import read_cao

        mesh = read_cao(path)  # its errors name the file and line
    else:
        mesh = _load_mesh(path)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: no triangles found; expected a mesh file trimesh can read (.obj, .ply, .stl)")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"{path}: vertices contain NaN or inf")
    texture, face_uv = mesh_print(mesh)  # before merging: a seam's corners keep their own coordinates
    if not mesh.is_watertight:
        # a textured mesh splits its vertices along UV seams, and each seam becomes an open outline;
        # the geometry is one surface (silhouettes and creases need it whole)
        merged = mesh.copy()
        merged.merge_vertices(merge_tex=True, merge_norm=True)
        if len(boundary_edges(merged)[0]) < len(boundary_edges(mesh)[0]):
            mesh = merged
    mesh.apply_scale(scale)
    model = ObjectModel(name or path.stem, mesh, symmetries=symmetries, texture=texture, face_uv=face_uv)
    d = model.diameter
    if d > MAX_PLAUSIBLE_DIAMETER_M:
        warnings.warn(
            f"{path}: diameter {d:.3g} m after scale={scale:g} — the file looks like it is in millimetres; "
            f"pass scale={scale * 0.001:g}",
            UserWarning,
            stacklevel=2,
        )
    elif d < MIN_PLAUSIBLE_DIAMETER_M:
        warnings.warn(
            f"{path}: diameter {d:.3g} m after scale={scale:g} is tiny — is the file in another unit?",
            UserWarning,
            stacklevel=2,
        )
    return model


def save_object(obj: ObjectModel, path) -> Path:
    """``obj`` as a Wavefront OBJ in metres at ``path`` (``.obj``), with its print beside it (``.mtl``
    and ``.png`` of the same stem) where it carries one: :func:`load_object` reads it back with the same
    geometry, symmetries detected again from the shape, and the same print at each surface point. Each
    file is written whole or not at all (temporary file, then rename). Returns ``path``."""
    from PIL import Image

    from ..io import atomic_write_bytes

    path = Path(path)
    if path.suffix.lower() != ".obj":
        raise ValueError(f"path: expected a .obj file name, got {str(path)!r}")
    if obj.texture is None:
        mesh = obj.mesh
    else:
        # one vertex per face corner: a corner's texture coordinates are its face's, not its vertex's
        corners = np.asarray(obj.vertices)[np.asarray(obj.mesh.faces)].reshape(-1, 3)
        mesh = trimesh.Trimesh(corners, np.arange(len(corners)).reshape(-1, 3), process=False)
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.asarray(obj.face_uv).reshape(-1, 2),
                                                    image=Image.fromarray(obj.texture))
    text, files = trimesh.exchange.obj.export_obj(mesh, include_normals=False, include_texture=obj.texture is not None,
                                                  return_texture=True, mtl_name=f"{path.stem}.mtl")
    # trimesh names the print after the material (material_0.png): named after the model, two models
    # printed differently share a folder
    images = [name for name in files if not name.endswith(".mtl")]
    for name in images:
        files[f"{path.stem}{Path(name).suffix}"] = files.pop(name)
    for name in [n for n in files if n.endswith(".mtl")]:
        text_mtl = files[name].decode()
        for old in images:
            text_mtl = text_mtl.replace(old, f"{path.stem}{Path(old).suffix}")
        files[name] = text_mtl.encode()
    for name, data in files.items():  # the print and its material first: the .obj names them
        atomic_write_bytes(path.parent / name, data)
    atomic_write_bytes(path, text.encode())
    return path
