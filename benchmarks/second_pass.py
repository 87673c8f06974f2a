"""When the shipped keypoint regressor should spend a second network pass (``passes="auto"``).

Usage:
    python benchmarks/second_pass.py --data data/truss_test [--checkpoint PATH] [--tune 400]

For every held-out view: the rotation error of the full inference path with one pass and with two
(the second on the crop re-centred on the first pose), and the first pass's twin-head confidence
(max probability). ``passes="auto"`` makes the second pass only below ``SECOND_PASS_BELOW``; since
the first pass is the same either way, its error on a view is the two-pass error below the
threshold and the one-pass error above, so thresholds are replayed without running it again. The
first ``--tune`` views choose the threshold; the rest confirm the shipped one. Writes
``results/second_pass.json`` and the "second-pass" section of RESULTS.md.
"""
from __future__ import annotations

import numpy as np
import torch

from _common import environment, tune_confirm_parser, update_results_md, write_json
from hybridpose.core import Frame
from hybridpose.datasets.bop import BopScene, find_scenes
from hybridpose.datasets.torch_dataset import crop_box
from hybridpose.metrics import rotation_error_deg
from hybridpose.regressors.evaluate import GROSS_ERROR_DEG
from hybridpose.regressors.predictor import (CROP_MARGIN, SECOND_PASS_BELOW, CheckpointRegressor,
                                             detect_bright_object)

THRESHOLDS = (0.5, 0.7, 0.8, 0.9, 0.95, 0.99)


def measure(checkpoint, data, limit=None) -> dict:
    """Per view: first-pass head confidence, rotation error (°) with 1 and with 2 passes."""
    one, two = CheckpointRegressor(checkpoint, passes=1), CheckpointRegressor(checkpoint, passes=2)
    items = [(s, i) for s in map(BopScene, find_scenes(data)) for i in s.image_ids][:limit]
    conf, err1, err2 = [], [], []
    with torch.no_grad():
        for scene, im_id in items:
            gt = scene.image(im_id)
            frame = Frame(scene.rgb(im_id), gt.camera, 0.0, im_id)
            box = detect_bright_object(frame.image)
            p = 0.0
            if box is not None:
                res, _, _, _, prob = one._keypoint_pass(frame.image, gt.camera.K, crop_box(box, CROP_MARGIN), turns=True)
                p = float(prob.max()) if res is not None and prob is not None else 0.0
            conf.append(p)
            for reg, errs in ((one, err1), (two, err2)):
                m = reg.predict(frame)
                errs.append(rotation_error_deg(m.pose, gt.pose) if m.pose is not None else 180.0)
    return {"conf": np.array(conf), "err1": np.array(err1), "err2": np.array(err2)}


def summary(err: np.ndarray, second_share: float) -> dict:
    return {"gross_share": float(np.mean(err > GROSS_ERROR_DEG)), "rot_mean_deg": float(err.mean()),
            "rot_median_deg": float(np.median(err)), "second_pass_share": second_share}


def rules(m: dict) -> dict:
    out = {"1 pass": summary(m["err1"], 0.0), "2 passes": summary(m["err2"], 1.0)}
    for tau in THRESHOLDS:
        second = m["conf"] < tau
        out[f"auto, below {tau:g}"] = summary(np.where(second, m["err2"], m["err1"]), float(second.mean()))
    return out


def main() -> None:
    ap = tune_confirm_parser("the threshold")
    args = ap.parse_args()
    m = measure(args.checkpoint, args.data, args.limit)
    n = len(m["conf"])
    tune = rules({k: v[:args.tune] for k, v in m.items()})
    confirm = rules({k: v[args.tune:] for k, v in m.items()}) if n > args.tune else {}
    shipped = f"auto, below {SECOND_PASS_BELOW:g}"
    write_json("second_pass", {"env": environment(), "data": args.data, "checkpoint": args.checkpoint,
                               "tune_views": args.tune, "views": n, "shipped_rule": shipped,
                               "tune": tune, "confirm": confirm})
    n_tune = min(args.tune, n)
    lines = ["## Second network pass of the shipped keypoint regressor (`benchmarks/second_pass.py`)", "",
             f"`{args.data}`, checkpoint `{args.checkpoint.split('/')[-1]}`, full inference path (twin rule, edge "
             f"refinement): views 0–{n_tune - 1} choose the threshold, views {n_tune}–{n - 1} confirm it. *auto, below "
             "x*: the second pass (on the crop re-centred on the first pose) only where the first pass's twin head "
             "is below x; *share*: views that get it.", "",
             f"| rule | > {GROSS_ERROR_DEG:.0f}° (tune) | mean ° (tune) | > {GROSS_ERROR_DEG:.0f}° (confirm) | "
             "mean ° (confirm) | median ° (confirm) | share with 2 passes (confirm) |", "|---|---|---|---|---|---|---|"]
    for name, t in tune.items():
        c = confirm.get(name)
        bold = "**" if name == shipped else ""
        conf = (f"{100 * c['gross_share']:.1f} % | {c['rot_mean_deg']:.2f} | {c['rot_median_deg']:.2f} | "
                f"{100 * c['second_pass_share']:.0f} %") if c else "– | – | – | –"
        lines.append(f"| {bold}{name}{bold} | {100 * t['gross_share']:.1f} % | {t['rot_mean_deg']:.2f} | {conf} |")
    update_results_md("second-pass", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
