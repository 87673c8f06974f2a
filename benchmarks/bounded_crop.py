"""How close the parallel VGG-19's crop without a roi (the detected object's box) is to the crop it trained on.

Usage: python benchmarks/bounded_crop.py --data data/truss_test100 [--limit N]

The parallel model's rotation stream trains on the "bounded image": the true object box (``bbox_obj``)
× ``CROP_MARGIN``, jittered by up to ``JITTER_SHIFT`` of the side and a margin of ``JITTER_MARGIN`` × the
extent. Without a ``roi`` its predictor crops around the detected object
(:func:`~hybridpose.regressors.predictor.detected_crop`; where nothing is detected
:func:`~hybridpose.regressors.predictor.translation_crop`). Per view: the crop centres' distance over the crop side, and
the crop side over the true box's extent; the share of views whose crop lies inside the training
jitter. Writes ``benchmarks/results/bounded_crop.json`` and the "bounded-crop" section of RESULTS.md.
"""
from __future__ import annotations

import argparse

import numpy as np

from _common import environment, update_results_md, write_json
from hybridpose.datasets.bop import BopScene, dataset_object, find_scenes
from hybridpose.datasets.torch_dataset import JITTER_MARGIN, JITTER_SHIFT, crop_box
from hybridpose.regressors.predictor import CROP_MARGIN, detected_crop, translation_crop


def crop_agreement(true_box, crop) -> tuple[float, float]:
    """(centre offset / crop side, crop side / true extent) of ``crop`` (cx, cy, side) px against the crop
    training makes around ``true_box`` (x, y, w, h) px; (inf, inf) without a crop."""
    if crop is None:
        return float("inf"), float("inf")
    tcx, tcy, tside = crop_box(true_box, CROP_MARGIN)
    cx, cy, side = crop
    return float(np.hypot(cx - tcx, cy - tcy) / side), float(side / (tside / CROP_MARGIN))


def inside_training_jitter(offset: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Views whose crop a training draw could have made: each centre coordinate within ``JITTER_SHIFT``
    of the side (so the offset within √2 of it), the side within ``JITTER_MARGIN`` × the extent."""
    return (offset <= JITTER_SHIFT * np.sqrt(2)) & (scale >= JITTER_MARGIN[0]) & (scale <= JITTER_MARGIN[1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args()
    views = [(scene, i) for scene in map(BopScene, find_scenes(args.data)) for i in scene.image_ids][: args.limit]
    diameter = dataset_object(args.data).diameter
    rows = {"detected object": [], "true translation, object diameter": []}
    for scene, i in views:
        gt = scene.image(i)
        rows["detected object"].append(crop_agreement(gt.bbox_obj, detected_crop(scene.rgb(i))))
        # the crop the predictor falls back to, here with a perfect translation: the best it can do
        rows["true translation, object diameter"].append(
            crop_agreement(gt.bbox_obj, translation_crop(gt.pose.t, gt.camera.K, diameter)))
    result = {"env": environment(), "data": args.data, "views": len(views), "crops": {}}
    lines = [
        "## The parallel VGG-19's crop without a roi (`python benchmarks/bounded_crop.py`)", "",
        f"`{args.data}`, {len(views)} views; the crop the predictor makes without a roi (around the detected object; "
        "where nothing is detected, around its translation estimate, sized by the object's diameter — shown here with the "
        f"*true* translation, its best case) against the one the model trains on (true box × {CROP_MARGIN}). "
        f"git {result['env']['git']}.", "",
        "| crop around | not detected | centre offset / side: median, 90 %, 99 %, max | side / true extent: 1 %, 10 %, "
        f"median, 90 %, 99 % | inside the training jitter (offset ≤ {JITTER_SHIFT}·√2, side {JITTER_MARGIN[0]}–"
        f"{JITTER_MARGIN[1]} × extent) |",
        "|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        offset, scale = np.array(r).T
        found = np.isfinite(offset)
        c = {"not_detected": int((~found).sum()),
             "offset_over_side_p50_90_99_max": [float(x) for x in np.percentile(offset[found], [50, 90, 99, 100])],
             "side_over_extent_p1_10_50_90_99": [float(x) for x in np.percentile(scale[found], [1, 10, 50, 90, 99])],
             "inside_training_jitter": float(inside_training_jitter(offset, scale).mean())}
        result["crops"][name] = c
        lines.append(f"| {name} | {c['not_detected']} | {' / '.join(f'{x:.3f}' for x in c['offset_over_side_p50_90_99_max'])} | "
                     f"{' / '.join(f'{x:.2f}' for x in c['side_over_extent_p1_10_50_90_99'])} | {c['inside_training_jitter']:.1%} |")
    write_json("bounded_crop", result)
    update_results_md("bounded-crop", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
