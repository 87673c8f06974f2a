"""Hand-held scenes (:mod:`hybridpose.render.handheld`) written as BOP sequences, for ``hybridpose
bench --suite realistic`` and for users' own evaluations: the same layout as the space sequences
(``rgb/``, masks, ``scene_gt.json``, ``scene_gt_info.json`` with ``visib_fract``, ``scene_meta.json``
with each frame's timestamp and image motion), no depth (zeros); and the part as drawn,
``models/part.obj`` in metres, with its print (``part.mtl``, ``part.png``) where it is printed — what
a user's textured mesh of a printed part gives the tracker (:func:`part_model`)."""
from __future__ import annotations

import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..geometry import Camera
from ..io import atomic_write_json
from ..objects import ObjectModel, load_object, save_object
from .bop import BopScene, BopSceneWriter, write_camera_json, write_models
from .generate import claim_folder

PART_FILE = Path("models") / "part.obj"  # the part as drawn, in the dataset's folder

# scikit-image's sample photos of scenes (rooms, people, street, textures), cut into backgrounds and prints
SAMPLE_PHOTOS = ("astronaut.png", "coffee.png", "chelsea.png", "motorcycle_left.png", "motorcycle_right.png",
                 "rocket.jpg", "brick.png", "gravel.png", "grass.png", "hubble_deep_field.jpg", "coins.png", "camera.png")


def sample_photos(folder) -> Path | None:
    """scikit-image's scene photos (:data:`SAMPLE_PHOTOS`) copied to ``folder``, or None when
    scikit-image is not installed (``pip install hybridpose[bench]``)."""
    try:
        import skimage
    except ImportError:
        return None
    source, folder = Path(skimage.__file__).parent / "data", Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name in SAMPLE_PHOTOS:
        if (source / name).is_file() and not (folder / name).is_file():
            shutil.copy(source / name, folder / name)
    return folder if any(folder.iterdir()) else None


def render_handheld_dataset(out, obj: ObjectModel, camera: Camera, spec, photos=None) -> Path:
    """Render the hand-held sequence ``spec`` (:class:`~hybridpose.render.handheld.HandheldSpec`) of
    ``obj`` into ``out`` (split ``test``, scene 0); returns the scene folder.

    ``photos``: a folder of photos the background and the print are cut from (None: procedural
    clutter). A folder that already holds this sequence is returned as it is; one that holds another
    is refused (ValueError naming ``out``). The sequence is drawn whole (seconds), so an interrupted
    render starts it again."""
    from ..render.appearance import PhotoBackgrounds
    from ..render.handheld import handheld_scene

    out = Path(out)
    pictures = PhotoBackgrounds(photos) if photos is not None else None
    claim_folder(out, {"kind": "handheld", "object": obj.name, "camera": camera.to_dict(), "spec": asdict(spec),
                       "photos": None if pictures is None else [p.name for p in pictures.files]})
    scene_dir = out / "test" / "000000"
    if ((scene_dir / "scene_meta.json").is_file() and len(BopScene(scene_dir).image_ids) == spec.frames
            and (out / PART_FILE).is_file()):
        return scene_dir
    write_models(out, obj)
    write_camera_json(out, camera)
    writer = BopSceneWriter(scene_dir, camera, load=False)
    scene = handheld_scene(spec, obj, camera, pictures)
    frames = scene.frames
    for f in frames:
        writer.write(f.index, f.image, np.zeros(f.image.shape[:2]), f.mask, f.mask_visib, f.pose, obj.vertices)
    writer.flush()
    save_object(scene.part, out / PART_FILE)
    # last: its presence marks the sequence whole
    atomic_write_json(scene_dir / "scene_meta.json", {"fps": spec.fps, "frames": {
        str(f.index): {"timestamp_s": f.timestamp, "motion_px": round(f.motion_px, 3)} for f in frames}})
    return scene_dir


def part_model(scene_dir) -> ObjectModel:
    """The part a hand-held scene (``scene_dir``: its ``test/000000`` folder, as
    :func:`render_handheld_dataset` returns it) was drawn with: its mesh in metres, and its print where
    it is printed. FileNotFoundError naming the file where the dataset predates it."""
    path = Path(scene_dir).parent.parent / PART_FILE
    if not path.is_file():
        raise FileNotFoundError(f"scene_dir: {path} not found; render the scene again (render_handheld_dataset)")
    return load_object(path)
