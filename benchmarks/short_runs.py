"""Every regressor backend, one short real training run on this CPU, evaluated on the held-out test set.

The paper's VGG models at 224 px take ≈ 0.7–1.1 s per training image on 2 CPU cores (VGG-16 …
Parallel VGG-19), so a 100-epoch run is GPU work (``benchmarks/gpu/``). This gives every backend the
same short budget here, from scratch (nothing is downloaded: no ImageNet weights), through the
commands a user runs (``hybridpose train`` with ``--time-limit``, then ``hybridpose eval``), and puts
the result beside a constant-pose reference — what a network that ignores the image would score.
The table says how far a few CPU-minutes get each model, honestly, not what the models can do
after a full run; and, at equal minutes, how much faster the keypoint models learn than the VGGs.

Usage:
    common="--object truss --kind random --size 640x480 --in-view --sun-cone 40 --sun-range 0.7,1.3 --workers 2"
    hybridpose render $common --count 1000 --seed 30 --out data/truss_short30
    python benchmarks/short_runs.py --train-data data/truss_short30 --test-data data/truss_test100 \
        [--minutes 12] [--limit 1000] [--runs runs/short] [--models vgg16 default ...]

Resumes: a model whose run finished is not trained again, one whose evaluation is stored is not
evaluated again (``<runs>/<model>/``). The table holds every model finished in ``--runs`` (several
invocations add up). Writes ``results/short_runs.json`` and the "short-runs" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from _common import environment, update_results_md, write_json
from hybridpose.machine import cpu_label
from hybridpose.datasets.bop import BopScene, find_scenes
from hybridpose.io import atomic_write_json
from hybridpose.training.eval_report import GROSS_ERROR_DEG, PAPER
from hybridpose.training.evaluate import evaluate_checkpoint
from hybridpose.regressors.models import available_models, model_kind
from hybridpose.training.train import add_train_arguments, config_from_args, train

MODELS = ("vgg16", "vgg19", "branched-vgg19", "parallel-vgg19", "default", "keypoints")
PAPER_NAME = {"vgg16": "VGG-16", "vgg19": "VGG-19", "branched-vgg19": "Branched VGG-19",
              "parallel-vgg19": "Parallel VGG-19"}
VGG_BATCH = 8
VGG_EPOCH_BATCHES = 20   # ≈ 2–3 min epochs, so the time limit (checked between epochs) is kept closely
VAL_FRACTION = 0.05


def train_arguments(model: str, args) -> list[str]:
    """The ``hybridpose train`` arguments of one short run (no early stop, a constant learning rate:
    a cosine over an unknown number of epochs would not decay anyway)."""
    argv = ["--model", model, "--data", args.train_data, "--out", str(Path(args.runs) / model), "--epochs", "1000",
            "--val-fraction", str(VAL_FRACTION), "--patience", "0", "--schedule", "constant",
            "--time-limit", f"{args.minutes:g}"]
    if model_kind(model) == "direct":
        argv += ["--batch", str(VGG_BATCH), "--max-batches", str(VGG_EPOCH_BATCHES)]
    return argv


def _labels(root) -> list:
    return [sc.image(i).pose for sc in (BopScene(p) for p in find_scenes(root)) for i in sc.image_ids]


def constant_pose_reference(train_root, test_root, limit: int | None) -> dict:
    """Errors on the test views of one pose for all: the training labels' mean translation and
    their rotation mean (scipy's chordal mean) — the score of a network that ignores the image."""
    poses, test = _labels(train_root), _labels(test_root)[:limit]
    if not poses or not test:
        raise ValueError(f"train_data / test_data: {train_root} has {len(poses)} views, {test_root} {len(test)}")
    t = np.mean([p.t for p in poses], axis=0)
    R = Rotation.from_matrix(np.stack([p.R for p in poses])).mean()
    rot = np.array([np.degrees((R.inv() * Rotation.from_matrix(p.R)).magnitude()) for p in test])
    trans = np.array([np.linalg.norm(p.t - t) for p in test])
    return {"rot_mean_deg": float(rot.mean()), "rot_median_deg": float(np.median(rot)),
            "trans_mean_m": float(trans.mean()), "trans_median_m": float(np.median(trans)),
            "gross_error_share": float(np.mean(rot > GROSS_ERROR_DEG)), "images": len(test), "train_views": len(poses)}


def run_model(model: str, args) -> dict:
    out = Path(args.runs) / model
    done, evaluated = out / "finished.json", out / "eval.json"
    if not done.exists():
        argv = train_arguments(model, args)
        parser = argparse.ArgumentParser()
        add_train_arguments(parser)
        cfg = config_from_args(parser.parse_args(argv))
        train(cfg, resume=(out / "last.pt").exists(), progress=False)
        history = json.loads((out / "history.json").read_text())
        best = min(history, key=lambda r: r["val_loss"])
        # histories written before train() counted its images had only the VGG runs' capped epochs
        seen = sum(r.get("train_images", VGG_EPOCH_BATCHES * VGG_BATCH) for r in history)
        atomic_write_json(done, {"command": "hybridpose train " + " ".join(argv), "epochs": len(history),
                                 "images_seen": seen,
                                 "train_min": sum(r["epoch_s"] for r in history) / 60,
                                 "val_rot_mean_deg": best["rot_mean_deg"], "val_trans_mean_m": best["trans_mean_m"]})
        (out / "last.pt").unlink(missing_ok=True)   # optimizer state: gigabytes, not needed to evaluate
    if not evaluated.exists():
        with tempfile.TemporaryDirectory() as tmp:
            s = evaluate_checkpoint(out / "best.pt", args.test_data, tmp, limit=args.limit, timing_images=20,
                                    gradcam_count=2)
        atomic_write_json(evaluated, {k: v for k, v in s.items() if not k.startswith("error_vs")})
    trained = {"command": "hybridpose train " + " ".join(train_arguments(model, args)), **json.loads(done.read_text())}
    return {"train": trained, "eval": json.loads(evaluated.read_text())}


def markdown(results: dict, reference: dict, args, env: dict) -> str:
    lines = [
        "## Every backend, one short run on this CPU (`python benchmarks/short_runs.py`)",
        "",
        f"Each model trained from scratch (no ImageNet weights: nothing is downloaded) for ≈ {args.minutes:g} minutes "
        f"on 2 CPU cores on the {reference['train_views']} views of `{args.train_data}` (5 % held out for validation), "
        f"then `hybridpose eval` on the first {reference['images']} views of `{args.test_data}` (full frame, no roi; the "
        "parallel model crops around its own translation, the keypoint models run their whole shipped path). "
        f"VGG models at 224 px, batch {VGG_BATCH}, epochs capped at {VGG_EPOCH_BATCHES} batches, Adam 1e-4 "
        "(the paper's loss, β = 10); keypoint models at their own crop size (128 / 160 px), batch 32, Adam 1e-3: "
        "each row's exact command is in `results/short_runs.json`. *Constant pose*: the training labels' mean "
        "translation and mean rotation for every view — a network that ignores the image. The paper's rows: "
        "100 epochs on a GPU from ImageNet weights, on their data. So these runs say that every backend trains and "
        "evaluates end to end here, and how far equal CPU-minutes get each — not what the models reach after "
        "a full run (the shipped `default` took ≈ 6 h of this CPU: table above). "
        f"git {env['git']}, {cpu_label(env)}.",
        "",
        "| model | where, how long | images seen | val rot ° | mean rot ° | median rot ° | mean trans m | > 30° | ms/img 1 thr | ms/img 2 thr |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, row in results.items():
        p = PAPER.get(PAPER_NAME.get(name, ""))
        if p:
            lines.append(f"| paper: {PAPER_NAME[name]} | GPU, 100 epochs, ImageNet | – | – | {p[0]:.2f} | {p[1]:.2f} | "
                         f"{p[2]:.2f} | – | – | – |")
        tr, ev = row["train"], row["eval"]
        ms = ev.get("ms_per_image", {})
        lines.append(f"| **{name}** | this CPU, {tr['train_min']:.0f} min, from scratch | {tr['images_seen']} | "
                     f"{tr['val_rot_mean_deg']:.1f} | {ev['rot_mean_deg']:.1f} | {ev['rot_median_deg']:.1f} | "
                     f"{ev['trans_mean_m']:.3f} | {100 * ev['gross_error_share']:.0f}% | "
                     f"{ms.get('1_thread', float('nan')):.0f} | {ms.get('2_threads', float('nan')):.0f} |")
    r = reference
    lines.append(f"| constant pose (reference) | – | – | – | {r['rot_mean_deg']:.1f} | {r['rot_median_deg']:.1f} | "
                 f"{r['trans_mean_m']:.3f} | {100 * r['gross_error_share']:.0f}% | – | – |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--train-data", required=True)
    ap.add_argument("--test-data", required=True)
    ap.add_argument("--minutes", type=float, default=12.0, help="training budget per model")
    ap.add_argument("--limit", type=int, default=1000, help="test views")
    ap.add_argument("--runs", default="runs/short")
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=[m for m in MODELS if m in available_models()])
    args = ap.parse_args()
    reference = constant_pose_reference(args.train_data, args.test_data, args.limit)
    print("constant pose", reference)
    for model in args.models:
        print(model, run_model(model, args))
    # every model finished in --runs, also by earlier invocations, in a fixed order
    results = {m: run_model(m, args) for m in MODELS if (Path(args.runs) / m / "eval.json").exists()}
    env = environment()
    write_json("short_runs", {"env": env, "train_data": args.train_data, "test_data": args.test_data,
                              "minutes": args.minutes, "reference": reference, "results": results})
    update_results_md("short-runs", markdown(results, reference, args, env))


if __name__ == "__main__":
    main()
