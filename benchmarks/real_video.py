"""Trackers on real video: ViSP's own model-based-tracking sequence (a textured 8.4-cm cube on a desk,
218 grey 640 × 480 frames, a hand-held camera; the sequence, CAD model ``cube.cao``, camera and
initial pose ``cube.0.pos`` that ViSP's tracker tutorials use), from Debian's / Ubuntu's
``visp-images-data`` package::

    sudo apt install visp-images-data          # or, without root:
    apt-get download visp-images-data && dpkg -x visp-images-data_*.deb visp
    python benchmarks/real_video.py --visp-images /usr/share/visp-images-data/ViSP-images
    # cam.json: {"width": 640, "height": 480, "fx": px, "fy": py, "cx": u0, "cy": v0} of mbt/cube.xml
    # (fit needs the image size, which a tracker configuration does not give; track takes it from the frames)
    # PHOTOS: scikit-image's sample photos (benchmarks/own_object.py, training_photos)
    hybridpose fit DIR/mbt/cube.cao --camera cam.json --budget 40m --backgrounds PHOTOS --textured-share 0.5 --out runs/visp_cube
    python benchmarks/real_video.py --visp-images DIR --regressor runs/visp_cube/best.pt   # + the hybrid and the
        # fitted CNN alone on every 6th frame (from the whole frame, and given the cube's box)

Where the package also holds ViSP's castle sequence (``mbt-depth/castel``: 30 frames of a textured
model castle in a cluttered room, modelled only in part by ``chateau.cao``, separate faces from its
``chateau.0.pos``), the trackers run on it too: ``combined`` with its defaults, ``edges`` with ``explain=False`` (the model explains a
fraction of the castle's edges; the check that asks it to would call every frame lost) and
``lost_quality=0.45``, beside the raw ``cv2.rapid`` trackers.

With ``--visp-repo`` (a checkout of github.com/lagadic/visp), five videos of its tutorials too
(``REPO_VIDEOS``): the MegaPose cube video (a printed cube turned by hand on a cluttered desk), the
detection tutorial's cube video, the lego square (four bricks, its ``.cao`` placing one brick model
four times; a focal length estimated from the video, its XML's does not fit it) and the two teabox
videos of its model-based tracking tutorials (the mono one, and the stereo one's left camera); every tracker forward
and back to the first frame from a hand-labelled first pose (``benchmarks/data/*.0.pos``), scored by how
far from it the round trip ends (forward–backward consistency) besides the edge distance. Its dragon
video is left out: its model is a Panda3D ``.bam`` file that the repository does not hold.

Every tracker starts from ``cube.0.pos`` on the first frame and is never re-initialised; our
backends (``edges``, ``klt-pnp``, ``rapid``, ``rapid-ols``, ``rapid-gos``: cv2.rapid's silhouette step
followed by our edge fit and quality) run beside OpenCV's raw ``cv2.rapid`` trackers
(``refine=False``). No true pose exists, so each frame is scored by the median distance from the
model's visible edges at the tracked pose to the image's edges (Canny; ``edges.edge_distances_px``):
about a pixel where the model sits on the cube, several where it slid off. Writes
``benchmarks/results/real_video.json``, the ``real-video`` section of ``benchmarks/RESULTS.md`` and,
under ``--out``, an overlay strip per run (frames 0, 72, 145, 217).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import environment, publish  # noqa: E402

TRACKERS = ("combined", "edges", "klt-pnp", "rapid", "rapid-ols", "rapid-gos")
RAW = ("rapid", "rapid-ols", "rapid-gos")  # cv2.rapid alone: refine=False
STRIP_FRAMES = (0, 72, 145, 217)
CASTLE_STRIP = (0, 10, 20, 29)
# the castle: our edge tracker without the explained-edge check (a partial model of a textured scene)
CASTLE_EDGES = {"explain": False, "lost_quality": 0.45}
CASTLE_SEARCH_PX = 16  # its initial pose lies 10–20 px off the castle: the first fit searches further
DEFAULT_DIRS = ("/usr/share/visp-images-data/ViSP-images",)
CNN_EVERY = 6  # the fitted CNN alone runs on every CNN_EVERY-th frame
RESULTS_JSON = Path(__file__).resolve().parent / "results" / "real_video.json"


def find_visp_images(arg: str | None) -> Path:
    """The ViSP-images folder: ``arg``, else ``$VISP_INPUT_IMAGE_PATH/ViSP-images`` (ViSP's own
    convention), else the Debian package's; an error saying how to get it where none holds the cube."""
    env = os.environ.get("VISP_INPUT_IMAGE_PATH")
    candidates = [arg] if arg else [*([os.path.join(env, "ViSP-images")] if env else []), *DEFAULT_DIRS]
    for c in candidates:
        if (Path(c) / "mbt" / "cube.cao").is_file():
            return Path(c)
    raise SystemExit(f"--visp-images: no ViSP-images folder with mbt/cube.cao among {candidates}; install "
                     "Debian's visp-images-data (apt install visp-images-data, or apt-get download visp-images-data "
                     "&& dpkg -x visp-images-data_*.deb DIR) and pass DIR/usr/share/visp-images-data/ViSP-images")


