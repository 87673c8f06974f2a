"""The paper's four VGG models trained on a lent GPU, beside the paper's table.

Usage (after a lease of ``train_on_gpu.sh start-vgg`` / ``wait-vgg`` brought back ``vgg_runs.tgz``):
    mkdir -p runs/gpu30 && tar -C runs/gpu30 -xzf vgg_runs.tgz
    python benchmarks/gpu/vgg_runs.py --runs runs/gpu30 --note "..."
    # the parallel model alone, two runs (folders parallel-vgg19 and pv_seed1), its own section
    python benchmarks/gpu/vgg_runs.py --runs runs/gpu34 --run parallel-vgg19 --run pv_seed1:parallel-vgg19 \
        --section gpu-vgg-100-epochs --name gpu_vgg_100_epochs --title "..." --note "..."

Reads each model's ``metrics.csv`` (validation per epoch: the 5 % held out of the training views,
the parallel model's rotation stream fed the crop around the true box) and its ``hybridpose eval``
reports on the test set (``<model>_eval``: the inference path, no roi; ``<model>_eval_roi``, where
present: ``--roi truth``), writes ``benchmarks/results/gpu_vgg_runs.json``, copies the plots there
and writes the "gpu-vgg-runs" section of RESULTS.md.
"""
from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import BENCH_DIR, update_results_md, write_json  # noqa: E402
from hybridpose.training.eval_report import PAPER  # noqa: E402

MODELS = ("vgg16", "vgg19", "branched-vgg19", "parallel-vgg19")
PAPER_NAMES = {"vgg16": "VGG-16", "vgg19": "VGG-19", "branched-vgg19": "Branched VGG-19", "parallel-vgg19": "Parallel VGG-19"}
TITLE = "The paper's VGG models on a lent GPU (`python benchmarks/gpu/vgg_runs.py`)"
SUMMARY_KEYS = ("images", "device", "machine", "rot_mean_deg", "rot_median_deg", "trans_mean_m", "speed_score",
                "add_0.1d_recall", "gross_error_share", "failures", "ms_per_image", "covariance_check")


def read_run(runs: Path, model: str, folder: str | None = None) -> dict:
    """One run's validation history and test-set summary (absent parts are left out, not invented):
    ``folder`` (default ``model``) holds its ``metrics.csv``, ``<folder>_eval`` and ``<folder>_eval_roi`` its reports."""
    folder = folder or model
    run: dict = {"model": model, "run": folder}
    metrics = runs / folder / "metrics.csv"
    if metrics.exists():
        with metrics.open() as f:
            rows = [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]
        best = min(rows, key=lambda r: r["val_loss"])
        run.update(epochs=len(rows), epoch_s_mean=sum(r["epoch_s"] for r in rows) / len(rows),
                   train_images=int(rows[-1]["train_images"]), val_best=best, val_last=rows[-1], history=rows)
    for key, sub in (("test", f"{folder}_eval"), ("test_roi", f"{folder}_eval_roi")):
        report = runs / sub / "report.json"
        if report.exists():
            r = json.loads(report.read_text())["summary"]
            run[key] = {k: r[k] for k in SUMMARY_KEYS if k in r}
            run["test_data"] = r.get("data")
    return run


def fmt(x, spec: str) -> str:
    return "–" if x is None else format(x, spec)


def roi_cell(t: dict | None) -> str:
    return "–" if not t else f"{t['rot_mean_deg']:.2f} / {t['rot_median_deg']:.2f} / {t['trans_mean_m']:.3f}"


def markdown(runs: list[dict], note: str, title: str = TITLE) -> str:
    lines = [f"## {title}", "", note, "",
             "| model | epochs × s | val: mean / median rot °, mean trans m (best epoch) | "
             "test: mean rot ° | median rot ° | mean trans m | SPEED | ADD-0.1d | > 30° | ms/img (GPU) | "
             "test, true box as roi: mean / median rot °, mean trans m |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for i, run in enumerate(runs):
        name = PAPER_NAMES[run["model"]]
        p = PAPER[name]
        if i == 0 or runs[i - 1]["model"] != run["model"]:
            lines.append(f"| paper: {name} (their data, GPU, 100 epochs, ImageNet) | 100 | – | {p[0]:.2f} | {p[1]:.2f} | "
                         f"{p[2]:.2f} | – | – | – | – | – |")
        label = run["model"] if run["run"] == run["model"] else f"{run['model']} (`{run['run']}`)"
        v, t = run.get("val_best"), run.get("test", {})
        val = (f"{v['rot_mean_deg']:.1f} / {v['rot_median_deg']:.1f} / {v['trans_mean_m']:.3f} (epoch {int(v['epoch'])})"
               if v else "–")
        ms = t.get("ms_per_image", {}).get("1_thread")
        lines.append(f"| **{label}** | {run.get('epochs', '–')} × {fmt(run.get('epoch_s_mean'), '.0f')} | {val} | "
                     f"{fmt(t.get('rot_mean_deg'), '.2f')} | {fmt(t.get('rot_median_deg'), '.2f')} | "
                     f"{fmt(t.get('trans_mean_m'), '.3f')} | {fmt(t.get('speed_score'), '.3f')} | "
                     f"{fmt(t.get('add_0.1d_recall'), '.2f')} | {fmt(t.get('gross_error_share'), '.1%')} | "
                     f"{fmt(ms, '.1f')} | {roi_cell(run.get('test_roi'))} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", required=True, help="folder vgg_runs.tgz was unpacked into")
    ap.add_argument("--run", action="append", metavar="FOLDER[:MODEL]",
                    help="a run folder under --runs (and its model, when the folder is not named after it); "
                         "default: the four models' folders")
    ap.add_argument("--note", default="", help="what ran where (Markdown), written above the table")
    ap.add_argument("--title", default=TITLE)
    ap.add_argument("--section", default="gpu-vgg-runs", help="RESULTS.md section to write")
    ap.add_argument("--name", default="gpu_vgg_runs", help="results/<name>.json, and the plots' prefix")
    args = ap.parse_args()
    specs = [(r.split(":")[0], (r.split(":") + [r])[1]) for r in args.run] if args.run else [(m, m) for m in MODELS]
    for folder, model in specs:
        if model not in MODELS:
            raise SystemExit(f"--run {folder}:{model}: expected a model in {MODELS}")
    runs = [read_run(Path(args.runs), model, folder) for folder, model in specs]
    if not any("epochs" in r for r in runs):
        raise SystemExit(f"--runs: no <run>/metrics.csv under {args.runs}")
    write_json(args.name, {"note": args.note, "runs": runs})
    prefix = "gpu" if args.name == "gpu_vgg_runs" else args.name
    for run in runs:
        for png in ("error_vs_distance.png", "gradcam.png"):
            src = Path(args.runs) / f"{run['run']}_eval" / png
            if src.exists():
                shutil.copyfile(src, BENCH_DIR / "results" / f"{prefix}_{run['run']}_{png}")
    update_results_md(args.section, markdown(runs, args.note, args.title))


if __name__ == "__main__":
    main()
