"""``hybridpose fit --refine-on`` on real footage, measured against a reference it never trained on.

ViSP's videos of printed parts with plain CAD models (``--video``: its detection-tutorial cube, 261
frames; its stereo tea box's left camera, 121), each with a network ``hybridpose fit`` made for the part
at its defaults (``--fit KEY=FIT_DIR``): the fit's ``best.pt`` is copied into ``--out`` and refined there
as ``fit --refine-on VIDEO`` refines it — the hybrid from no initial pose labels the frames it holds
with confidence, the network trains on the earlier three quarters of them for ``--budget`` minutes (the
command's default) or until its loss on a tenth of them kept out stops improving (``--patience``: one
row for each value given; by default 0, training to the budget, and the command's default) and the last
quarter, a later stretch, is held back. Scored on that stretch before
and after against the ``combined`` track from the hand-labelled first pose (as
``megapose_no_pose.py`` scores; not the refinement's own labels): the network alone on every frame
(in a tracker's basin: ≤ 10° and ≤ 5 % of the distance, up to the part's symmetries), and the hybrid
from no initial pose started at the stretch's first frame (within 5° and 2 cm; trusted more than 10°
off). Writes ``results/refine_on_footage.json`` and the ``refine-on-footage`` block of ``RESULTS.md``::

    python benchmarks/refine_on_footage.py --visp-repo ../visp --fit detection_cube=runs/cube/fit,teabox_left=runs/teabox/fit
"""
from __future__ import annotations

import argparse
import shutil
import sys
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import environment, publish  # noqa: E402
from megapose_no_pose import reference_track, score_cnn, score_hybrid  # noqa: E402
from real_video import REPO_VIDEOS, repo_camera, repo_frames  # noqa: E402

VIDEO_KEYS = ("detection_cube", "teabox_left")  # long enough for 30 training frames before the held-back quarter


def refine_video(repo: Path, key: str, fit_dir: Path, out: Path, budget_min: float, tracker: str,
                 patiences: list[int]) -> list[dict]:
    """One video's rows, one per patience: the refinement's record and the before/after scores on its
    held-back stretch (the video decoded, its reference tracked and the fit scored once for all)."""
    from hybridpose.io import read_json
    from hybridpose.refine import refine_on_footage

    video = next(v for v in REPO_VIDEOS if v.key == key)
    frames, camera, model, pose0 = repo_frames(repo, video)
    obj = replace(model, texture=None, face_uv=None)  # the shape alone, as the plain CAD model gives it
    reference = reference_track(frames, obj, pose0)

    def scores(checkpoint: Path, cut: int) -> dict:
        held = [f for f in frames if f.index >= cut]
        return {"cnn": score_cnn(str(checkpoint), held, obj, reference, every=1),
                "hybrid": score_hybrid(str(checkpoint), held, obj, reference, tracker)}

    before, rows = {}, []  # the fit's scores by the first held-back frame (the same labelling gives the same)
    fit_cell, reference_frames = _fit_cell(fit_dir), sum(r is not None for r in reference)
    for patience in patiences:
        work = out / key / f"patience{patience}" / "fit"
        if not (work / "refine" / "refine.json").is_file():  # a run cut short starts its refinement over
            shutil.rmtree(work, ignore_errors=True)
            work.mkdir(parents=True)
            shutil.copy(fit_dir / "best.pt", work / "best.pt")
            if (fit_dir / "data" / "calib").is_dir():
                shutil.copytree(fit_dir / "data" / "calib", work / "data" / "calib")
            refine_on_footage(work, repo / video.video, obj, repo_camera(repo / video.camera), budget_min=budget_min,
                              tracker=tracker, patience=patience, progress=print)
        record = read_json(work / "refine" / "refine.json")
        cut = record["held_back_from"]
        if cut not in before:
            before[cut] = scores(fit_dir / "best.pt", cut)
        rows.append({"video": key, "fit": str(fit_dir), "fit_cell": fit_cell, "refine": record,
                     "reference_frames": reference_frames, "before": before[cut],
                     "after": scores(work / "refine" / "best.pt", cut)})
    return rows


def _fit_cell(fit_dir: Path) -> str:
    """What the fit was, from its ``fit.json`` (its folder where that is gone)."""
    from hybridpose.io import read_json

    path = Path(fit_dir) / "fit.json"
    if not path.is_file():
        return f"`{fit_dir}`"
    fit = read_json(path)
    return (f"{fit['request']['budget_min']:g}-minute fit, {fit['plan']['train_views']} views, "
            f"{fit.get('epochs_trained', '?')} epochs")