def visp_sequence(images: Path, model: Path, config: Path, first_pose: Path):
    """(frames, camera, object, first pose) of one of ViSP's tracker sequences: the ``.pgm`` frames of
    ``images`` (30 fps), the ``.cao`` ``model``, the camera of the tracker ``config`` and the ``.pos`` pose."""
    from hybridpose.geometry import load_camera
    from hybridpose.objects import load_object
    from hybridpose.tracking import first_frame_size, load_pose, read_frames

    camera = load_camera(config, image_size=first_frame_size(images))  # the config gives no image size
    return list(read_frames(images, camera, fps=30)), camera, load_object(model), load_pose(first_pose)


def tracker_step(tracker, pose0, first_search_px: int | None = None):
    """``step(frame) → (pose or None, lost)`` of a tracker started at ``pose0`` on frame 0 (searching
    ``first_search_px`` there where given) and never re-initialised."""
    def step(frame):
        if frame.index == 0:
            tracker.init(frame, pose0)
            if first_search_px:
                m = tracker.track(frame, pose0, search_px=first_search_px)
                return m.pose, m.lost
        m = tracker.track(frame)
        return m.pose, m.lost
    return step


def run(label: str, frames, obj, step, out: Path, strip_frames=STRIP_FRAMES) -> dict:
    """``step(frame) → (pose or None, lost)`` over ``frames``: per-frame median edge distance (px, NaN
    without a pose), lost flags, ms per frame (the step only), and the overlay strip."""
    from hybridpose.edges import ModelView, edge_distances_px
    from hybridpose.viz import draw_wireframe

    view = ModelView(obj)
    medians, lost, ms, strip, poses = [], [], [], [], []
    for frame in frames:
        t0 = time.perf_counter()
        pose, is_lost = step(frame)
        ms.append(1000 * (time.perf_counter() - t0))
        lost.append(bool(is_lost))
        poses.append(pose)
        d = edge_distances_px(view, frame, pose) if pose is not None else np.zeros(0)
        medians.append(float(np.median(d)) if len(d) else float("nan"))
        if frame.index in strip_frames:
            img = frame.image if pose is None else draw_wireframe(frame.image, obj, pose, frame.camera,
                                                                  (255, 60, 60) if is_lost else (60, 255, 60), 2)
            strip.append(cv2.resize(img, (320, 240), interpolation=cv2.INTER_AREA))
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{''.join(c if c.isalnum() or c in '-.' else '_' for c in label)}.png"
    tmp = path.with_name(path.stem + ".tmp.png")
    cv2.imwrite(str(tmp), cv2.cvtColor(np.hstack(strip), cv2.COLOR_RGB2BGR))
    tmp.replace(path)
    m = np.array(medians)
    tracked = ~np.array(lost) & np.isfinite(m)
    return {"run": label, "frames": len(m), "tracked": int(tracked.sum()),
            "edge_px_median": float(np.median(m[tracked])) if tracked.any() else None,
            "edge_px_p90": float(np.percentile(m[tracked], 90)) if tracked.any() else None,
            "edge_px_worst": float(np.max(m[tracked])) if tracked.any() else None,
            "ms_per_frame": float(np.mean(ms)), "edge_px_per_frame": [round(x, 3) for x in medians],
            "lost_per_frame": lost, "strip": str(path), "poses": poses}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--visp-images", default=None, help="the ViSP-images folder (holds mbt/cube.cao)")
    ap.add_argument("--out", default="runs/real_video", help="overlay strips")
    ap.add_argument("--regressor", default=None, help="a checkpoint fitted for cube.cao: adds the hybrid, no initial pose")
    ap.add_argument("--visp-repo", default=None,
                    help="a checkout of ViSP's repository (github.com/lagadic/visp): adds its MegaPose and "
                         "detection-tutorial cube videos")
    ap.add_argument("--fusions", default="isam2,ukf,none", help="the hybrid's fusion backends, one row each")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    from hybridpose.bench.runner import WARMUP_FRAMES
    from hybridpose.estimator import HybridEstimator
    from hybridpose.registry import create

    root = find_visp_images(args.visp_images)
    mbt = root / "mbt"
    frames, camera, obj, pose0 = visp_sequence(mbt / "cube", mbt / "cube.cao", mbt / "cube.xml", mbt / "cube.0.pos")
    out = Path(args.out)

    # untimed, on fresh trackers (as the bench runner does): the first calls compile the numba kernels (seconds where their cache is
    # cold, as after an install), which would be charged to the first sequence each tracker runs
    for name in TRACKERS:
        step = tracker_step(create("tracker", name, object=obj), pose0)
        for frame in frames[:WARMUP_FRAMES]:
            step(frame)
    rows = []
    for name in TRACKERS:
        rows.append(run(name, frames, obj, tracker_step(create("tracker", name, object=obj), pose0), out))
        print(f"{name}: {rows[-1]['tracked']} of {rows[-1]['frames']} frames, {rows[-1]['edge_px_median']} px", flush=True)
    for name in RAW:
        rows.append(run(f"{name} (raw cv2)", frames, obj,
                        tracker_step(create("tracker", name, object=obj, refine=False), pose0), out))
        print(f"{name} raw: {rows[-1]['tracked']} of {rows[-1]['frames']} frames, {rows[-1]['edge_px_median']} px", flush=True)
    alone = cnn_alone(frames, obj, args.regressor, rows[0]) if args.regressor else None
    carried = None
    if not args.regressor and RESULTS_JSON.is_file():
        # no fitted CNN this run: the hybrid rows and the CNN's line of the last run that had one stand
        last = json.loads(RESULTS_JSON.read_text())
        kept = [r for r in last.get("rows", []) if r["run"].startswith("hybrid")]
        if kept:
            carried = last.get("carried_from") or last["environment"]["git"]
            alone = last.get("cnn_alone")
    for fusion in (args.fusions.split(",") if args.regressor else []):
        est = HybridEstimator.from_names(object=obj, regressor=args.regressor, fusion=fusion)

        def hybrid_step(frame, est=est):
            e = est.step(frame)
            return (None, True) if e.pose is None or e.status == "lost" else (e.pose, False)
        rows.append(run(f"hybrid (edges + fitted CNN + {fusion}, no initial pose)", frames, obj, hybrid_step, out))
        print(f"hybrid {fusion}: {rows[-1]['tracked']} of {rows[-1]['frames']} frames", flush=True)
    pair = picture(rows, "real_video_cube.jpg")
    for r in rows:
        r.pop("poses")
    if carried:
        rows += kept
    payload = {"environment": environment(), "sequence": str(mbt / "cube"), "camera": camera.to_dict(), "rows": rows,
               "cnn_alone": alone, **({"carried_from": carried} if carried else {})}
    lines = [f"ViSP's cube sequence (`visp-images-data`, `mbt/cube`: {len(frames)} real frames, 640 × 480 grey), "
             f"commit `{payload['environment']['git']}`, one thread. Trackers alone start from `cube.0.pos` and are "
             "never re-initialised; hybrid rows get no pose at all; per frame, the median distance (px) from the "
             "model's visible edges to the image's edges; over the frames each run tracked (not flagged lost).", "",
             *table(rows), *([""] + [f"The hybrid rows and the fitted CNN's line come from the run at commit `{carried}` "
                                   "(this run had no `--regressor`)."] if carried else []),
             "", f"Frames 0, 72, 145 and 217: {' (top) and '.join(r['run'] for r in pair)}"
             f"{' (bottom)' if len(pair) > 1 else ''}, green where the run trusted its pose.", "",
             "![the model at each run's pose on ViSP's cube sequence](results/real_video_cube.jpg)"]
    if alone is not None:
        lines += ["", *cnn_alone_lines(alone, rows[0]["run"])]
    castle_dir = root / "mbt-depth" / "castel"
    if (castle_dir / "chateau.cao").is_file():
        payload["castle"], castle_lines = castle(castle_dir, out)
        lines += ["", *castle_lines]
    for video in REPO_VIDEOS if args.visp_repo else ():
        payload[video.key], video_lines = repo_video(Path(args.visp_repo), video, out)
        lines += ["", *video_lines]
    publish("real_video", "real-video", payload, lines)


