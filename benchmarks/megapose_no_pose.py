"""The hybrid from no initial pose on real footage: ViSP's MegaPose cube video (a printed 8.45-cm cube
turned by hand on a cluttered desk, 640 × 480 RGB; ViSP's repository, ``tutorial/tracking/dnn/data``),
or with ``--video detection_cube`` its detection tutorial's cube video (its printed cube, a plain CAD
model), or ``--video teabox`` / ``teabox_left`` its model-based tutorials' tea box (a printed box, its
plain ``teabox.cao``), with networks fitted to the part by ``hybridpose fit`` on this CPU::

    # PHOTOS: scikit-image's sample photos (benchmarks/own_object.py, training_photos); cam.json: the
    # video's camera (megapose_cube.json's intrinsics and image size)
    hybridpose fit VISP/tutorial/tracking/dnn/data/models/cube/cube.obj --camera cam.json --budget 20m \\
        --backgrounds PHOTOS --out runs/mp_fit
    python benchmarks/megapose_no_pose.py --visp-repo VISP --regressor plain=runs/mp_fit/best.pt,...

Each network (``NAME=CHECKPOINT``, one row each) runs alone on every 5th frame and inside the hybrid
(``combined`` + ``isam2``, defaults, no initial pose) over the frames ``real_video.py`` tracks out and
back (the MegaPose video's first 590, the detection cube's 261). No true pose exists: the reference is
the ``combined`` tracker alone from the hand-labelled first pose (``data/<video>.0.pos``), which ends
its round trip over the same frames within a few degrees and millimetres of where it started
(``real_video.py``), on the frames where the same tracker from
starts a hand label cannot tell from it agrees with it (:func:`reference_track`). Scored up to the cube's symmetries (its shape
is a cube): the hybrid's trusted frames within 5° and 2 cm of the reference, those more than 10° off,
its first pose; the CNN's frames within a tracker's basin (10°, 5 % of the distance). And scored
exactly: the hybrid's frames within 5° and 2 cm of the reference itself, the printed cube's own pose
(which face is which: the labelled first pose is the one its print shows). Writes
``results/megapose_no_pose.json`` and the ``megapose-no-pose`` block of ``RESULTS.md`` (the detection
cube: ``detection_cube_no_pose``, ``detection-cube-no-pose``); the table also gives the median edge
distance (px) of the hybrid's trusted frames. Each network's hybrid runs on the cube's shape alone
(its print stripped, as a plain CAD model gives it) and, where the video's model carries its print
(ViSP's MegaPose ``cube.obj`` beside its ``.mtl``; ``--mesh`` names another), on the printed model: the
hybrid then checks its starts against the print, starts at the pose the print shows, and its keypoint
memory holds the print from the first frame (the memory alone, the print's keypoints with nothing
learned, is scored as the network is). ``--memory on,off`` runs each hybrid with and without its
keypoint memory (``HybridConfig.keypoint_memory``).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import environment, publish  # noqa: E402
from real_video import REPO_VIDEOS, repo_frames  # noqa: E402

HELD_DEG, HELD_M, WRONG_DEG = 5.0, 0.02, 10.0
# each video: its results block, and what was tuned on it
VIDEOS = {"megapose_cube": ("megapose-no-pose", "The start checks' thresholds were set on this video "
                                                "(`docs/decisions.md`): development figures, not held-out ones."),
          "detection_cube": ("detection-cube-no-pose", "No start check was tuned on this video (the trackers were "
                                                       "developed on it too)."),
          "teabox": ("teabox-no-pose", "The start rules for plain surroundings (`plain_surround_quality`, "
                                       "`start_alternatives`) were developed on this video (`docs/decisions.md`): "
                                       "development figures."),
          "teabox_left": ("teabox-left-no-pose", "Nothing was tuned on this video.")}
CNN_EVERY = 5


REF_AGREE_DEG, REF_AGREE_M = 2.0, 0.005
# starts as far from the label as a label is good to: 0.2° about a camera axis, 0.5 mm across
LABEL_NUDGES = (((0.2, 0.0, 0.0), (0.0005, 0.0, 0.0)), ((0.0, -0.2, 0.0), (0.0, -0.0005, 0.0)))


def reference_track(frames, obj, pose0) -> list:
    """The ``combined`` tracker alone from ``pose0``: its pose per frame, None where it is lost or where
    the same tracker started from ``pose0`` nudged as far as a hand label is good to (``LABEL_NUDGES``)
    ends more than ``REF_AGREE_DEG`` or ``REF_AGREE_M`` away from it, up to the symmetries: on the
    MegaPose video, where the cube faces the camera square-on and a mug passes, tracks from starts a
    label cannot tell apart part ways by up to 18°, and a frame where they do has no reference to
    score against."""
    from hybridpose.geometry import Pose, rotvec_to_matrix
    from hybridpose.metrics import nearest_equivalent
    from hybridpose.registry import create

    def track(start):
        tracker = create("tracker", "combined", object=obj)
        tracker.init(frames[0], start)
        return [m.pose for m in (tracker.track(f) for f in frames)]

    reference = track(pose0)
    for turn_deg, shift_m in LABEL_NUDGES:
        nudged = Pose(rotvec_to_matrix(np.radians(turn_deg)) @ pose0.R, pose0.t + np.asarray(shift_m))
        for k, (ref, other) in enumerate(zip(reference, track(nudged))):
            if ref is not None and (other is None or not _within(other, nearest_equivalent(other, ref, obj.symmetries),
                                                                 REF_AGREE_DEG, REF_AGREE_M)):
                reference[k] = None
    return reference


def _within(pose, truth, deg: float, metres: float) -> bool:
    """Whether ``pose`` lies within ``deg`` and ``metres`` of ``truth``."""
    from hybridpose.metrics import rotation_error_deg

    return bool(rotation_error_deg(pose, truth) <= deg and np.linalg.norm(pose.t - truth.t) <= metres)


def score_cnn(regressor, frames, obj, reference, every: int = CNN_EVERY) -> dict:
    """The fitted network (a checkpoint; or any ``predict(frame)`` giving a Measurement or None) alone on
    every ``every``-th frame with a reference: frames in a tracker's basin."""
    from hybridpose.bench.modes import BASIN_DEG, BASIN_PCT
    from hybridpose.metrics import nearest_equivalent, rotation_error_deg
    from hybridpose.registry import create_regressor

    predict = create_regressor(regressor, object=obj).predict if isinstance(regressor, str) else regressor
    sampled = [f for f in frames[::every] if reference[f.index] is not None]
    inside, rot = 0, []
    for frame in sampled:
        m, ref = predict(frame), reference[frame.index]
        if m is None or m.pose is None:
            continue
        truth = nearest_equivalent(m.pose, ref, obj.symmetries)
        rot.append(rotation_error_deg(m.pose, truth))
        inside += rot[-1] <= BASIN_DEG and 100 * np.linalg.norm(m.pose.t - truth.t) / np.linalg.norm(truth.t) <= BASIN_PCT
    return {"frames": len(sampled), "in_basin": int(inside), "rot_median_deg": float(np.median(rot)) if rot else None}