def _training_cell(rec: dict) -> str:
    why = (f"no better for {rec['patience_epochs']} epochs" if rec.get("stopped_early") else "the budget")
    bf16 = ", bfloat16" if rec.get("training_bf16") else ""
    return f"{rec.get('patience_epochs') or 'none'}; {rec['epochs_trained']}, {rec['minutes']['train']:.1f} ({why}{bf16})"


def _cnn_cell(c: dict) -> str:
    med = "—" if c["rot_median_deg"] is None else f"{c['rot_median_deg']:.1f}°"
    return f"{c['in_basin']} of {c['frames']} ({med})"


def _hybrid_cell(h: dict) -> str:
    first = "never" if h["first_pose"] is None else f"frame {h['first_pose']}"
    return f"{first}; {h['held']} of {h['frames']}; {h['wrong']}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--visp-repo", required=True, help="a checkout of github.com/lagadic/visp")
    ap.add_argument("--fit", required=True,
                    help="VIDEO=FIT_DIR[,VIDEO=FIT_DIR...]: a `hybridpose fit` folder for each video's part "
                         f"(videos: {', '.join(VIDEO_KEYS)})")
    ap.add_argument("--budget", type=float, default=None, help="minutes of refinement (default: the command's)")
    ap.add_argument("--patience", default=None,
                    help="EPOCHS[,EPOCHS...]: one row each, the training stopped after that many epochs without "
                         "a better loss on its kept-out frames (0: trains to the budget; default: 0 and the command's)")
    ap.add_argument("--tracker", default="combined", help="the tracker that labels the frames (default combined)")
    ap.add_argument("--out", default="runs/refine_on_footage", help="where the copied fits are refined")
    args = ap.parse_args(argv)
    from hybridpose.refine import DEFAULT_BUDGET_MIN, PATIENCE_EPOCHS
    from hybridpose.threads import set_threads

    fits = dict(item.split("=", 1) for item in args.fit.split(","))
    unknown = sorted(set(fits) - set(VIDEO_KEYS))
    if unknown:
        raise SystemExit(f"--fit: unknown video(s) {unknown}; expected any of {list(VIDEO_KEYS)}")
    missing = [d for d in fits.values() if not (Path(d) / "best.pt").is_file()]
    if missing:
        raise SystemExit(f"--fit: no best.pt in {missing} (a `hybridpose fit` folder)")
    set_threads(1)
    budget = DEFAULT_BUDGET_MIN if args.budget is None else args.budget
    try:
        patiences = ([0, PATIENCE_EPOCHS] if args.patience is None
                     else [int(p) for p in str(args.patience).split(",")])
    except ValueError:
        raise SystemExit(f"--patience: expected whole numbers of epochs, comma-separated, got {args.patience!r}") from None
    rows = [row for key, d in fits.items()
            for row in refine_video(Path(args.visp_repo), key, Path(d), Path(args.out), budget, args.tracker, patiences)]
    lines = [f"`hybridpose fit --refine-on` from no initial pose on ViSP's real videos (`python "
             f"benchmarks/refine_on_footage.py`, commit `{environment()['git']}`, {budget:g} minutes of refinement, "
             f"`{args.tracker}` labelling): scored on the held-back last quarter of the tracked frames against the "
             "`combined` track from the hand-labelled first pose. Nothing was tuned on these figures.", "",
             "| video | the fit refined | frames trained on / held back (from frame) | training: patience (epochs); "
             "epochs, minutes (stopped by) | "
             "network alone on the held-back frames, in a tracker's basin (rotation median): before → after | "
             "hybrid from no initial pose over them (first pose; within 5° and 2 cm of the scored; trusted > 10° off): "
             "before → after |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        rec, b, a = r["refine"], r["before"], r["after"]
        lines.append(f"| {r['video']} | {r['fit_cell']} | {rec['train_frames']} / {rec['held_back_frames']} "
                     f"({rec['held_back_from']}) | {_training_cell(rec)} | {_cnn_cell(b['cnn'])} → {_cnn_cell(a['cnn'])} | "
                     f"{_hybrid_cell(b['hybrid'])} → {_hybrid_cell(a['hybrid'])} |")
    uncalibrated = [r["video"] for r in rows if r["refine"].get("calibration_skipped")]
    if uncalibrated:
        lines += ["", f"Not re-calibrated after refining (the fit folder kept no calibration renders, `data/calib`): "
                      f"{', '.join(uncalibrated)} — the refined network's covariance is its training's."]
    publish("refine_on_footage", "refine-on-footage", {"environment": environment(), "budget_min": budget,
                                                       "rows": rows}, lines)


if __name__ == "__main__":
    main()