def cnn_alone(frames, obj, regressor: str, reference: dict, every: int = CNN_EVERY) -> dict:
    """The fitted CNN alone on every ``every``-th frame, against the ``reference`` run's poses (to the
    nearest of the object's equivalent poses): from the whole frame (``"whole"``), and given the box
    of the reference pose's projection (``"box"``: the detection's share of the misses). Each: the
    frames in a tracker's basin (as in ``hybridpose bench``: within ``BASIN_DEG`` and ``BASIN_PCT`` %
    of the distance), those with a pose at all, the median ms a call."""
    from hybridpose.bench.modes import BASIN_DEG, BASIN_PCT
    from hybridpose.metrics import nearest_equivalent, rotation_error_deg
    from hybridpose.regressors.predictor import CheckpointRegressor

    reg = CheckpointRegressor(regressor, object=obj)
    sampled = [f for f in frames[::every]
               if reference["poses"][f.index] is not None and not reference["lost_per_frame"][f.index]]
    out = {"every": every, "frames": [f.index for f in sampled], "basin_deg": BASIN_DEG, "basin_pct": BASIN_PCT}
    for key in ("whole", "box"):
        inside, found, ms = [], 0, []
        for frame in sampled:
            ref = reference["poses"][frame.index]
            box = frame.camera.image_box(obj.bbox_corners, ref) if key == "box" else None
            roi = None if box is None else (int(box[0]), int(box[1]), int(np.ceil(box[2] - box[0])),
                                            int(np.ceil(box[3] - box[1])))
            t0 = time.perf_counter()
            m = reg.predict(frame, roi)
            ms.append(1000 * (time.perf_counter() - t0))
            if m.pose is None:
                continue
            found += 1
            truth = nearest_equivalent(m.pose, ref, obj.symmetries)
            pct = 100 * np.linalg.norm(m.pose.t - truth.t) / np.linalg.norm(ref.t)
            if rotation_error_deg(m.pose, truth) <= BASIN_DEG and pct <= BASIN_PCT:
                inside.append(frame.index)
        out[key] = {"in_basin": inside, "found": found, "ms_median": float(np.median(ms))}
    return out


