"""How the shipped keypoint regressor should choose among the truss's box twins (end-for-end turns).

Usage:
    python benchmarks/twin_choice.py --data data/truss_test [--checkpoint PATH] [--tune 400] [--verifier PATH]

For every held-out view: the twin head's probabilities, the rotation error of each twin of the PnP
pose, and the edge fit (:func:`hybridpose.edges.fit_edges`) from each twin. Then the
choice rules are replayed on those numbers: the head alone, the edges alone, and the gated rule of
``CheckpointRegressor._refine`` (head alone when p ≥ ``tau``; else the twin with the best
``log p + a · log quality``) on a grid of (tau, a). The grid is scored on the first ``--tune`` views
and the shipped constants (``TWIN_SURE``, ``TWIN_EDGE_WEIGHT``) are then reported on the remaining
views, which took no part in choosing them. With ``--verifier`` (a ``hybridpose train-verifier``
checkpoint) its belief in each twin is measured too and the rules that add ``b · log p_verifier``
are replayed. A fit of quality < ``REFINE_MIN_QUALITY`` is not used,
as in the predictor (the twin's unrefined pose counts instead). Writes
``results/twin_choice.json`` and the "twin-choice" section of RESULTS.md.
"""
from __future__ import annotations

import numpy as np
import torch

from _common import environment, tune_confirm_parser, update_results_md, write_json
from hybridpose.core import Frame
from hybridpose.datasets.bop import BopScene, find_scenes
from hybridpose.datasets.torch_dataset import crop_box
from hybridpose.geometry import Pose
from hybridpose.metrics import rotation_error_deg
from hybridpose.regressors.evaluate import GROSS_ERROR_DEG
from hybridpose.regressors.predictor import (CROP_MARGIN, REFINE_MIN_QUALITY, REFINE_SEARCH_PX, TWIN_EDGE_WEIGHT,
                                             TWIN_SURE, CheckpointRegressor, detect_bright_object, twin_scores)
from hybridpose.edges import fit_edges, to_gray

TAUS = (0.5, 0.7, 0.8, 0.9, 0.95)
WEIGHTS = (2.0, 4.0, 8.0, 16.0)
VERIFIER_WEIGHTS = (0.5, 1.0, 2.0, 4.0)


def measure(reg: CheckpointRegressor, data, limit=None, verifier=None) -> dict:
    """Per view (arrays over views × twins): head probability, CNN error, fit quality, fit error (°)
    and, with a ``verifier`` (:class:`TwinVerifier`), its probability of each twin."""
    S = [Pose.identity(), *reg.twins]
    prob, cnn_err, fit_q, fit_err, ver, ver_fit = [], [], [], [], [], []
    items = [(s, i) for s in map(BopScene, find_scenes(data)) for i in s.image_ids][:limit]
    with torch.no_grad():
        for scene, im_id in items:
            gt = scene.image(im_id)
            frame = Frame(scene.rgb(im_id), gt.camera, 0.0, im_id)
            box = detect_bright_object(frame.image)
            res = None
            if box is not None:
                res, _, _, order, p = reg._keypoint_pass(frame.image, gt.camera.K, crop_box(box, CROP_MARGIN),
                                                          turns=True)  # the first pass as shipped
            if res is None:  # a failure for every rule alike
                prob.append(np.full(len(S), 1.0 / len(S)))
                cnn_err.append(np.full(len(S), 180.0))
                fit_q.append(np.zeros(len(S)))
                fit_err.append(np.full(len(S), 180.0))
                ver.append(np.full(len(S), 1.0 / len(S)))
                ver_fit.append(np.full(len(S), 1.0 / len(S)))
                continue
            keypoints_pose = res.pose @ S[order[0]]  # undo the head's twin
            twins = [keypoints_pose @ s for s in S]
            gray = to_gray(frame.image)
            fits = [fit_edges(reg.twin_check.view, frame, t, gray=gray, search_px=REFINE_SEARCH_PX) for t in twins]
            prob.append(p)
            cnn_err.append([rotation_error_deg(t, gt.pose) for t in twins])
            fit_q.append([f.quality if f else 0.0 for f in fits])
            fit_err.append([rotation_error_deg(f.pose, gt.pose) if f else 180.0 for f in fits])
            if verifier is not None:  # the strip along the head's choice, as in the predictor
                ver.append(verifier.probabilities(frame.image, gt.camera.K, twins, strip_pose=twins[order[0]]))
                fitted = [f.pose if f and f.quality >= REFINE_MIN_QUALITY else t for f, t in zip(fits, twins)]
                ver_fit.append(verifier.probabilities(frame.image, gt.camera.K, fitted, strip_pose=fitted[order[0]]))
    m = {"prob": prob, "cnn_err": cnn_err, "fit_q": fit_q, "fit_err": fit_err}
    if verifier is not None:
        m["ver"], m["ver_fit"] = ver, ver_fit
    return {k: np.array(v, dtype=float) for k, v in m.items()}


def final_error(m: dict, pick: np.ndarray) -> np.ndarray:
    """Rotation error (°) of the predictor's output when it settles on twin ``pick`` per view."""
    rows = np.arange(len(pick))
    use_fit = m["fit_q"][rows, pick] >= REFINE_MIN_QUALITY
    return np.where(use_fit, m["fit_err"][rows, pick], m["cnn_err"][rows, pick])


