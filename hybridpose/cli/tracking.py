"""The estimator's commands: ``track`` (a video, with or without an initial pose), ``bench`` (the
sequence benchmark), ``fit`` (a CNN for your own object) and ``demo``."""
from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..fit_plan import FAR_FILL, NEAR_FILL
from ..geometry import Camera
from ..hybrid_config import DEFAULT_FUSION
from ..registry import backend_options, names
from .common import close_bars, counter, float_pair, progress
from .data import verify_dataset


def cmd_track(args) -> int:
    from ..geometry import load_camera
    from ..objects import load_object
    from ..registry import create, get
    from ..tracking import chosen_tracker, first_frame, load_pose, read_frames, track_sequence
    from ..hybrid_config import HybridConfig, changes_text
    from ..regressors.options import KeypointOptions

    first = first_frame(args.source)
    args.tracker, args.tracker_chosen = chosen_tracker(args.tracker, first)
    if args.tracker_chosen:
        print(f"track: tracker {args.tracker} ({args.tracker_chosen}; --tracker NAME chooses)")
    tracker_kw = backend_options(args.tracker_option, get("tracker", args.tracker), "--tracker-option")
    regressor_kw = backend_options(args.regressor_option, KeypointOptions, "--regressor-option")
    if regressor_kw and args.init_pose is not None:
        raise ValueError("--regressor-option: the tracker alone runs from --init-pose; no CNN to set")
    hybrid_kw = backend_options(args.hybrid_option, HybridConfig, "--hybrid-option")
    if hybrid_kw and args.init_pose is not None:
        raise ValueError("--hybrid-option: the tracker alone runs from --init-pose; no hybrid policy to set")
    HybridConfig(**hybrid_kw)  # the values checked before the video is read
    get("fusion", args.fusion)
    obj = load_object(args.object, scale=args.scale)
    # a camera file without an image size (a ViSP tracker configuration) calibrates these frames
    camera = load_camera(args.camera, image_size=(first.shape[1], first.shape[0]))
    frames = read_frames(args.source, camera, args.fps)
    if args.sun_dir is not None:
        from ..tracking import with_sun

        frames = with_sun(frames, args.sun_dir)
    _warm(args.tracker, args.fusion if args.init_pose is None else None)
    if args.init_pose is None:
        from ..estimator import HybridEstimator
        from ..tracking import run_hybrid_on_frames

        est = HybridEstimator.from_names(object=obj, tracker=args.tracker, regressor=args.regressor,
                                         fusion=args.fusion, tracker_kw=tracker_kw, regressor_kw=regressor_kw,
                                         config=hybrid_kw,  # the regressor's recommended policy, these fields changed
                                         threads=args.threads)
        policy = changes_text(est.config)
        res = run_hybrid_on_frames(frames, est, args.out, max_frames=args.max_frames, progress=counter("track"),
                                   draw_sites=args.draw_sites)
        close_bars()
        write_run_record(res, args, obj, camera, policy={"fields": asdict(est.config), "changed": policy})
        print(f"track: {res.frames} frames with the hybrid ({args.tracker} + {args.regressor} + {args.fusion}"
              f"{'; policy ' + policy if policy else ''}; {_cost(res)}, {res.lost} lost, {res.reinits} re-initialised) → "
              f"{res.video}, {res.out / 'poses.csv'}, {res.out / 'scene_gt.json'}, {res.out / 'run.json'}")
        return _finished(res)
    from ..threads import set_threads

    pose0 = load_pose(args.init_pose)
    set_threads(args.threads)
    tracker = create("tracker", args.tracker, object=obj, **tracker_kw)
    res = track_sequence(frames, tracker, pose0, args.out, max_frames=args.max_frames, progress=counter("track"),
                         draw_sites=args.draw_sites)
    close_bars()
    write_run_record(res, args, obj, camera)
    print(f"track: {res.frames} frames with {args.tracker} ({_cost(res)}, {res.lost} flagged lost) → "
          f"{res.video}, {res.out / 'poses.csv'}, {res.out / 'scene_gt.json'}, {res.out / 'run.json'}")
    return _finished(res)