def cnn_alone_lines(alone: dict, reference: str) -> list[str]:
    """The results page's lines for :func:`cnn_alone`."""
    n = len(alone["frames"])

    def counts(key):
        return f"{len(alone[key]['in_basin'])} of {n} ({alone[key]['ms_median']:.0f} ms median a call)"

    return [f"The fitted CNN alone, on one frame in {alone['every']}, against the `{reference}` track from "
            f"`cube.0.pos` (to the nearest of the cube's equivalent poses): within {alone['basin_deg']:g}° and "
            f"{alone['basin_pct']:g} % of the distance (a tracker's basin) on {counts('whole')} from the whole "
            f"frame; on {counts('box')} given the box of the cube's projection."]


def table(rows: list[dict], round_trip: bool = False) -> list[str]:
    """The results table's lines, one row per run; ``round_trip``: runs out and back
    (:func:`forward_backward`), with where each ended (:func:`fb_cell`)."""
    tracked = "frames tracked (of the round trip)" if round_trip else "frames tracked"
    back = " back at frame 0: deg / mm |" if round_trip else ""
    lines = [f"| run | {tracked} | edge px: median / p90 / worst frame |{back} ms/frame |",
             "|---|---|---|" + ("---|" if round_trip else "") + "---|"]
    for r in rows:
        px = "—" if r["edge_px_median"] is None else f"{r['edge_px_median']:.2f} / {r['edge_px_p90']:.2f} / {r['edge_px_worst']:.2f}"
        end = f" {fb_cell(r)} |" if round_trip else ""
        lines.append(f"| {r['run']} | {r['tracked']} of {r['frames']} | {px} |{end} {r['ms_per_frame']:.1f} |")
    return lines


