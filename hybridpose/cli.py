"""The ``hybridpose`` command: render, verify, demo."""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

from .geometry import Camera, load_camera

log = logging.getLogger("hybridpose")


def _progress(desc: str):
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit="img", dynamic_ncols=True)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)
        if done >= total:
            bar.close()

    return update


def _counter(desc: str, unit: str = "frame"):
    """Progress bar for a stream of unknown length (video frames)."""
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit=unit, dynamic_ncols=True)

    def update(done: int) -> None:
        bar.update(done - bar.n)

    return update


def _base_camera(args) -> Camera:
    cam = load_camera(args.camera) if getattr(args, "camera", None) else Camera.default()
    return cam.scaled(args.size) if args.size else cam


def _float_pair(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH (two numbers), got {text!r}") from None
    return lo, hi


def _sun_dir(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers x,y,z, got {text!r}")
    return vals


def cmd_render(args) -> int:
    from .datasets import render_random_dataset, render_sequence_dataset
    from .objects import load_object
    from .render import AppearanceSpec, SensorModel, SpaceLighting
    from .render.sequences import SequenceSpec

    obj = load_object(args.object, scale=args.scale)
    camera = _base_camera(args)
    lighting = SpaceLighting(sun_direction_cam=args.sun_dir, sun_intensity=args.sun, exposure=args.exposure,
                             background=args.background)
    sensor = SensorModel(blur_sigma_px=args.blur, noise_std=args.noise, gamma=args.gamma)
    looks = AppearanceSpec(args.appearance, args.backgrounds, photo_share=args.photo_share)
    if args.kind == "random":
        scene = render_random_dataset(args.out, obj, camera, args.count, seed=args.seed,
                                      distance_range_m=(args.near, args.far), lighting=lighting, sensor=sensor,
                                      progress=_progress("render"), sun_cone_deg=args.sun_cone,
                                      sun_scale_range=args.sun_range, in_view=args.in_view, workers=args.workers,
                                      elevation_range_deg=args.elevation, appearance=looks)
    else:
        spec = SequenceSpec(trajectory=args.trajectory, frames=args.frames, fps=args.fps, occlusion=args.occlusion,
                            lighting=args.lighting, seed=args.seed)
        scene = render_sequence_dataset(args.out, obj, camera, spec, lighting=lighting, sensor=sensor,
                                        progress=_progress("render"), workers=args.workers, appearance=looks)
    print(f"wrote {scene} ({camera.width}×{camera.height}, BOP format) and {Path(args.out) / 'labels.csv'}")
    return 0


def verify_dataset(root, out, frames: int = 12, columns: int = 4, object_name: str | None = None) -> dict:
    """Contact sheet of ``frames`` evenly spaced images with the CAD edges projected at the labelled
    pose (green) and the visible-mask outline (magenta); returns alignment statistics (IoU of the
    rendered full mask against the projected mesh silhouette)."""
    from .datasets import find_scenes
    from .datasets.bop import BopScene, dataset_object
    from .io import write_image
    from .viz import contact_sheet, draw_mask_contour, draw_wireframe, silhouette

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
        tile = draw_mask_contour(img, scene.mask(im_id, visible=True))
        tile = draw_wireframe(tile, obj, gt.pose, gt.camera, color=(0, 255, 0))
        tiles.append(tile)
        labels.append(f"#{im_id} z={gt.pose.t[2]:.2f}m vis={gt.visib_fract:.2f}")
    write_image(out, contact_sheet(tiles, columns=columns, labels=labels))
    stats = {"frames": len(ids), "iou_mean": float(np.mean(ious)) if ious else None,
             "iou_min": float(np.min(ious)) if ious else None}
    return stats


def cmd_verify(args) -> int:
    stats = verify_dataset(args.data, args.out, frames=args.frames, object_name=args.object)
    print(f"wrote {args.out}: {stats['frames']} frames; rendered mask vs projected CAD mesh IoU "
          f"mean {stats['iou_mean']:.4f}, min {stats['iou_min']:.4f}")
    return 0


def _mode_line(name: str, st: dict) -> str:
    rec = st["recover_frames"]
    rec_txt = "—" if not rec else ", ".join("never" if n is None else str(n) for n in rec)
    return (f"  {name:8s} {st['rot_median_deg']:7.2f} {st['rot_p90_deg']:7.2f} {st['rot_max_deg']:7.2f} "
            f"{st['trans_mean_pct']:8.2f} {100 * st['coverage']:6.0f}% {st['silent_failures']:7d} "
            f"{st['frames_lost']:5d}   {rec_txt:10s} {st['ms_per_frame']:7.1f}")


def cmd_demo(args) -> int:
    from .bench.modes import hybrid_record, load_sequence, run_cnn, run_tracker, sequence_stats, trusted_errors_deg
    from .datasets import render_sequence_dataset
    from .estimator import HybridEstimator
    from .io import write_image
    from .metrics import rotation_error_deg
    from .objects import load_object
    from .registry import create
    from .render.sequences import SequenceSpec
    from .tracking import draw_estimate, run_hybrid_on_frames
    from .viz import contact_sheet, plot_error_over_time

    from .registry import get

    get("tracker", args.tracker), get("fusion", args.fusion)  # unknown names refused before rendering
    out = Path(args.out)
    obj = load_object("truss")
    camera = Camera.default().scaled(args.size)
    spec = SequenceSpec(trajectory="tumble", frames=args.frames, fps=30.0, occlusion="arm", seed=args.seed)
    scene_dir = render_sequence_dataset(out / "seq_tumble_arm", obj, camera, spec, progress=_progress("demo: render"))
    stats = verify_dataset(out / "seq_tumble_arm", out / "verify.png", frames=12)
    print(f"demo: rendered {spec.frames} frames of a tumbling truss; a robot arm passes in front (partial, then "
          f"full) → {out / 'seq_tumble_arm'}")
    print(f"demo: contact sheet with projected CAD edges → {out / 'verify.png'} "
          f"(mask vs CAD IoU mean {stats['iou_mean']:.4f})")

    seq = load_sequence(scene_dir)
    regressor = create("regressor", "default", object=obj)
    estimator = HybridEstimator(create("tracker", args.tracker, object=obj), regressor,
                                create("fusion", args.fusion))
    keep = set(np.linspace(0, len(seq) - 1, 8).round().astype(int).tolist())
    tiles, labels, hybrid, calls = [], [], [], [0]

    def collect(frame, e, overlay):
        if frame.index in keep:  # labelled after resizing, so the sheet's labels stay legible
            tiles.append(draw_estimate(frame, obj, e, None))
            err = f"{rotation_error_deg(e.pose, seq[len(hybrid)].truth):.1f} deg" if e.pose is not None else "no pose"
            labels.append(f"#{frame.index} {e.status.upper()} {err}")
        hybrid.append(hybrid_record(e, estimator.regressor_calls - calls[0]))
        calls[0] = estimator.regressor_calls

    # the hybrid has no ground truth at all: the CNN initialises it
    res = run_hybrid_on_frames((s.frame for s in seq), estimator, out / "track", on_frame=collect)
    records = {"tracker": run_tracker(seq, create("tracker", args.tracker, object=obj)),
               "cnn": run_cnn(seq, regressor), "hybrid": hybrid}
    write_image(out / "tracking.png", contact_sheet(tiles, columns=4, labels=labels))
    errors = {mode: [np.nan if e is None else e for e in trusted_errors_deg(seq, recs)] for mode, recs in records.items()}
    plot_error_over_time(out / "error_over_time.png", [s.frame.timestamp for s in seq], errors,
                         [s.visible for s in seq], title=f"tumble + arm, seed {args.seed}",
                         statuses=[r.status for r in hybrid])
    print(f"demo: errors on the {sum(s.visible >= 0.5 for s in seq)} frames where the truss is at least half visible "
          "(tracker: from the true first pose; CNN: every frame; hybrid: no ground truth)")
    print("  mode     median°    p90°  worst°  trans.%  frames  silent  lost   recovery   ms/frame")
    for mode, recs in records.items():
        print(_mode_line(mode, sequence_stats(seq, recs)))
    print("  (frames: share with a trusted pose; silent: frames > 5° off not flagged lost; recovery: frames after "
          "a full occlusion until ≤ 2°)")
    print(f"demo: hybrid overlay (green tracking, yellow (re)init, red lost) → {res.video}; "
          f"{out / 'tracking.png'}; error over time → {out / 'error_over_time.png'}")
    return 0


def cmd_track(args) -> int:
    from .geometry import load_camera
    from .objects import load_object
    from .registry import create
    from .tracking import load_pose, read_frames, track_sequence

    from .registry import get

    get("tracker", args.tracker), get("fusion", args.fusion)
    obj = load_object(args.object, scale=args.scale)
    camera = load_camera(args.camera)
    frames = read_frames(args.source, camera, args.fps)
    if args.init_pose is None:
        from .estimator import HybridEstimator
        from .tracking import run_hybrid_on_frames

        est = HybridEstimator.from_names(object=obj, tracker=args.tracker, regressor=args.regressor,
                                         fusion=args.fusion)
        res = run_hybrid_on_frames(frames, est, args.out, max_frames=args.max_frames, progress=_counter("track"))
        print(f"track: {res.frames} frames with the hybrid ({args.tracker} + {args.regressor} + {args.fusion}; "
              f"{res.ms_per_frame:.1f} ms/frame, {res.lost} lost, {res.reinits} re-initialised) → "
              f"{res.video}, {res.out / 'poses.csv'}, {res.out / 'scene_gt.json'}")
        return 0
    pose0 = load_pose(args.init_pose)
    tracker = create("tracker", args.tracker, object=obj)
    res = track_sequence(frames, tracker, pose0, args.out, max_frames=args.max_frames, progress=_counter("track"))
    print(f"track: {res.frames} frames with {args.tracker} ({res.ms_per_frame:.1f} ms/frame, {res.lost} flagged lost) → "
          f"{res.video}, {res.out / 'poses.csv'}, {res.out / 'scene_gt.json'}")
    return 0


def _names(text: str) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(",") if n.strip())


def cmd_fit(args) -> int:
    from .fit import fit
    from .geometry import load_camera

    camera = load_camera(args.camera) if args.camera else None
    fit(args.mesh, args.out, camera=camera, scale=args.scale, budget=args.budget, seed=args.seed,
        backgrounds=args.backgrounds, workers=args.workers,
        init_from=None if args.init_from == "none" else args.init_from, bar=_progress)
    return 0


def cmd_bench(args) -> int:
    from .bench.command import BenchRequest, bench, rewrite_report, write_results_page

    if args.report_only:
        result = rewrite_report(args.out)
        print((Path(args.out) / "report.md").read_text())
        if args.results_md:
            write_results_page(args.results_md, result, result["plots"], block=args.results_block)
        return 0
    try:
        periods = tuple(int(p) for p in _names(args.check_periods))
    except ValueError:
        raise ValueError(f"--check-periods: expected whole numbers of frames, got {args.check_periods!r}") from None
    req = BenchRequest(out=args.out, suite=None if args.data else args.suite, split=args.split, data=args.data,
                       object=args.object, scale=args.scale, modes=_names(args.modes), trackers=_names(args.trackers),
                       fusions=_names(args.fusions), regressor=args.regressor, check_periods=periods,
                       configs=tuple(args.config),
                       workers=args.workers, ray=args.ray, video=args.video, limit=args.limit, cache=args.cache)
    bar: list = []  # made at the first finished sequence, after every input was checked

    def progress(name: str) -> None:
        if not bar:
            bar.append(_counter("bench", unit="sequence"))
            bar.append(0)
        bar[1] += 1
        bar[0](bar[1])

    result = bench(req, progress=progress)
    out = Path(args.out)
    print(f"bench: {len(result['rows'])} rows → {out / 'results.json'}, {out / 'report.md'}, plots in {out}")
    print((out / "report.md").read_text())
    if args.results_md:
        write_results_page(args.results_md, result, result["plots"], block=args.results_block)
        print(f"bench: results page block {args.results_block!r} rewritten → {args.results_md}")
    return 0


def cmd_eval(args) -> int:
    from .regressors.evaluate import evaluate_checkpoint
    from .regressors.checkpoints import checkpoint_or_shipped

    s = evaluate_checkpoint(checkpoint_or_shipped(args.checkpoint), args.data, args.out, limit=args.limit, progress=_progress("eval"),
                            timing_images=args.timing_images,
                            refine_edges=not args.no_refine, passes=args.passes, turns=args.turns,
                            pnp_outliers=args.pnp_outliers,
                            turn_pnp_outliers=None if args.turn_pnp_outliers == "same" else args.turn_pnp_outliers,
                            sun_known=args.sun_known,
                            device=args.device, verifier=None if args.verifier == "none" else args.verifier,
                            mirror_verifier=None if args.mirror_verifier == "none" else args.mirror_verifier,
                            edge_on_expert=None if args.edge_on_expert == "none" else args.edge_on_expert,
                            expert_rule=args.expert_rule, dim_fallback=not args.no_dim_fallback,
                            max_depth_m=None if args.max_depth == "none" else args.max_depth, engine=args.engine,
                            roi=args.roi)
    ms = s["ms_per_image"]
    timed = (f"{ms['1_thread']:.1f} ms/img (1 thread; the bare network {ms['network_1_thread']:.1f} ms a call on "
             f"{s['engine']} on this CPU)" if "1_thread" in ms else f"not timed (engine {s['engine']})")
    print(f"eval {s['model']} on {s['images']} images: rotation mean {s['rot_mean_deg']:.2f}° / median "
          f"{s['rot_median_deg']:.2f}°, translation mean {s['trans_mean_m']:.3f} m, SPEED {s['speed_score']:.3f}, "
          f"ADD-0.1d {s['add_0.1d_recall']:.2f}, {s['failures']} failures, {timed} → {Path(args.out) / 'report.md'}")
    return 0


def cmd_compare(args) -> int:
    from .io import atomic_write_json
    from .regressors.compare import compare_reports, comparison_markdown

    if len(args.reports) % 2:
        raise ValueError("reports: expected pairs, A B [A2 B2 ...] (model A's and model B's report on each test "
                         f"set), got {len(args.reports)} paths")
    c = compare_reports(args.reports[0::2], args.reports[1::2], gross_deg=args.gross_deg)
    text = comparison_markdown(c)
    if args.out:
        atomic_write_json(Path(args.out), c)
    print(text, end="")
    return 0


def cmd_calibrate(args) -> int:
    from .regressors.evaluate import calibrate_checkpoint
    from .regressors.checkpoints import checkpoint_or_shipped

    cal = calibrate_checkpoint(checkpoint_or_shipped(args.checkpoint), args.data, args.out, limit=args.limit, progress=_progress("calibrate"),
                               coverage=args.coverage, by_quality=not args.single_scale)
    fp = cal["full_path"]
    print(f"calibrate: {fp['poses']} poses on {args.data}: {fp['inside_share_before']:.0%} were inside the "
          f"{fp['coverage']:.0%} ellipsoid; covariance ×{fp['factor']:.3f} → {args.out}")
    bands = cal.get("quality_scale")
    if bands:
        print("  then by quality band: " + ", ".join(f"≥ {e:.1f}: ×{f:.2f} ({n} poses)" for e, f, n in
                                                     zip(bands["edges"], bands["factors"], bands["poses"])))
    from .regressors.int8_file import stale_int8

    beside = stale_int8(args.out)  # e.g. --out the checkpoint itself: its 8-bit model was made from the file before
    if beside is not None:
        print(f"calibrate: {beside} was not made from {args.out} (engine='auto' now runs the float network); "
              f"run hybridpose quantize --checkpoint {args.out} --data DIR again")
    return 0


def cmd_quantize(args) -> int:
    from .regressors.quantize import quantize_checkpoint

    rec = quantize_checkpoint(args.checkpoint, args.data, args.out, crops=args.crops, progress=_progress("quantize"))
    print(f"quantize: {rec['checkpoint']} calibrated on {rec['crops']} crops of {args.data} → {rec['path']} "
          f"(use it with engine='onnxruntime-int8')")
    return 0


def cmd_export(args) -> int:
    from .regressors.checkpoints import export_checkpoint

    ck = export_checkpoint(args.checkpoint, args.out)
    print(f"export: {ck['config']['model']} (epoch {ck.get('epoch')}) → {args.out} "
          f"({Path(args.out).stat().st_size / 2**20:.1f} MB, calibration {'yes' if 'calibration' in ck else 'NO'})")
    return 0


def cmd_train(args) -> int:
    from .regressors.train import add_train_arguments, run

    p = argparse.ArgumentParser(prog="hybridpose train", description="train a CNN pose regressor on a rendered "
                                "dataset (checkpoints, --resume)")
    add_train_arguments(p)
    train_args = p.parse_args(args.train_args)
    train_args.verbose, train_args.command = args.verbose, args.command
    return run(train_args)


def cmd_train_verifier(args) -> int:
    from .datasets.bop import dataset_object
    from .regressors.train_verifier import build_pairs, check_estimators, estimator_folders, train_verifier

    if args.epochs < 1:  # before minutes of cutting pairs
        raise ValueError(f"--epochs: expected at least 1, got {args.epochs}")
    obj = dataset_object(args.data[0], args.object)
    # unset: build_pairs' own default (LABEL_MAX_DEG), so the bound is written down in one place
    bound = {} if args.label_max_deg is None else {"label_max_deg": args.label_max_deg}
    folders = estimator_folders(args.estimates_from)
    check_estimators(ck for ck, _ in folders)
    pairs = [build_pairs(args.data, args.out, obj, seed=args.seed, workers=args.workers, estimates_from=ck,
                         mirrors=args.mirrors, folder=folder, **bound) for ck, folder in folders]
    pairs = pairs[0] if len(pairs) == 1 else pairs
    best = train_verifier(pairs, args.out, obj, epochs=args.epochs, batch=args.batch, lr=args.lr, width=args.width,
                          seed=args.seed, resume=args.resume, init_from=args.init_from)
    hist = json.loads((Path(args.out) / "history.json").read_text())
    print(f"train-verifier: {len(hist)} epochs, best validation accuracy {max(h['val_acc'] for h in hist):.4f} "
          f"→ {best}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from . import registry
    from .render.lighting import BACKGROUNDS
    from .render.sequences import LIGHTINGS, OCCLUSIONS

    p = argparse.ArgumentParser(prog="hybridpose", description="6-DoF pose tracking of a known rigid object.")
    p.add_argument("-v", "--verbose", action="store_true")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a random-view dataset or a sequence (BOP format, resumable)")
    r.add_argument("--object", default="truss", help="built-in name or mesh file (.obj/.ply/.stl)")
    r.add_argument("--scale", type=float, default=1.0, help="mesh units → metres (0.001 for mm)")
    r.add_argument("--kind", choices=("random", "sequence"), required=True)
    r.add_argument("--count", type=int, default=1000, help="random: number of images")
    r.add_argument("--near", type=float, default=0.3, help="random: nearest object distance, m")
    r.add_argument("--far", type=float, default=1.2, help="random: farthest object distance, m")
    r.add_argument("--trajectory", default="tumble", choices=registry.available("trajectory"))
    r.add_argument("--occlusion", default="none", choices=OCCLUSIONS)
    r.add_argument("--lighting", default="constant", choices=LIGHTINGS)
    r.add_argument("--frames", type=int, default=300)
    r.add_argument("--fps", type=float, default=30.0)
    r.add_argument("--size", default=None, help="N or WxH; the camera is rescaled, field of view kept")
    r.add_argument("--camera", default=None, help="camera file (.json/.yaml: width, height, K); default 640×480 f=600")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--background", choices=BACKGROUNDS, default="black")
    r.add_argument("--sun-dir", type=_sun_dir, default=(0.6, 0.4, 0.7), help="sunlight direction x,y,z in the camera frame")
    r.add_argument("--sun", type=float, default=1.0, help="sun intensity")
    r.add_argument("--sun-cone", type=float, default=0.0,
                   help="random: per-image sun direction uniform within this cone (degrees, up to 180) around --sun-dir "
                        "(e.g. --sun-dir 0,0,1 --sun-cone 120: light from any side, some back-lit)")
    r.add_argument("--in-view", action="store_true",
                   help="random: keep the whole object in the image (default: only its centre)")
    r.add_argument("--elevation", type=_float_pair, default=None, metavar="LOW,HIGH",
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
    r.add_argument("--sun-range", type=_float_pair, default=(1.0, 1.0),
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


    # the training options live with the trainer, which imports torch: they are parsed in cmd_train so
    # that `hybridpose --help` and every other command start without it
    t = sub.add_parser("train", help="train a CNN pose regressor on a rendered dataset (checkpoints, --resume); "
                                     "hybridpose train --help for its options", add_help=False)
    t.set_defaults(func=cmd_train, train_args=[])

    tv = sub.add_parser("train-verifier", help="train the twin verifier (image vs a drawing of each box twin) "
                                                "that checks the keypoint regressor's end-for-end choice")
    tv.add_argument("--data", nargs="+", required=True, help="rendered datasets (labels.csv, camera.json)")
    tv.add_argument("--out", required=True, help="run folder: pairs/ (cut once, resumable), best.pt, last.pt")
    tv.add_argument("--object", default=None, help="object name or mesh in metres (default: the first dataset's)")
    tv.add_argument("--epochs", type=int, default=4)
    tv.add_argument("--batch", type=int, default=64, help="views per step (each with its 4 candidates)")
    tv.add_argument("--lr", type=float, default=2e-3, help="peak learning rate (warm-up, then cosine)")
    tv.add_argument("--width", type=int, default=32, help="network width (channels of the first full block)")
    tv.add_argument("--seed", type=int, default=0)
    tv.add_argument("--workers", type=int, default=1, help="processes that cut the pairs (the result does not depend on it)")
    tv.add_argument("--resume", action="store_true", help="continue from out/last.pt")
    tv.add_argument("--estimates-from", nargs="+", default=None, metavar="CHECKPOINT",
                    help="candidates from this keypoint regressor's own poses of the views (what the verifier sees "
                         "at inference) instead of noise on the ground truth; several: every view is cut once per "
                         "checkpoint (out/pairs, out/pairs2, …: e.g. the default and its edge-on expert, whose twins "
                         "the pooled rule scores too) and the verifier trains on all of them")
    tv.add_argument("--label-max-deg", type=float, default=None, metavar="DEG",
                    help="with --estimates-from: leave out views whose nearest twin is further off than this "
                         "(degrees; default train_verifier.LABEL_MAX_DEG, 20; wider teaches the views with "
                         "poor keypoints too)")
    tv.add_argument("--init-from", default=None, metavar="CHECKPOINT",
                    help="start from this twin-verifier checkpoint's weights (fine-tuning; same --width)")
    tv.add_argument("--mirrors", action="store_true",
                    help="the edge-on mirror verifier: views estimated near edge-on only, each with eight candidates "
                         "(the four twins and the four twins of the edge-on mirror, verify.edge_on_mirror)")
    tv.set_defaults(func=cmd_train_verifier)

    cal = sub.add_parser("calibrate", help="re-scale a regressor checkpoint's covariance on its whole inference path "
                                           "(held-out rendered views), so the fusion layer gets honest uncertainties")
    cal.add_argument("--checkpoint", required=True,
                     help="checkpoint to re-scale (best.pt, an export, or a shipped one by name: default)")
    cal.add_argument("--data", required=True, help="held-out BOP dataset, another seed than training and test sets")
    cal.add_argument("--out", required=True, help="where to write the re-scaled checkpoint (may be --checkpoint)")
    cal.add_argument("--limit", type=int, default=None, help="use the first N images only")
    cal.add_argument("--coverage", type=float, default=0.9, help="share of the errors inside the ellipsoid of that "
                                                                  "probability (default 0.9)")
    cal.add_argument("--single-scale", action="store_true",
                     help="one covariance factor for all measurements (default: keypoint models also get a factor per "
                          "band of measurement quality, so poor measurements are not over-confident)")
    cal.set_defaults(func=cmd_calibrate)

    qz = sub.add_parser("quantize", help="8-bit model of a keypoint checkpoint for ONNX Runtime (engine onnxruntime-int8), "
                                         "calibrated on the crops the float network sees on rendered views")
    qz.add_argument("--checkpoint", required=True, help="keypoint checkpoint (best.pt or an export)")
    qz.add_argument("--data", required=True, help="BOP dataset to calibrate on (another seed than the test sets)")
    qz.add_argument("--out", default=None, help="the .onnx file (default: beside the checkpoint, NAME.int8.onnx, "
                                                "where engine='onnxruntime-int8' looks for it)")
    qz.add_argument("--crops", type=int, default=300, help="calibration crops (default 300)")
    qz.set_defaults(func=cmd_quantize)

    e = sub.add_parser("eval", help="evaluate a trained regressor: paper table, SPEED, ADD-0.1d, plots, Grad-CAM, ms/img")
    e.add_argument("--checkpoint", required=True,
                   help="best.pt of a training run, an export, or a shipped checkpoint by name (default)")
    e.add_argument("--data", required=True, help="held-out BOP dataset (e.g. hybridpose render --kind random --seed 100)")
    e.add_argument("--out", required=True, help="report folder (report.json/.md, error_vs_distance.png, gradcam.png)")
    e.add_argument("--limit", type=int, default=None, help="evaluate the first N images only")
    e.add_argument("--timing-images", type=int, default=100,
                   help="time the whole predict path on the first N images at 1 and 2 threads (default 100; 0: "
                        "no timing, e.g. for accuracy runs of many sets side by side)")
    e.add_argument("--no-refine", action="store_true", help="keypoint models: CNN + PnP + twin check only, no edge refinement")
    e.add_argument("--passes", choices=("1", "2", "auto"), default="auto",
                   help="keypoint models: network passes (2 = again on the crop re-centred on the first pose; "
                        "auto, the default: the second only where the first one's twin head is unsure)")
    e.add_argument("--turns", choices=("auto", "always", "off"), default="auto",
                   help="keypoint models: also try the first crop turned in-plane by ±20°/±40° (auto, the default: "
                        "only where the first pass's PnP keeps < 80 %% of the keypoints)")
    e.add_argument("--pnp-outliers", choices=("drop-worst", "ransac"), default="drop-worst",
                   help="keypoint models: PnP leaves the worst keypoint out until the rest agree (drop-worst, the "
                        "default; RANSAC when more than half would go) or runs RANSAC as soon as one disagrees")
    e.add_argument("--turn-pnp-outliers", choices=("drop-worst", "ransac", "drop-worst-only", "same"),
                   default="drop-worst-only",
                   help="keypoint models: the same for the passes on the turned crops (drop-worst-only, the default: "
                        "no RANSAC there, a turned pass most of whose keypoints disagree gives no pose; "
                        "same: as --pnp-outliers)")
    e.add_argument("--roi", choices=("none", "truth"), default="none",
                   help="none (default): no prior, the object found by detection (the parallel VGG-19 crops around its "
                        "own translation where nothing is detected); truth: each view's true object box from scene_gt_info.json, as a tracker on the object "
                        "passes it in the hybrid (the paper's 'bounded image')")
    e.add_argument("--device", default="cpu", help="where the network runs: cpu (default) or cuda[:N] (the VGG models)")
    e.add_argument("--engine", choices=("auto", "onnxruntime", "torch", "onnxruntime-int8"), default="auto",
                   help="keypoint models: what runs the network: auto (default: ONNX Runtime on the CPU, on the "
                        "checkpoint's 8-bit model where hybridpose quantize made one from it, as for the shipped "
                        "default, else in float32; torch where it cannot run), onnxruntime (float32; an error where "
                        "it cannot run), torch, or onnxruntime-int8 (the 8-bit model; an error without one)")
    e.add_argument("--verifier", default="auto", help="keypoint models: twin-verifier checkpoint (train-verifier), "
                                                      "'auto' (the shipped one, if any) or 'none'")
    e.add_argument("--mirror-verifier", default="auto",
                   help="keypoint models: edge-on mirror verifier (train-verifier --mirrors), 'auto' (the shipped one, "
                        "if any) or 'none'")
    e.add_argument("--edge-on-expert", default="auto",
                   help="keypoint models: a second keypoint checkpoint trained on near edge-on views that re-estimates "
                        "the pose where the first estimate is near edge-on, 'auto' (the shipped one, if any) or 'none'")
    e.add_argument("--expert-rule", choices=("quality", "pooled", "pooled-unsure", "replace"),
                   default="pooled-unsure",
                   help="keypoint models with an edge-on expert: the best-scored box twin of both estimates where a "
                        "twin head is unsure, else the measurement of higher quality (pooled-unsure, the default), "
                        "always the measurement of higher quality (quality), always the best-scored twin (pooled), "
                        "or the expert's (replace)")
    e.add_argument("--no-dim-fallback", action="store_true",
                   help="keypoint models: report a view lost where nothing bright is found, instead of looking for a "
                        "faintly lit object")
    e.add_argument("--max-depth", default="none", metavar="M",
                   help="keypoint models: refuse estimates deeper than M metres along the optical axis, 'auto' "
                        "(3x the far end of the training depths the checkpoint records) or 'none' (default)")
    e.add_argument("--sun-known", action="store_true",
                   help="keypoint models: give the regressor each image's sun as the dataset records it (what a "
                        "caller with a sun sensor can do: the crop is turned so the light crosses it as in training)")
    e.set_defaults(func=cmd_eval)

    c = sub.add_parser("compare", help="paired comparison of two eval reports on the same images "
                                        "(McNemar on gross errors, bootstrap on mean/median)")
    c.add_argument("reports", nargs="+", metavar="A B",
                   help="report.json (or its folder) of model A, then of model B on the same images; more "
                        "pairs (A2 B2 …, other test sets) are pooled")
    c.add_argument("--gross-deg", type=float, default=30.0, help="rotation error that counts as gross, degrees")
    c.add_argument("--out", default=None, help="also write the comparison as JSON here")
    c.set_defaults(func=cmd_compare)

    x = sub.add_parser("export", help="inference-only copy of a training checkpoint (what the package ships)")
    x.add_argument("--checkpoint", required=True, help="best.pt of a training run")
    x.add_argument("--out", required=True)
    x.set_defaults(func=cmd_export)

    k = sub.add_parser("track", help="track your object through a video or image folder (the hybrid: the CNN "
                                     "initialises; --init-pose: the tracker alone from that pose)")
    k.add_argument("source", help="video file (.mp4/.avi/...) or folder of images")
    k.add_argument("--object", required=True, help="built-in name or mesh file (.obj/.ply/.stl)")
    k.add_argument("--scale", type=float, default=1.0, help="mesh units → metres (0.001 for mm)")
    k.add_argument("--camera", required=True, help="camera file (.json/.yaml: width, height, K or fx/fy/cx/cy, dist)")
    k.add_argument("--init-pose", default=None,
                   help="tracker alone from this pose, no CNN, no fusion. JSON: quat_wxyz + t_m (metres), R + t_m, "
                        "or BOP cam_R_m2c + cam_t_m2c (mm)")
    k.add_argument("--regressor", default="default", help="registered regressor or a checkpoint file (best.pt)")
    k.add_argument("--fusion", default="ukf", help="fusion backend of the hybrid (ukf, isam2, none)")
    k.add_argument("--tracker", default="edges", help="registered tracker (edges, klt-pnp, rapid, rapid-gos, rapid-ols)")
    k.add_argument("--fps", type=float, default=None, help="frame rate for image folders (default 30)")
    k.add_argument("--max-frames", type=int, default=None)
    k.add_argument("--out", required=True, help="folder for the overlay video, poses.csv, scene_gt.json")
    k.set_defaults(func=cmd_track)

    b = sub.add_parser("bench", help="tracker-only vs CNN-only vs hybrid on a seeded sequence suite or your BOP "
                                     "sequences: results.json, report.md, plots (resumable)")
    b.add_argument("--suite", default="standard", help="standard (7 kinds × 20 seeds), occlusion, smoke")
    b.add_argument("--split", default="report", choices=["report", "tuning"],
                   help="report: seeds no tuning used (the published figures); tuning: the seeds defaults were chosen on")
    b.add_argument("--data", default=None, help="your BOP sequences (folder) instead of a suite; needs --object")
    b.add_argument("--object", default="truss", help="built-in name or mesh file")
    b.add_argument("--scale", type=float, default=1.0, help="mesh units → metres (0.001 for mm)")
    b.add_argument("--modes", default="tracker,cnn,hybrid")
    b.add_argument("--trackers", default="edges", help="comma list: tracker-only and hybrid runs per tracker")
    b.add_argument("--fusions", default="ukf", help="comma list: a hybrid run per tracker × fusion")
    b.add_argument("--regressor", default="default", help="registered name or checkpoint file")
    b.add_argument("--check-periods", default="", help="comma list of CNN check periods to ablate (frames)")
    b.add_argument("--config", action="append", default=[],
                   help="one more hybrid run with these HybridConfig fields, e.g. probation_frames=2,check_period=5 "
                        "(repeatable)")
    b.add_argument("--workers", type=int, default=1, help="parallel processes (one sequence each)")
    b.add_argument("--ray", default=None, help="run on Ray: an address, 'auto' or 'local' (pip install 'hybridpose[ray]')")
    b.add_argument("--video", default=None, help="also write the hybrid's overlay video of this sequence")
    b.add_argument("--limit", type=int, default=None, help="the suite's first N sequences only")
    b.add_argument("--cache", default="runs/bench_cache", help="rendered suite sequences (reused)")
    b.add_argument("--out", required=True)
    b.add_argument("--results-md", default=None, help="rewrite the bench block of this results page (RESULTS.md)")
    b.add_argument("--results-block", default="bench",
                   help="which <!-- NAME:begin --> … <!-- NAME:end --> block of --results-md to rewrite")
    b.add_argument("--report-only", action="store_true",
                   help="rewrite report.md and the plots (and --results-md) from OUT/results.json; run nothing")
    b.set_defaults(func=cmd_bench)

    f = sub.add_parser("fit", help="a CNN pose regressor for your own CAD model within a time budget: renders randomised "
                                   "views, trains, calibrates and evaluates on this CPU (resumable)")
    f.add_argument("mesh", help="the part's mesh file (.obj/.ply/.stl) or a built-in object name")
    f.add_argument("--scale", type=float, default=1.0, help="mesh units → metres (0.001 for mm)")
    f.add_argument("--camera", default=None, help="camera file (.json/.yaml); default 640×480, f = 600 px")
    f.add_argument("--out", required=True, help="the fit's folder (an interrupted fit resumes there)")
    f.add_argument("--budget", default="60m", help="time for the whole fit: 60m, 1h30m, 90s (default 60m)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--backgrounds", default=None, metavar="DIR", help="photos: half the training backgrounds are crops of them")
    f.add_argument("--workers", type=int, default=1, help="render processes")
    f.add_argument("--init-from", default="default",
                   help="checkpoint to start from: 'default' (the shipped network's weights), a path, or 'none'")
    f.set_defaults(func=cmd_fit)

    d = sub.add_parser("demo", help="render an arm-occlusion sequence, run tracker-only, CNN-only and the hybrid "
                                    "(no ground truth) on it, print their errors, write the overlay video and plots")
    d.add_argument("--out", default="hybridpose_demo")
    d.add_argument("--frames", type=int, default=60)
    d.add_argument("--size", default="640x480")
    d.add_argument("--tracker", default="edges", help="registered tracker (edges, klt-pnp, rapid, rapid-gos, rapid-ols)")
    d.add_argument("--fusion", default="ukf", help="fusion backend of the hybrid (ukf, isam2, none)")
    d.add_argument("--seed", type=int, default=1)
    d.set_defaults(func=cmd_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if args.command == "train":  # its options are parsed by cmd_train (see build_parser)
        args.train_args = list(args.train_args or []) + extra
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, TypeError) as exc:
        print(f"hybridpose {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