def _warm(tracker: str, fusion: str | None) -> None:
    """Compile (or load) the kernels before the first frame (:func:`hybridpose.warm_up`), saying so
    where it took long: the first run after an install."""
    from ..warmup import COMPILE_NOTICE_S, warm_up

    seconds = warm_up(trackers=(tracker,), fusions=(fusion,) if fusion else ())
    if seconds > COMPILE_NOTICE_S:
        print(f"compiled the tracking kernels in {seconds:.0f} s (once after an install: they are cached)")


def _cost(res) -> str:
    """A run's cost, its first frame apart (loading, compiling on a cold cache) from the rest."""
    if res.frames < 2:
        return f"{res.first_frame_ms:.1f} ms for its one frame"
    return (f"{res.ms_per_frame:.1f} ms/frame after a first frame of {res.first_frame_ms:.0f} ms; "
            f"{res.wall_ms_per_frame:.0f} ms/frame with reading the source and writing the overlay")


def _finished(res) -> int:
    """The exit status of a track run: 0, or 130 (as a shell reports Ctrl-C) where the user stopped it."""
    if res.note:
        print(f"track: {res.note}")
    if res.interrupted:
        print(f"track: stopped by the user after {res.frames} frames; the outputs hold those frames")
        return 130
    return 0


def write_run_record(res, args, obj, camera, policy: dict | None = None) -> None:
    """``OUT/run.json``: what a run of ``track`` was asked (its options), with what (object, camera,
    the hybrid's policy), what it gave (frames, lost, re-initialised, ms a frame) and on what (commit,
    package versions, CPU) — to rerun it and compare."""
    from ..io import atomic_write_json
    from ..machine import describe_cpu, git_commit, package_versions

    options = {k: v for k, v in vars(args).items() if k != "func"}
    atomic_write_json(res.out / "run.json", {
        "options": options, "mode": "tracker" if args.init_pose is not None else "hybrid",
        "object": {"name": obj.name, "diameter_m": obj.diameter, "symmetric": obj.symmetric},
        "camera": camera.to_dict(), **({"policy": policy} if policy is not None else {}),
        "frames": res.frames, "lost": res.lost, "reinits": res.reinits, "ms_per_frame": res.ms_per_frame,
        "first_frame_ms": res.first_frame_ms, "wall_ms_per_frame": res.wall_ms_per_frame, "interrupted": res.interrupted,
        "commit": git_commit(), "versions": package_versions(), "cpu": describe_cpu()})


def cmd_bench(args) -> int:
    from ..bench.command import BenchRequest, bench, rewrite_report, write_results_page
    from ..bench.suite import parse_seeds

    if args.report_only:
        result = rewrite_report(args.out)
        print((Path(args.out) / "report.md").read_text())
        if args.results_md:
            write_results_page(args.results_md, result, result["plots"], block=args.results_block)
        return 0
    try:
        periods = tuple(int(p) for p in names(args.check_periods))
    except ValueError:
        raise ValueError(f"--check-periods: expected whole numbers of frames, got {args.check_periods!r}") from None
    req = BenchRequest(out=args.out, suite=None if args.data else args.suite, split=args.split, data=args.data,
                       object=args.object, scale=args.scale, modes=names(args.modes), trackers=names(args.trackers),
                       fusions=names(args.fusions), regressor=args.regressor, check_periods=periods,
                       configs=tuple(args.config), tracker_options=tuple(args.tracker_option), sun=names(args.sun),
                       workers=args.workers, ray=args.ray, video=args.video, limit=args.limit, cache=args.cache,
                       seeds=parse_seeds(args.seeds) if args.seeds else None,
                       sequences=tuple(t.strip() for t in (args.sequences or "").split(",") if t.strip()))
    bar: list = []  # made at the first finished sequence, after every input was checked

    def progress(name: str) -> None:
        if not bar:
            bar.append(counter("bench", unit="sequence"))
            bar.append(0)
        bar[1] += 1
        bar[0](bar[1])

    result = bench(req, progress=progress)
    close_bars()
    out = Path(args.out)
    print(f"bench: {len(result['rows'])} rows → {out / 'results.json'}, {out / 'report.md'}, plots in {out}")
    print((out / "report.md").read_text())
    if args.results_md:
        write_results_page(args.results_md, result, result["plots"], block=args.results_block)
        print(f"bench: results page block {args.results_block!r} rewritten → {args.results_md}")
    return 0


