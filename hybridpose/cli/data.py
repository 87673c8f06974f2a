"""``hybridpose render`` and ``verify``: rendered datasets and sequences (BOP format), and a contact
sheet that shows the labels line up with the images."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .common import base_camera, float_pair, progress, sun_dir


def cmd_render(args) -> int:
    from ..datasets import render_random_dataset, render_sequence_dataset
    from ..objects import load_object
    from ..render import AppearanceSpec, SensorModel, SpaceLighting
    from ..render.sequences import SequenceSpec

    obj = load_object(args.object, scale=args.scale)
    camera = base_camera(args)
    if camera.dist:  # the renderer is a pinhole; what is trained on these views undistorts its frames
        print("render: rendering through the camera's pinhole model (same K, no lens distortion)")
        camera = camera.pinhole()
    lighting = SpaceLighting(sun_direction_cam=args.sun_dir, sun_intensity=args.sun, exposure=args.exposure,
                             background=args.background)
    sensor = SensorModel(blur_sigma_px=args.blur, noise_std=args.noise, gamma=args.gamma)
    looks = AppearanceSpec(args.appearance, args.backgrounds, photo_share=args.photo_share,
                           texture_share=args.texture_share)
    if args.kind == "random":
        scene = render_random_dataset(args.out, obj, camera, args.count, seed=args.seed,
                                      distance_range_m=(args.near, args.far), lighting=lighting, sensor=sensor,
                                      progress=progress("render"), sun_cone_deg=args.sun_cone,
                                      sun_scale_range=args.sun_range, in_view=args.in_view, workers=args.workers,
                                      elevation_range_deg=args.elevation, appearance=looks,
                                      occluded_share=args.occluded_share)
    else:
        spec = SequenceSpec(trajectory=args.trajectory, frames=args.frames, fps=args.fps, occlusion=args.occlusion,
                            lighting=args.lighting, seed=args.seed)
        scene = render_sequence_dataset(args.out, obj, camera, spec, lighting=lighting, sensor=sensor,
                                        progress=progress("render"), workers=args.workers, appearance=looks)
    print(f"wrote {scene} ({camera.width}×{camera.height}, BOP format) and {Path(args.out) / 'labels.csv'}")
    return 0


SHEET_TILE_PX = 320  # width of a frame on the verification sheet


def verify_dataset(root, out, frames: int = 12, columns: int = 4, object_name: str | None = None) -> dict:
    """Contact sheet of ``frames`` evenly spaced images with the CAD edges projected at the labelled
    pose (green) and the visible-mask outline (magenta); returns alignment statistics (IoU of the
    rendered full mask against the projected mesh silhouette)."""
    from ..datasets import find_scenes
    from ..datasets.bop import BopScene, dataset_object
    from ..io import write_image
    from ..viz import contact_sheet, draw_mask_contour, draw_wireframe, silhouette

    root = Path(root)
    scene = BopScene(find_scenes(root)[0])
    if not scene.image_ids:
        raise ValueError(f"{root}: the dataset holds no images")
    obj = dataset_object(root, object_name)
    ids = [scene.image_ids[int(round(k))] for k in np.linspace(0, len(scene.image_ids) - 1, min(frames, len(scene)))]
    tiles, labels, ious = [], [], []
    for im_id in ids:
        gt = scene.image(im_id)
        img = scene.rgb(im_id)
        mask_full = scene.mask(im_id, visible=False)
        sil = silhouette(obj, gt.pose, gt.camera)
        union = (sil | mask_full).sum()
        if union:
            ious.append(float((sil & mask_full).sum() / union))
        # the outline over the edges, thick enough to survive the sheet's downscaling (half size at 640 px)
        tile = draw_wireframe(img, obj, gt.pose, gt.camera, color=(0, 255, 0))
        tile = draw_mask_contour(tile, scene.mask(im_id, visible=True),
                                 thickness=max(1, int(round(2 * img.shape[1] / SHEET_TILE_PX))))
        tiles.append(tile)
        labels.append(f"#{im_id} z={gt.pose.t[2]:.2f}m vis={gt.visib_fract:.2f}")
    write_image(out, contact_sheet(tiles, columns=columns, labels=labels, tile_width=SHEET_TILE_PX))
    stats = {"frames": len(ids), "iou_mean": float(np.mean(ious)) if ious else None,
             "iou_min": float(np.min(ious)) if ious else None}
    return stats


def cmd_verify(args) -> int:
    stats = verify_dataset(args.data, args.out, frames=args.frames, object_name=args.object)
    print(f"wrote {args.out}: {stats['frames']} frames; rendered mask vs projected CAD mesh IoU "
          f"mean {stats['iou_mean']:.4f}, min {stats['iou_min']:.4f}")
    return 0


def add_commands(sub) -> None:
    """Add this module's subcommands to the ``hybridpose`` parser's ``sub``."""
    from .. import registry
    from ..render.lighting import BACKGROUNDS
    from ..render.sequences import LIGHTINGS, OCCLUSIONS

    r = sub.add_parser("render", help="render a random-view dataset or a sequence (BOP format, resumable)")
    r.add_argument("--object", default="truss", help="built-in name or mesh file (.obj/.ply/.stl)")
    r.add_argument("--scale", type=float, default=1.0, help="mesh units → metres (0.001 for mm)")
    r.add_argument("--kind", choices=("random", "sequence"), required=True)
    r.add_argument("--count", type=int, default=1000, help="random: number of images")
    r.add_argument("--near", type=float, default=0.3, help="random: nearest object distance, m")
    r.add_argument("--far", type=float, default=1.2, help="random: farthest object distance, m")
    r.add_argument("--trajectory", default="tumble", choices=registry.available("trajectory"))
    r.add_argument("--occlusion", default="none", choices=OCCLUSIONS, help="sequence: the arm passing in front")
    r.add_argument("--occluded-share", type=float, default=0.0, metavar="SHARE",
                   help="random: share of the views with the arm partly in front of the object (seeded per view)")
    r.add_argument("--lighting", default="constant", choices=LIGHTINGS)
    r.add_argument("--frames", type=int, default=300)
    r.add_argument("--fps", type=float, default=30.0)
    r.add_argument("--size", default=None, help="N or WxH; the camera is rescaled, field of view kept")
    r.add_argument("--camera", default=None,
                   help="camera file (ours: .json/.yaml with width, height, K; ROS camera_info; OpenCV FileStorage; "
                        "ViSP XML, its size from --size where it gives none); default 640×480 f=600")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--background", choices=BACKGROUNDS, default="black")
    r.add_argument("--sun-dir", type=sun_dir, default=(0.6, 0.4, 0.7), help="sunlight direction x,y,z in the camera frame")
    r.add_argument("--sun", type=float, default=1.0, help="sun intensity")
    r.add_argument("--sun-cone", type=float, default=0.0,
                   help="random: per-image sun direction uniform within this cone (degrees, up to 180) around --sun-dir "
                        "(e.g. --sun-dir 0,0,1 --sun-cone 120: light from any side, some back-lit)")
    r.add_argument("--in-view", action="store_true",
                   help="random: keep the whole object in the image (default: only its centre)")
    r.add_argument("--elevation", type=float_pair, default=None, metavar="LOW,HIGH",
                   help="random: only views LOW..HIGH degrees from edge-on (0 edge-on, 90 face-on), "
                        "e.g. 0,20 for more of the hard views of a flat object")
    r.add_argument("--appearance", choices=("space", "random"), default="space",
                   help="'space' (black or Earth background, no ambient light) or 'random': a cluttered or photo "
                        "background, ambient and extra lights, a random part colour — per image for --kind random, "
                        "one look for a whole sequence (a part outside space)")
    r.add_argument("--backgrounds", default=None, metavar="DIR",
                   help="with --appearance random: a folder of photos to cut backgrounds from")
    r.add_argument("--photo-share", type=float, default=0.5,
                   help="with --backgrounds: the share of backgrounds cut from the photos (the rest procedural clutter)")
    r.add_argument("--texture-share", type=float, default=0.0, metavar="SHARE",
                   help="random appearance: share of the images with a random print on the part (photo crops "
                        "or procedural clutter, seeded per image)")
    r.add_argument("--sun-range", type=float_pair, default=(1.0, 1.0),
                   help="random: per-image sun intensity factor drawn from LOW,HIGH")
    r.add_argument("--exposure", type=float, default=1.0)
    r.add_argument("--noise", type=float, default=0.0, help="Gaussian read noise, fraction of full scale")
    r.add_argument("--blur", type=float, default=0.0, help="Gaussian blur sigma, px")
    r.add_argument("--gamma", type=float, default=1.0)
    r.add_argument("--workers", type=int, default=1,
                   help="render processes (each with its own GL context); same images for any number")
    r.add_argument("--out", required=True)
    r.set_defaults(func=cmd_render)

    v = sub.add_parser("verify", help="contact sheet of frames with projected CAD edges + alignment IoU")
    v.add_argument("data", help="dataset root written by `hybridpose render`")
    v.add_argument("--out", default="verify.png")
    v.add_argument("--frames", type=int, default=12)
    v.add_argument("--object", default=None, help="object name or mesh in metres (default: the dataset's models/obj_000001.ply)")
    v.set_defaults(func=cmd_verify)
