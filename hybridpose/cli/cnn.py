"""The CNN regressor's commands: ``train``, ``train-verifier``, ``calibrate``, ``quantize``, ``eval``,
``compare``, ``export``."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from .common import progress


def cmd_train(args) -> int:
    from ..training.train import add_train_arguments, run

    p = argparse.ArgumentParser(prog="hybridpose train", description="train a CNN pose regressor on a rendered "
                                "dataset (checkpoints, --resume)")
    add_train_arguments(p)
    train_args = p.parse_args(args.train_args)
    train_args.verbose, train_args.command = args.verbose, args.command
    return run(train_args)


def cmd_train_verifier(args) -> int:
    from ..datasets.bop import dataset_object
    from ..training.train_verifier import (
        build_pairs,
        check_estimators,
        estimator_folders,
        train_verifier,
    )

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


def cmd_calibrate(args) -> int:
    from ..regressors.checkpoints import checkpoint_or_shipped
    from ..training.evaluate import calibrate_checkpoint

    cal = calibrate_checkpoint(checkpoint_or_shipped(args.checkpoint), args.data, args.out, limit=args.limit, progress=progress("calibrate"),
                               coverage=args.coverage, by_quality=not args.single_scale)
    fp = cal["full_path"]
    print(f"calibrate: {fp['poses']} poses on {args.data}: {fp['inside_share_before']:.0%} were inside the "
          f"{fp['coverage']:.0%} ellipsoid; covariance ×{fp['factor']:.3f} → {args.out}")
    bands = cal.get("quality_scale")
    if bands:
        print("  then by quality band: " + ", ".join(f"≥ {e:.1f}: ×{f:.3g} ({n} poses)" for e, f, n in
                                                     zip(bands["edges"], bands["factors"], bands["poses"])))
    from ..regressors.int8_file import stale_int8

    beside = stale_int8(args.out)  # e.g. --out the checkpoint itself: its 8-bit model was made from the file before
    if beside is not None:
        print(f"calibrate: {beside} was not made from {args.out} (engine='auto' now runs the float network); "
              f"run hybridpose quantize --checkpoint {args.out} --data DIR again")
    return 0


def cmd_quantize(args) -> int:
    from ..training.quantize import quantize_checkpoint

    rec = quantize_checkpoint(args.checkpoint, args.data, args.out, crops=args.crops, progress=progress("quantize"))
    print(f"quantize: {rec['checkpoint']} calibrated on {rec['crops']} crops of {args.data} → {rec['path']} "
          f"(use it with engine='onnxruntime-int8')")
    return 0


def cmd_eval(args) -> int:
    from ..regressors.checkpoints import checkpoint_or_shipped
    from ..training.evaluate import evaluate_checkpoint

    s = evaluate_checkpoint(checkpoint_or_shipped(args.checkpoint), args.data, args.out, limit=args.limit, progress=progress("eval"),
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
    from ..io import atomic_write_json
    from ..training.compare import compare_reports, comparison_markdown

    if len(args.reports) % 2:
        raise ValueError("reports: expected pairs, A B [A2 B2 ...] (model A's and model B's report on each test "
                         f"set), got {len(args.reports)} paths")
    c = compare_reports(args.reports[0::2], args.reports[1::2], gross_deg=args.gross_deg)
    text = comparison_markdown(c)
    if args.out:
        atomic_write_json(Path(args.out), c)
    print(text, end="")
    return 0


def cmd_export(args) -> int:
    from ..regressors.checkpoints import export_checkpoint

    ck = export_checkpoint(args.checkpoint, args.out)
    print(f"export: {ck['config']['model']} (epoch {ck.get('epoch')}) → {args.out} "
          f"({Path(args.out).stat().st_size / 2**20:.1f} MB, calibration {'yes' if 'calibration' in ck else 'NO'})")
    return 0


def add_commands(sub) -> None:
    """Add this module's subcommands to the ``hybridpose`` parser's ``sub``."""
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