def cmd_fit(args) -> int:
    from ..fit import fit, parse_budget
    from ..geometry import NoImageSize, load_camera
    from ..objects import load_object
    from ..registry import get

    try:
        camera = load_camera(args.camera) if args.camera else None
    except NoImageSize as exc:  # a ViSP tracker configuration: fit renders views, so it needs their size
        raise ValueError(f"--camera: {exc}: fit renders views of that size; write a camera file with width and "
                         "height, e.g. JSON {\"width\": 640, \"height\": 480, \"fx\": px, \"fy\": py, "
                         "\"cx\": u0, \"cy\": v0}") from None
    for flag, path in (("--video", args.video), ("--refine-on", args.refine_on), ("--init-pose", args.init_pose)):
        if path is not None and not Path(path).exists():
            raise ValueError(f"{flag}: {path}: no such file or folder")
    if args.init_pose is not None and args.refine_on is None:
        raise ValueError("--init-pose: the first frame's pose of the --refine-on video; give --refine-on too")
    get("tracker", args.video_tracker)  # an unknown name refused before the fit's hour
    fit(args.mesh, args.out, camera=camera, scale=args.scale, budget=args.budget, seed=args.seed,
        backgrounds=None if args.backgrounds == "none" else args.backgrounds, workers=args.workers,
        init_from=None if args.init_from == "none" else args.init_from, bar=progress,
        occluded_share=args.occluded_share, textured_share=args.textured_share, look=args.look,
        distance_range_m=args.distances)
    if args.video is not None:
        from ..footage_check import check_on_footage
        from ..io import atomic_write_text

        obj = load_object(args.mesh, scale=args.scale)
        check = check_on_footage(args.video, obj, camera or Camera.default(), str(Path(args.out) / "best.pt"),
                                 tracker=args.video_tracker)
        report = Path(args.out) / "report.md"
        atomic_write_text(report, report.read_text().rstrip("\n") + "\n\n## On your footage\n\n" + check.text() + "\n")
        print(f"fit: {check.text()}")
    if args.refine_on is not None:
        from ..refine import refine_on_footage
        from ..tracking import load_pose

        refine_on_footage(args.out, args.refine_on, load_object(args.mesh, scale=args.scale), camera or Camera.default(),
                          budget_min=parse_budget(args.refine_budget), tracker=args.video_tracker, seed=args.seed,
                          init_pose=load_pose(args.init_pose) if args.init_pose else None)
    return 0


def _mode_line(name: str, st: dict, records) -> str:
    """One mode's row of the demo's table; its cost over the frames after the first, the first apart
    (the hybrid's loads the CNN's first call and, on a cold cache, compiles the kernels)."""
    rec = st["recover_frames"]
    rec_txt = "—" if not rec else ", ".join("never" if n is None else str(n) for n in rec)
    later = np.mean([r.ms for r in records[1:]]) if len(records) > 1 else float("nan")
    return (f"  {name:8s} {st['rot_median_deg']:7.2f} {st['rot_p90_deg']:7.2f} {st['rot_max_deg']:7.2f} "
            f"{st['trans_mean_pct']:8.2f} {100 * st['coverage']:6.0f}% {st['silent_failures']:7d} "
            f"{st['frames_lost']:5d}   {rec_txt:10s} {later:7.1f} {records[0].ms:9.0f}")