def gated(m: dict, tau: float, a: float) -> tuple[np.ndarray, float]:
    """The predictor's rule: (twin per view, edge fits per view)."""
    head = m["prob"].argmax(1)
    score = twin_scores(m["prob"], m["fit_q"], edge_weight=a)
    sure = m["prob"].max(1) >= tau
    pick = np.where(sure, head, score.argmax(1))
    return pick, float(np.mean(np.where(sure, 1, m["prob"].shape[1])))


def summary(err: np.ndarray, fits: float) -> dict:
    return {"gross_share": float(np.mean(err > GROSS_ERROR_DEG)), "rot_mean_deg": float(err.mean()),
            "rot_median_deg": float(np.median(err)), "fits_per_view": fits}


def rules(m: dict) -> dict:
    head = m["prob"].argmax(1)
    edges = (m["fit_q"] * 1.0).argmax(1)
    out = {"head alone": summary(final_error(m, head), 1.0),
           "edges alone (best fit quality)": summary(final_error(m, edges), m["prob"].shape[1]),
           "oracle twin (keypoint quality limit)": summary(m["cnn_err"].min(1), 0.0)}
    for tau in TAUS:
        for a in WEIGHTS:
            pick, fits = gated(m, tau, a)
            out[f"gated tau={tau} a={a:g}"] = summary(final_error(m, pick), fits)
    if "ver" in m:
        out["verifier alone"] = summary(final_error(m, m["ver"].argmax(1)), 0.0)
        out["verifier alone, on the edge-fitted twins"] = summary(final_error(m, m["ver_fit"].argmax(1)), 4.0)
        for b in VERIFIER_WEIGHTS:
            score = np.log(m["prob"] + 1e-6) + b * np.log(m["ver"] + 1e-6)
            out[f"head x verifier b={b:g}"] = summary(final_error(m, score.argmax(1)), 1.0)
            for a in (0.0, TWIN_EDGE_WEIGHT):
                pick, fits = gated_verified(m, TWIN_SURE, a, b)
                out[f"gated tau={TWIN_SURE} a={a:g} + verifier b={b:g}"] = summary(final_error(m, pick), fits)
    return out


def gated_verified(m: dict, tau: float, a: float, b: float) -> tuple[np.ndarray, float]:
    """The gated rule with the verifier's belief added where the head is unsure:
    ``log p + a · log quality + b · log p_verifier``."""
    head = m["prob"].argmax(1)
    score = twin_scores(m["prob"], m["fit_q"], edge_weight=a, verifier_prob=m["ver"], verifier_weight=b)
    sure = m["prob"].max(1) >= tau
    return np.where(sure, head, score.argmax(1)), float(np.mean(np.where(sure, 1, m["prob"].shape[1])))


def split(m: dict, rows: slice) -> dict:
    return {k: v[rows] for k, v in m.items()}


def main() -> None:
    ap = tune_confirm_parser("(tau, a)")
    ap.add_argument("--save", help="also write the per-view measurements to this .npz")
    ap.add_argument("--load", help="replay the rules on measurements saved with --save (no inference)")
    ap.add_argument("--verifier", help="also score the twins with this twin-verifier checkpoint (train-verifier)")
    args = ap.parse_args()
    reg = CheckpointRegressor(args.checkpoint)
    if args.load:
        m = dict(np.load(args.load))
    else:
        verifier = None
        if args.verifier:
            from hybridpose.regressors.twin_verifier import TwinVerifier

            verifier = TwinVerifier(args.verifier, reg.twin_check.view.object)
        m = measure(reg, args.data, args.limit, verifier)
        if args.save:
            np.savez(args.save, **m)
    tune, confirm = rules(split(m, slice(0, args.tune))), rules(split(m, slice(args.tune, None)))
    shipped = f"gated tau={TWIN_SURE} a={TWIN_EDGE_WEIGHT:g}"
    write_json("twin_choice", {"env": environment(), "data": args.data, "checkpoint": args.checkpoint,
                               "tune_views": args.tune, "views": len(m["prob"]), "shipped_rule": shipped,
                               "tune": tune, "confirm": confirm})
    n_tune, n_conf = min(args.tune, len(m["prob"])), max(len(m["prob"]) - args.tune, 0)
    lines = ["## Twin choice of the shipped keypoint regressor (`benchmarks/twin_choice.py`)", "",
             f"`{args.data}`, checkpoint `{args.checkpoint.split('/')[-1]}`: views 0–{n_tune - 1} choose the rule's "
             f"constants, views {n_tune}–{n_tune + n_conf - 1} confirm them. Gated rule (the predictor's): the head's "
             "twin alone when its probability ≥ tau, else every twin is edge-fitted and the best "
             "`log p + a · log quality` wins. Errors after the edge refinement (fits of quality < 0.5 unused).", "",
             f"| rule | > {GROSS_ERROR_DEG:.0f}° (tune) | mean ° (tune) | > {GROSS_ERROR_DEG:.0f}° (confirm) | "
             "mean ° (confirm) | median ° (confirm) | edge fits / view |",
             "|---|---|---|---|---|---|---|"]
    for name in tune:
        t, c = tune[name], confirm.get(name)
        bold = "**" if name == shipped else ""
        conf = (f"{100 * c['gross_share']:.1f} % | {c['rot_mean_deg']:.2f} | {c['rot_median_deg']:.2f} | "
                f"{c['fits_per_view']:.2f}") if c and n_conf else "– | – | – | –"
        lines.append(f"| {bold}{name}{bold} | {100 * t['gross_share']:.1f} % | {t['rot_mean_deg']:.2f} | {conf} |")
    update_results_md("twin-choice", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