def score_memory(frames, obj, reference) -> dict | None:
    """The keypoint memory of a printed ``obj`` (its print alone, nothing learned) on every
    ``CNN_EVERY``-th frame with a reference, as :func:`score_cnn` scores the network; None for a plain part."""
    from hybridpose.edges import ModelView
    from hybridpose.edges.print_match import PrintView
    from hybridpose.regressors.keypoint_memory import KeypointMemory

    if obj.texture is None:
        return None
    memory = KeypointMemory.from_print(PrintView(ModelView(obj)), frames[0].camera)
    return score_cnn(memory.find, frames, obj, reference)


def score_hybrid(regressor: str, frames, obj, reference, tracker: str = "combined", memory: bool = True,
                 config: dict | None = None) -> dict:
    """The hybrid (``tracker`` + the fitted network + isam2; with its keypoint memory or not; ``config``:
    more :class:`HybridConfig` fields changed) from no initial pose over ``frames``, against ``reference``."""
    from hybridpose.edges import ModelView
    from hybridpose.edges.image_distance import edge_distances_px
    from hybridpose.estimator import HybridEstimator
    from hybridpose.metrics import nearest_equivalent, rotation_error_deg

    est = HybridEstimator.from_names(object=obj, tracker=tracker, regressor=regressor, fusion="isam2",
                                     config={**(config or {}), **({} if memory else {"keypoint_memory": False})})
    view = ModelView(obj)
    held = wrong = trusted = exact = 0
    first, ms, scored, edge_px = None, [], 0, []
    for frame in frames:
        t0 = time.perf_counter()
        e = est.step(frame)
        ms.append(1000 * (time.perf_counter() - t0))
        ref = reference[frame.index]
        scored += ref is not None
        if e.pose is None or e.status not in ("tracking", "init", "reinit"):
            continue
        trusted += 1
        first = frame.index if first is None else first
        d = edge_distances_px(view, frame, e.pose)
        if len(d):
            edge_px.append(float(np.median(d)))
        if ref is None:
            continue
        truth = nearest_equivalent(e.pose, ref, obj.symmetries)
        held += _within(e.pose, truth, HELD_DEG, HELD_M)
        wrong += rotation_error_deg(e.pose, truth) > WRONG_DEG
        # the printed cube's own pose: which face is which (the reference's first pose shows its print)
        exact += _within(e.pose, ref, HELD_DEG, HELD_M)
    return {"frames": scored, "all_frames": len(frames), "first_pose": first, "trusted": trusted, "held": int(held), "wrong": int(wrong),
            "held_exact": int(exact), "edge_px_median": float(np.median(edge_px)) if edge_px else None,
            "ms_per_frame": float(np.mean(ms))}