def cmd_demo(args) -> int:
    from ..bench.modes import (
        hybrid_record,
        load_sequence,
        run_cnn,
        run_tracker,
        sequence_stats,
        trusted_errors_deg,
    )
    from ..datasets import render_sequence_dataset
    from ..estimator import HybridEstimator
    from ..io import write_image
    from ..metrics import rotation_error_deg
    from ..objects import load_object
    from ..registry import create, get
    from ..render.sequences import SequenceSpec
    from ..tracking import draw_estimate, run_hybrid_on_frames
    from ..viz import contact_sheet, plot_error_over_time

    get("tracker", args.tracker), get("fusion", args.fusion)  # unknown names refused before rendering
    out = Path(args.out)
    obj = load_object("truss")
    camera = Camera.default().scaled(args.size)
    spec = SequenceSpec(trajectory="tumble", frames=args.frames, fps=30.0, occlusion="arm", seed=args.seed)
    scene_dir = render_sequence_dataset(out / "seq_tumble_arm", obj, camera, spec, progress=progress("demo: render"))
    stats = verify_dataset(out / "seq_tumble_arm", out / "verify.png", frames=12)
    print(f"demo: rendered {spec.frames} frames of a tumbling truss; a robot arm passes in front (partial, then "
          f"full) → {out / 'seq_tumble_arm'}")
    print(f"demo: contact sheet with projected CAD edges → {out / 'verify.png'} "
          f"(mask vs CAD IoU mean {stats['iou_mean']:.4f})")

    seq = load_sequence(scene_dir)
    _warm(args.tracker, args.fusion)
    regressor = create("regressor", "default", object=obj)
    estimator = HybridEstimator(create("tracker", args.tracker, object=obj), regressor,
                                create("fusion", args.fusion))
    keep = set(np.linspace(0, len(seq) - 1, 8).round().astype(int).tolist())
    tiles, labels, hybrid, calls, sites = [], [], [], [0], []

    def collect(frame, e, overlay):
        first_reinit = e.status == "reinit" and "reinit" not in (r.status for r in hybrid)
        if frame.index in keep or first_reinit:  # labelled after resizing, so the sheet's labels stay legible
            tiles.append(draw_estimate(frame, obj, e, None))
            err = f"{rotation_error_deg(e.pose, seq[len(hybrid)].truth):.1f} deg" if e.pose is not None else "no pose"
            labels.append(f"#{frame.index} {e.status.upper()} {err}")
        # the edge sites of the clearest tracked frame (the first one fully in view)
        visible = seq[len(hybrid)].visible
        if e.status == "tracking" and (not sites or sites[0][0] < min(visible, 0.99)):
            sites[:] = [(visible, sites_picture(frame, e, estimator.tracker.last_sites, obj))]
        hybrid.append(hybrid_record(e, estimator.regressor_calls - calls[0]))
        calls[0] = estimator.regressor_calls

    # the hybrid has no ground truth at all: the CNN initialises it
    res = run_hybrid_on_frames((s.frame for s in seq), estimator, out / "track", on_frame=collect)
    records = {"tracker": run_tracker(seq, create("tracker", args.tracker, object=obj)),
               "cnn": run_cnn(seq, regressor), "hybrid": hybrid}
    write_image(out / "tracking.png", contact_sheet(tiles, columns=4, labels=labels))
    if sites:
        write_image(out / "sites.png", sites[0][1])
    errors = {mode: [np.nan if e is None else e for e in trusted_errors_deg(seq, recs)] for mode, recs in records.items()}
    plot_error_over_time(out / "error_over_time.png", [s.frame.timestamp for s in seq], errors,
                         [s.visible for s in seq], title=f"tumble + arm, seed {args.seed}",
                         statuses=[r.status for r in hybrid])
    print(f"demo: errors on the {sum(s.visible >= 0.5 for s in seq)} frames where the truss is at least half visible "
          "(tracker: from the true first pose; CNN: every frame; hybrid: no ground truth)")
    print("  mode     median°    p90°  worst°  trans.%  frames  silent  lost   recovery   ms/frame  1st frame")
    for mode, recs in records.items():
        print(_mode_line(mode, sequence_stats(seq, recs), recs))
    print("  (frames: share with a trusted pose; silent: frames > 5° off not flagged lost; recovery: frames after "
          "a full occlusion until ≤ 2°; ms/frame: after the first frame, whose ms are apart)")
    print("demo: " + recoveries_text([r.status for r in hybrid]))
    print(f"demo: hybrid overlay (green tracking, yellow (re)init, red lost) → {res.video}; "
          f"{out / 'tracking.png'}; error over time → {out / 'error_over_time.png'}"
          + (f"; the edge tracker's sites on a clear frame → {out / 'sites.png'}" if sites else ""))
    return 0