def picture(rows: list[dict], name: str, pair: list[dict] | None = None) -> list[dict]:
    """``benchmarks/results/NAME``: the strips of ``pair`` one above the other (default: the first run's
    above that of the raw cv2 run that strayed most); the runs shown."""
    raw = [r for r in rows if r["run"].endswith("(raw cv2)") and r["edge_px_median"] is not None]
    if pair is None:
        pair = [rows[0], max(raw, key=lambda r: r["edge_px_median"])] if raw else [rows[0]]
    image = np.vstack([cv2.resize(cv2.imread(r["strip"]), None, fx=0.75, fy=0.75, interpolation=cv2.INTER_AREA)
                       for r in pair])
    path = Path(__file__).resolve().parent / "results" / name
    tmp = path.with_name(path.stem + ".tmp.jpg")
    cv2.imwrite(str(tmp), image, [cv2.IMWRITE_JPEG_QUALITY, 80])
    tmp.replace(path)
    return pair


def castle(folder: Path, out: Path) -> tuple[dict, list[str]]:
    """ViSP's castle sequence (``mbt-depth/castel``): our ``edges`` (``CASTLE_EDGES``) and OpenCV's raw
    ``cv2.rapid`` trackers from ``chateau.0.pos``; (payload, results-page lines)."""
    from hybridpose.registry import create

    # the grey frames (its depth_image_* files are .bin)
    frames, camera, obj, pose0 = visp_sequence(folder / "castel", folder / "chateau.cao", folder / "chateau.xml",
                                               folder / "chateau.0.pos")

    def step_of(tracker):
        return tracker_step(tracker, pose0, CASTLE_SEARCH_PX)

    options = ", ".join(f"{k}={v}" for k, v in CASTLE_EDGES.items())
    rows = [run("combined", frames, obj, step_of(create("tracker", "combined", object=obj)), out / "castle", CASTLE_STRIP),
            run(f"edges ({options})", frames, obj, step_of(create("tracker", "edges", object=obj, **CASTLE_EDGES)),
                out / "castle", CASTLE_STRIP),
            run("edges (defaults)", frames, obj, step_of(create("tracker", "edges", object=obj)), out / "castle",
                CASTLE_STRIP)]
    for name in RAW:
        rows.append(run(f"{name} (raw cv2)", frames, obj, step_of(create("tracker", name, object=obj, refine=False)),
                        out / "castle", CASTLE_STRIP))
    for r in rows:
        r.pop("poses")
        print(f"castle {r['run']}: {r['tracked']} of {r['frames']} frames, {r['edge_px_median']} px", flush=True)
    pair = picture(rows, "real_video_castle.jpg")
    lines = [f"ViSP's castle sequence (`mbt-depth/castel`: {len(frames)} real frames, 640 × 480 grey, hand-held "
             "camera): a textured model castle in a cluttered room, `chateau.cao` modelling only its floor, tower, "
             "door and slope as separate faces. Every tracker starts from `chateau.0.pos` (10–20 px off the castle; "
             f"the first fit searches {CASTLE_SEARCH_PX} px) and is never re-initialised.", "", *table(rows), "",
             f"Frames {', '.join(map(str, CASTLE_STRIP[:-1]))} and {CASTLE_STRIP[-1]}: "
             f"{' (top) and '.join(r['run'] for r in pair)}{' (bottom)' if len(pair) > 1 else ''}.", "",
             "![the model at each run's pose on ViSP's castle sequence](results/real_video_castle.jpg)"]
    return {"sequence": str(folder / "castel"), "camera": camera.to_dict(), "rows": rows}, lines