def _after_first(h: dict) -> str:
    """The trusted frames' share of the frames from the hybrid's first pose on (`` (95 %)``)."""
    if h["first_pose"] is None:
        return ""
    return f" ({100 * h['trusted'] / (h['all_frames'] - h['first_pose']):.0f} %)"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--visp-repo", required=True, help="a checkout of github.com/lagadic/visp")
    ap.add_argument("--regressor", required=True, help="NAME=CHECKPOINT[,NAME=CHECKPOINT...]: fitted networks, one row each")
    ap.add_argument("--video", choices=tuple(VIDEOS), default="megapose_cube",
                    help="megapose_cube (default): a printed cube turned by hand in clutter; detection_cube: ViSP's "
                         "printed cube beside a tube, a hand reaching in (its CAD model plain, as a user's often is); "
                         "teabox, teabox_left: a printed tea box on a table, its CAD model plain")
    ap.add_argument("--trackers", default="combined",
                    help="the hybrid's trackers, one row each (default combined, what `hybridpose track` takes on "
                         "these lit scenes; edges: the space tracker, which it takes on black space)")
    ap.add_argument("--memory", default="on",
                    help="the hybrid's keypoint memory, one row each: on (default), off, or on,off")
    ap.add_argument("--mesh", default=None,
                    help="the cube's mesh with its print (an OBJ beside a .mtl naming its image) where the video's "
                         "own model carries none: each network's hybrid runs again with it, its starts checked "
                         "against the print (the MegaPose cube's model carries its print)")
    args = ap.parse_args(argv)
    from hybridpose.objects import load_object
    from hybridpose.threads import set_threads

    set_threads(1)
    networks = dict(item.split("=", 1) for item in args.regressor.split(","))
    trackers = [t.strip() for t in args.trackers.split(",") if t.strip()]
    memories = [{"on": True, "off": False}[m.strip()] for m in args.memory.split(",") if m.strip()]
    video = next(v for v in REPO_VIDEOS if v.key == args.video)
    block, tuned = VIDEOS[args.video]
    frames, camera, model, pose0 = repo_frames(Path(args.visp_repo), video)
    obj = replace(model, texture=None, face_uv=None)  # the shape alone, as a plain CAD model gives it
    reference = reference_track(frames, obj, pose0)
    printed = load_object(args.mesh) if args.mesh is not None else (model if model.texture is not None else None)
    if printed is not None and printed.texture is None:
        raise SystemExit(f"--mesh: {args.mesh} carries no print (an OBJ needs its .mtl naming the image)")
    memory_alone = score_memory(frames, printed, reference) if printed is not None else None
    rows = []
    for name, path in networks.items():
        cnn = score_cnn(path, frames, obj, reference)
        for label, part in (("shape", obj), ("print", printed)):
            if part is None:
                continue
            for tracker in trackers:
                for memory in memories:
                    row = {"network": name, "checkpoint": path, "mesh": label, "tracker": tracker, "memory": memory,
                           "cnn": cnn, "memory_alone": memory_alone if label == "print" else None,
                           "hybrid": score_hybrid(path, frames, part, reference, tracker, memory)}
                    rows.append(row)
                    print(name, label, tracker, memory, row, flush=True)
    lines = [f"{video.title}, its first {len(frames)} frames, from no initial pose "
             f"(`python benchmarks/megapose_no_pose.py{'' if args.video == 'megapose_cube' else ' --video ' + args.video}`, commit `{environment()['git']}`, one thread): the hybrid "
             f"(`{'`, `'.join(trackers)}` + `isam2`, defaults) with each fitted network, scored up to the part's symmetries against "
             "the `combined` track from the hand-labelled first pose, on the "
             f"{sum(r is not None for r in reference)} frames where the same tracker from two starts 0.2° and 0.5 mm "
             f"from it agrees with it within {REF_AGREE_DEG:g}° and {1000 * REF_AGREE_M:g} mm. {tuned}", "",
             "| network | tracker | the hybrid's model | keypoint memory | CNN alone: in a tracker's basin (rotation median) | "
             "memory alone, the print's: in a tracker's basin | hybrid: first pose | "
             f"trusted frames (of {len(frames)}; from the first pose on) | within {HELD_DEG:g}° and {100 * HELD_M:g} cm | …of its own pose (which face is which) | "
             f"trusted > {WRONG_DEG:g}° off | edge px (median of trusted frames) | ms/frame |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        c, h, k = r["cnn"], r["hybrid"], r["memory_alone"]
        med = "—" if c["rot_median_deg"] is None else f"{c['rot_median_deg']:.0f}°"
        alone = "—" if k is None else f"{k['in_basin']} of {k['frames']}"
        model = "shape and print (starts checked against the print)" if r["mesh"] == "print" else "shape"
        lines.append(f"| {r['network']} | {r['tracker']} | {model} | {'on' if r['memory'] else 'off'} | "
                     f"{c['in_basin']} of {c['frames']} ({med}) | {alone} | "
                     f"{'never' if h['first_pose'] is None else 'frame ' + str(h['first_pose'])} | {h['trusted']}{_after_first(h)} | "
                     f"{h['held']} of {h['frames']} ({100 * h['held'] / h['frames']:.0f} %) | {h['held_exact'] if r['mesh'] == 'print' else '—'} | {h['wrong']} | "
                     f"{'—' if h['edge_px_median'] is None else format(h['edge_px_median'], '.2f')} | {h['ms_per_frame']:.0f} |")
    publish(block.replace("-", "_"), block, {"environment": environment(), "video": video.key, "rows": rows}, lines)


if __name__ == "__main__":
    main()