def recoveries_text(statuses: list[str]) -> str:
    """How the hybrid came back after each stretch it flagged lost: the CNN re-initialised it
    (``reinit``) or the tracker resumed from the fused prediction (``tracking``)."""
    back, lost_from = [], None
    for k, status in enumerate(statuses):
        if status == "lost":
            lost_from = k if lost_from is None else lost_from
            continue
        if lost_from is not None and status in ("tracking", "reinit"):
            how = "the CNN re-initialised it" if status == "reinit" else "the tracker resumed from the prediction"
            back.append(f"lost from frame {lost_from}, back at frame {k}: {how}")
        lost_from = None
    if back:
        return "; ".join(back)
    if not {"tracking", "reinit"} & set(statuses):
        return "the hybrid never started: the CNN found no truss it could confirm"
    return "never lost the truss" if "lost" not in statuses else "lost the truss and did not come back before the end"


def sites_picture(frame, estimate, sites, obj, width_px: int = 560):
    """The frame around the object, enlarged (at least twice, to ``width_px`` wide), with the model at
    the estimate and the tracker's edge sites (what the tracker saw: ``hybridpose track --draw-sites``)."""
    import cv2

    from ..tracking import draw_estimate, with_sites
    from ..viz import SITE_LEGEND, put_label

    image = with_sites(draw_estimate(frame, obj, estimate, None), sites, frame.camera, legend=False)
    box = frame.camera.image_box(obj.bbox_corners, estimate.pose)
    h, w = image.shape[:2]
    if box is not None:
        pad = 10
        x0, y0 = max(int(box[0]) - pad, 0), max(int(box[1]) - pad, 0)
        x1, y1 = min(int(np.ceil(box[2])) + pad, w), min(int(np.ceil(box[3])) + pad, h)
        if x1 - x0 >= 16 and y1 - y0 >= 16:
            image = image[y0:y1, x0:x1]
    scale = max(2.0, width_px / image.shape[1])
    image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    return put_label(put_label(image, f"#{frame.index} {estimate.status.upper()}: edge sites"), SITE_LEGEND, bottom=True)