@dataclass(frozen=True)
class RepoVideo:
    """A video of ViSP's repository tracked forward and back from a hand-labelled first pose."""

    key: str            # the payload's key and the picture's name
    title: str          # what the results page calls it
    about: str          # what it shows
    video: str          # the video, in the repository
    model: str          # its CAD model, in the repository
    camera: str         # its camera: a ViSP tracker XML, or a JSON of px, py, u0, v0 (in the repository, or ours)
    frames: int         # how many of its frames make the round trip
    strip: tuple        # the frames shown on the way out
    label: str          # how the first pose was labelled


DATA = Path(__file__).resolve().parent / "data"
REPO_VIDEOS = (
    RepoVideo("megapose_cube", "ViSP's MegaPose cube video",
              "a printed 8.45-cm cube turned by hand on a cluttered desk (keyboard, mug, bottle, screen), "
              "640 × 480 RGB; after frame 600 a mug hides most of the cube",
              "tutorial/tracking/dnn/data/cube_video.mp4", "tutorial/tracking/dnn/data/models/cube/cube.obj",
              "tutorial/tracking/dnn/data/megapose_cube.json", 590, (0, 150, 300, 450, 589),
              "the front face's corners clicked, then one edge fit; which face is which read from its print"),
    RepoVideo("detection_cube", "ViSP's detection-tutorial cube video",
              "ViSP's printed 8.4-cm cube on a table beside a tube, a hand reaching in, 640 × 480 grey",
              "tutorial/detection/object/cube.mp4", "tutorial/detection/object/cube.cao",
              "tutorial/detection/object/cube.xml", 261, (0, 65, 130, 195, 260),
              "six corners clicked, then one edge fit"),
    RepoVideo("lego_square", "ViSP's lego-square video",
              "four 2 × 4 bricks in a square on a green plate (4.8 cm across, `lego-square.cao` loading one brick "
              "four times, placed), the plate pushed and turned by a hand before a fixed camera, 640 × 480 RGB; its camera is ours: "
              "ViSP's `lego-square.xml` gives 839 px focal length, with which no tracker holds these frames, and "
              "the model holds them for any focal length from 445 to 485 px (465 here, `data/lego_square.json`)",
              "tutorial/tracking/model-based/generic/model/lego-square/lego-square.mp4",
              "tutorial/tracking/model-based/generic/model/lego-square/lego-square.cao",
              str(DATA / "lego_square.json"), 99, (0, 25, 50, 75, 98),
              "the square's four top corners clicked, then edge fits searched around that pose"),
    RepoVideo("teabox", "ViSP's teabox video",
              "ViSP's printed tea box (16.5 × 6.8 × 8 cm, `teabox.cao`) on a white table, 0.45 m from a camera "
              "moved slowly by hand, 640 × 480 grey",
              "tutorial/tracking/model-based/generic/model/teabox/teabox.mp4",
              "tutorial/tracking/model-based/generic/model/teabox/teabox.cao",
              "tutorial/tracking/model-based/generic/model/teabox/teabox.xml", 39, (0, 13, 26, 38),
              "six corners clicked (PnP), then one edge fit"),
    RepoVideo("teabox_left", "ViSP's stereo teabox video (left camera)",
              "the same tea box on a wooden disc 0.41 m from the camera, a hand sliding and turning the disc, "
              "640 × 480 grey",
              "tutorial/tracking/model-based/generic-stereo/teabox_left.mp4",
              "tutorial/tracking/model-based/generic-stereo/teabox_left.cao",
              "tutorial/tracking/model-based/generic-stereo/teabox_left.xml", 121, (0, 40, 80, 120),
              "six corners clicked (PnP), then one edge fit"),
)


def repo_camera(path: Path):
    """A ViSP tracker configuration (XML), or a JSON whose ``camera`` gives px, py, u0, v0 (the MegaPose
    tutorial's; ours for the lego square)."""
    from hybridpose.geometry import Camera, load_camera

    if path.suffix.lower() == ".json":
        c = json.loads(path.read_text())["camera"]
        return Camera.from_K(np.array([[c["px"], 0, c["u0"]], [0, c["py"], c["v0"]], [0, 0, 1]]), 640, 480)
    return load_camera(path, image_size=(640, 480))