def add_commands(sub) -> None:
    """Add this module's subcommands to the ``hybridpose`` parser's ``sub``."""
    from ..fit import LOOKS, OCCLUDED_SHARE, TEXTURED_SHARE
    from ..refine import PATIENCE_EPOCHS

    k = sub.add_parser("track", help="track your object through a video or image folder (the hybrid: the CNN "
                                     "initialises; --init-pose: the tracker alone from that pose)")
    k.add_argument("source", help="video file (.mp4/.avi/...) or folder of images (.png/.jpg/.pgm/...)")
    k.add_argument("--object", required=True, help="built-in name or mesh file (.obj/.ply/.stl, ViSP .cao)")
    k.add_argument("--scale", type=float, default=1.0, help="mesh units → metres (0.001 for mm)")
    k.add_argument("--camera", required=True,
                   help="camera file: ours (.json/.yaml: width, height, K or fx/fy/cx/cy, dist), a ROS camera_info "
                        "YAML, an OpenCV FileStorage calibration (YAML/XML), a ViSP camera XML or tracker "
                        "configuration (its image size then comes from the frames)")
    k.add_argument("--init-pose", default=None,
                   help="tracker alone from this pose, no CNN, no fusion. JSON: quat_wxyz + t_m (metres), R + t_m, "
                        "or BOP cam_R_m2c + cam_t_m2c (mm); or a ViSP .pos file (tx ty tz in m, θu in rad)")
    k.add_argument("--regressor", default="default", help="registered regressor or a checkpoint file (best.pt)")
    k.add_argument("--fusion", default=DEFAULT_FUSION, help=f"fusion backend of the hybrid (isam2, ukf, none; default {DEFAULT_FUSION})")
    k.add_argument("--tracker", default="auto", help="tracker: auto (the default: edges where at least half the first frame "
                   "is dark, black space; else combined), edges (space), combined (real footage: a printed part, clutter, "
                   "a hand-held camera); the baselines klt-pnp, rapid, rapid-gos and rapid-ols by name too")
    k.add_argument("--tracker-option", action="append", metavar="NAME=VALUE",
                   help="a keyword of the tracker (repeatable), e.g. explain=false or lost_quality=0.4 for "
                        "edges; an unknown name lists the ones it takes")
    k.add_argument("--regressor-option", action="append", metavar="NAME=VALUE",
                   help="an option of a checkpoint regressor (repeatable; KeypointOptions), e.g. fine_tiles=true "
                        "to look for a small part in finer tiles of the frame")
    k.add_argument("--hybrid-option", action="append", metavar="NAME=VALUE",
                   help="a field of the hybrid's policy (repeatable; HybridConfig), set over the policy the "
                        "regressor's checkpoint recommends (a part fitted with hybridpose fit: reacquire_deg=20; "
                        "reacquire_deg=none turns it off)")
    k.add_argument("--sun-dir", default=None, metavar="X,Y,Z|CSV",
                   help="in space with the sun the only light: the direction the sunlight travels in the camera "
                        "frame (x right, y down, z forward), e.g. from a sun sensor — one for every frame, or a CSV "
                        "file of it over time (columns timestamp_s or frame, x, y, z; interpolated between rows); "
                        "the edge fits then leave out the model edges the sun cannot show")
    k.add_argument("--fps", type=float, default=None, help="frame rate for image folders (default 30)")
    k.add_argument("--max-frames", type=int, default=None)
    k.add_argument("--threads", type=int, default=None,
                   help="CPU threads for the per-frame work (torch, ONNX Runtime, OpenCV, numba); default "
                        "$HYBRIDPOSE_THREADS or 1, which holds up where other work keeps the cores busy")
    k.add_argument("--draw-sites", action="store_true",
                   help="draw the tracker's moving-edge sites on the overlay, as ViSP does: cyan matched, red "
                        "rejected (a line to the edge it found), orange no edge on a lit line, grey no edge in the dark")
    k.add_argument("--out", required=True, help="folder for the overlay video, poses.csv, scene_gt.json")
    k.set_defaults(func=cmd_track)

    b = sub.add_parser("bench", help="tracker-only vs CNN-only vs hybrid on a seeded sequence suite or your BOP "
                                     "sequences: results.json, report.md, plots (resumable)")
    b.add_argument("--suite", default="standard",
                   help="standard (space: 7 kinds × 20 seeds), occlusion, smoke, or realistic (a printed cube and a "
                        "plain box filmed by a hand-held camera on photos and clutter: 3 kinds × 10 seeds)")
    b.add_argument("--split", default="report", choices=["report", "tuning"],
                   help="report: seeds no tuning used (the published figures); tuning: the seeds defaults were chosen on")
    b.add_argument("--seeds", default=None,
                   help="the split's seeds instead of its default twenty, e.g. 920-979 or 520-539,560 (tuning "
                        "seeds lie in 900–999, or 100–199 for the realistic suite; report seeds outside it); more "
                        "seeds, a tighter spread")
    b.add_argument("--data", default=None, help="your BOP sequences (folder) instead of a suite; needs --object")
    b.add_argument("--object", default="truss", help="built-in name or mesh file")
    b.add_argument("--scale", type=float, default=1.0, help="mesh units → metres (0.001 for mm)")
    b.add_argument("--modes", default="tracker,cnn,hybrid",
                   help="comma list among tracker (from the true first pose), cnn (every frame, no prior) and "
                        "hybrid (no ground truth); default all three, on the same frames")
    b.add_argument("--trackers", default="",
                   help="comma list: tracker-only and hybrid runs per tracker (default: edges; combined on the "
                        "realistic suite)")
    b.add_argument("--fusions", default=DEFAULT_FUSION, help="comma list: a hybrid run per tracker × fusion")
    b.add_argument("--regressor", default="default",
                   help="registered name or checkpoint file; for the realistic suite one per part, "
                        "cube=FIT/best.pt,box=FIT2/best.pt (hybridpose fit cube --out FIT): without them its "
                        "CNN and hybrid runs are left out")
    b.add_argument("--check-periods", default="", help="comma list of CNN check periods to ablate (frames)")
    b.add_argument("--config", action="append", default=[],
                   help="one more hybrid run with these HybridConfig fields, e.g. probation_frames=2,check_period=5 "
                        "or keep_quality=none (repeatable), set over the default row's policy (the defaults, with "
                        "what the regressor's checkpoint recommends)")
    b.add_argument("--tracker-option", action="append", default=[], metavar="NAME=VALUE",
                   help="a keyword argument of every tracker run, tracker-only and hybrid, e.g. max_samples=800 "
                        "(repeatable; the options a tracker takes: its docstring)")
    b.add_argument("--sun", default="known",
                   help="known: the frames of space-lit sequences carry the sun's direction, as a spacecraft's "
                        "sun sensors give it (the edge fits leave out edges the sun cannot show); unknown: they "
                        "do not; known,unknown: every run both ways")
    b.add_argument("--workers", type=int, default=1, help="parallel processes (one sequence each)")
    b.add_argument("--ray", default=None,
                   help="run the sequences as Ray tasks: 'local' (start Ray here for the run), 'auto' (the cluster "
                        "this machine joined with `ray start`) or a cluster's address (pip install 'hybridpose[ray]')")
    b.add_argument("--video", default=None, help="also write the hybrid's overlay video of this sequence")
    b.add_argument("--sequences", default=None, metavar="PATTERNS",
                   help="comma list of shell-style patterns of the sequences to run (NAME_sSEED), e.g. "
                        "'approach_arm-*' or 'tumble_none_s503,fly-around_*'; default all")
    b.add_argument("--limit", type=int, default=None, help="the suite's first N sequences only")
    b.add_argument("--cache", default="runs/bench_cache", help="rendered suite sequences (reused)")
    b.add_argument("--out", required=True,
                   help="folder for results.json, report.md and the plots (an interrupted run resumes from its rows)")
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
    f.add_argument("--camera", default=None,
                   help="camera file (ours, ROS camera_info, OpenCV FileStorage or ViSP XML, with its image size); "
                        "default 640×480, f = 600 px")
    f.add_argument("--out", required=True, help="the fit's folder (an interrupted fit resumes there)")
    f.add_argument("--budget", default="60m", help="time for the whole fit: 60m, 1h30m, 90s (default 60m)")
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--look", default="random", choices=LOOKS,
                   help="random: a part on a bench or in a hand (cluttered or photo backgrounds, lights, colours, "
                        "and a real camera's motion blur, exposure, white balance, noise and JPEG; the network learns "
                        "to find the part); space: black space and the sun alone, the part "
                        "found as the sunlit pixels (default random)")
    f.add_argument("--distances", type=float_pair, default=None, metavar="NEAR,FAR",
                   help=f"the part's distances in the views, metres (default: log-uniform from where its diameter "
                        f"spans {100 * NEAR_FILL:.0f} %% to {100 * FAR_FILL:.0f} %% of the image's shorter side)")
    f.add_argument("--backgrounds", default="shipped", metavar="DIR",
                   help="photos: half the training backgrounds are crops of them (look random); default: a few "
                        "public-domain photos that come with hybridpose; none: procedural clutter alone")
    f.add_argument("--workers", type=int, default=None, help="render processes (default: one per core)")
    f.add_argument("--init-from", default="default",
                   help="checkpoint to start from: 'default' (the shipped network's weights), a path, or 'none'")
    f.add_argument("--occluded-share", type=float, default=OCCLUDED_SHARE, metavar="SHARE",
                   help=f"share of the training views with the arm partly in front of the part (default {OCCLUDED_SHARE:g})")
    f.add_argument("--video", default=None, metavar="FILE",
                   help="your own footage (video file or image folder, same camera): after the fit, the network is "
                        "checked on 40 of its frames without labels — how often the tracker confirms its pose "
                        "(where the hybrid can start) — and report.md says so")
    f.add_argument("--video-tracker", default="combined",
                   help="the tracker that confirms the CNN's poses in the --video check (default combined: real "
                        "footage; edges in space)")
    f.add_argument("--refine-on", default=None, metavar="VIDEO",
                   help="your own footage (video file or image folder, same camera): after the fit, the tracker "
                        "(--video-tracker) follows the part through it and the frames it holds with confidence "
                        "refine the network (refine/best.pt); the last quarter of those frames (a later stretch) is held "
                        "back and report.md gives the network's errors there before and after")
    f.add_argument("--init-pose", default=None, metavar="FILE",
                   help="the part's pose in the --refine-on video's first frame (as for `track --init-pose`): the "
                        "tracker starts from it; without it, from the hybrid's own start")
    f.add_argument("--refine-budget", default="10m", help="the most training time of --refine-on (default 10m; "
                   f"less where its loss on a tenth of its frames, kept out, stops falling for {PATIENCE_EPOCHS} epochs)")
    f.add_argument("--textured-share", type=float, default=None, metavar="SHARE",
                   help="share of the training views with a random print on the part, as real parts often are "
                        f"(default {TEXTURED_SHARE:g}, 0 in space; 0 for a part you know to be plain)")
    f.set_defaults(func=cmd_fit)

    d = sub.add_parser("demo", help="render an arm-occlusion sequence, run tracker-only, CNN-only and the hybrid "
                                    "(no ground truth) on it, print their errors, write the overlay video and plots")
    d.add_argument("--out", default="hybridpose_demo", help="folder for the sequence, the pictures and the overlay "
                                                            "video (default hybridpose_demo)")
    d.add_argument("--frames", type=int, default=60, help="frames to render at 30 fps (default 60: 2 s)")
    d.add_argument("--size", default="640x480", help="image size WxH (default 640x480; at 160x120 the CNN "
                                                     "finds no truss: the hybrid never starts)")
    d.add_argument("--tracker", default="edges", help="tracker: edges (space, the default) or combined (real footage: a printed part, clutter, a "
                   "hand-held camera); the baselines klt-pnp, rapid, rapid-gos and rapid-ols by name too")
    d.add_argument("--fusion", default=DEFAULT_FUSION, help=f"fusion backend of the hybrid (isam2, ukf, none; default {DEFAULT_FUSION})")
    d.add_argument("--seed", type=int, default=1, help="the tumble's and the arm's draw (default 1)")
    d.set_defaults(func=cmd_demo)