def repo_frames(repo: Path, video: RepoVideo):
    """(frames, camera, object, first pose) of ``video``: its first ``video.frames`` frames, its camera and
    CAD model from ``repo`` (a checkout of github.com/lagadic/visp), the pose in ``benchmarks/data``."""
    from hybridpose.objects import load_object
    from hybridpose.tracking import load_pose, read_frames

    path = repo / video.video
    if not path.is_file():
        raise SystemExit(f"--visp-repo: {path} not found; pass a checkout of github.com/lagadic/visp")
    camera = repo_camera(repo / video.camera)
    frames = []
    for frame in read_frames(path, camera):  # at the video's own frame rate, as `hybridpose track` reads it
        if frame.index >= video.frames:
            break
        frames.append(frame)
    return frames, camera, load_object(repo / video.model), load_pose(DATA / f"{video.key}.0.pos")


def forward_backward(frames, obj, tracker, pose0, out: Path, label: str, strip_out=()) -> dict:
    """``tracker`` from ``pose0`` over ``frames`` and back to the first (never re-initialised): the
    :func:`run` row of the whole round trip, with how far the pose it ends at lies from ``pose0``
    (degrees, mm) — a drift-free tracker comes back where it started."""
    from dataclasses import replace

    from hybridpose.metrics import rotation_error_deg

    trip = [replace(f, index=k, timestamp=k / 30) for k, f in enumerate(frames + frames[-2::-1])]
    strip = tuple(sorted({*strip_out, len(trip) - 1}))
    row = run(label, trip, obj, tracker_step(tracker, pose0), out, strip)
    end = row["poses"][-1]  # None where the run ends lost: it did not come back
    row["fb_deg"] = None if end is None else rotation_error_deg(end, pose0)
    row["fb_mm"] = None if end is None else 1000 * float(np.linalg.norm(end.t - pose0.t))
    row["lost_frames"] = int(sum(row["lost_per_frame"]))
    return row


def fb_cell(row: dict) -> str:
    """``deg / mm`` back at the first frame, or ``lost at the end``."""
    return "lost at the end" if row["fb_deg"] is None else f"{row['fb_deg']:.1f} / {row['fb_mm']:.1f}"


def repo_video(repo: Path, video: RepoVideo, out: Path) -> tuple[dict, list[str]]:
    """Every tracker forward and backward over ``video``; (payload, results-page lines)."""
    from hybridpose.registry import create

    frames, camera, obj, pose0 = repo_frames(repo, video)
    folder = out / video.key
    rows = [forward_backward(frames, obj, create("tracker", name, object=obj), pose0, folder, name, video.strip)
            for name in TRACKERS]
    rows.append(forward_backward(frames, obj, create("tracker", "klt-pnp", object=obj, edge_refine=False), pose0,
                                 folder, "klt-pnp (edge_refine=False)", video.strip))
    for r in rows:
        for key in ("poses", "edge_px_per_frame", "lost_per_frame"):  # the page needs the summary
            r.pop(key)
        print(f"{video.key} {r['run']}: {r['tracked']} of {r['frames']}, back at frame 0: {fb_cell(r)}", flush=True)
    worst = min(rows[1:], key=lambda r: (r["fb_deg"] is not None, r["tracked"]))
    pair = picture(rows, f"real_video_{video.key}.jpg", [rows[0], worst])
    lines = [f"{video.title} (ViSP's repository, `{video.video}`): {video.about}; its first {len(frames)} frames, "
             "forward and back to the first frame: a tracker that does not drift ends where it started. Every "
             f"tracker starts from a hand-labelled first pose (`benchmarks/data/{video.key}.0.pos`: {video.label}) "
             "and is never re-initialised.", "", *table(rows, round_trip=True)]
    lines += ["", f"Frames {', '.join(map(str, video.strip))} of the way out and the last of the way back: "
              f"{' (top) and '.join(r['run'] for r in pair)} (bottom), green where the run trusted its pose.", "",
              f"![the model at each run's pose on {video.title}](results/real_video_{video.key}.jpg)"]
    return {"sequence": str(repo / video.video), "camera": camera.to_dict(), "rows": rows}, lines


if __name__ == "__main__":
    main()
