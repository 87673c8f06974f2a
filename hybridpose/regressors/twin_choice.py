"""The end-for-end twin choice of a keypoint regressor: which of an estimate's box twins it returns,
edge-fitted.

A twin head names the twin it believes (``KeypointEstimate.order``/``prob``); the edge fit of each twin
(:func:`hybridpose.edges.fit.fit_edges`) and, where loaded, a twin verifier
(:mod:`.twin_verifier`) weigh in where the head is unsure: :func:`twin_scores`. Near edge-on, a mirror
verifier may replace the pose by its edge-on mirror (:meth:`TwinChoice.mirror_check`). With an
edge-on expert, the twins of both estimates are pooled (:meth:`TwinChoice.pooled`).
"""
from __future__ import annotations

import numpy as np

from ..core import Frame
from ..geometry import Pose
from ..objects import view_elevation_deg
from .keypoint_passes import KeypointEstimate, pnp_quality
from .verify import MIRROR_BELOW_DEG, TwinCheck, edge_on_mirror

# the edge fit from a CNN pose: how far it searches for image edges (px), and the fit quality below
# which the unrefined pose is kept
REFINE_SEARCH_PX = 16
REFINE_MIN_QUALITY = 0.5  # an edge refinement below this quality keeps the unrefined pose
# The twin choice (see TwinChoice.refine). Tuned on test views 0–399, confirmed on 400–999 (docs/decisions.md):
# the head is right whenever it is sure (no wrong twin above p = 0.99 in 400 views), so its twin alone is
# fitted from p ≥ TWIN_SURE; below, every twin is fitted and the head's belief is weighed against the
# edge support, log p + TWIN_EDGE_WEIGHT · log quality. Edge support alone picks worse than the head
# (20 % vs 9 % of views > 30°): wrong-twin fits lock onto the truss's symmetric chords.
TWIN_SURE = 0.8
TWIN_EDGE_WEIGHT = 8.0  # see above (chosen with TWIN_SURE on views 0–399)
VERIFIER_WEIGHT = 1.0  # see above (chosen with TWIN_SURE on views 0–399)
# with a twin verifier the head counts as sure only from this probability (chosen on the seed-101 test
# set)
VERIFIER_SURE = 0.95
# with a twin verifier, the weight of the edge fits' quality in the twin choice: 0 chooses by head ×
# verifier before any fit, and only the chosen twin is edge-fitted (one fit instead of four, ≈ 1.7 ms
# a view on average). Not the default: with it (and VERIFIER_WEIGHT 0.5) 98 views of 5000 were > 30°
# off against 95 with the edges weighed in (docs/decisions.md).
VERIFIER_EDGE_WEIGHT = TWIN_EDGE_WEIGHT
# Edge-on mirror check (mirror_verifier): the returned pose is replaced by one of its box twins or of
# its edge-on mirror's only where the mirror verifier believes that one with at least this probability
# (lower ones broke more views than they fixed; no mirror verifier is shipped: docs/decisions.md)
MIRROR_SWITCH_P = 0.95
# expert_rule "pooled": the weight of log q_pnp (each estimate's PnP quality) added to the twin score
# when the twins of both estimates are pooled (0–2 measure alike; docs/decisions.md). Used by
# "pooled" and "pooled-unsure" (below)
POOLED_PNP_WEIGHT = 1.0


def twin_scores(prob, quality, edge_weight: float = TWIN_EDGE_WEIGHT, verifier_prob=None,
                verifier_weight: float = VERIFIER_WEIGHT) -> np.ndarray:
    """The twin choice's score ``log p + edge_weight · log quality [+ verifier_weight · log p_verifier]``
    (the higher, the likelier).

    ``prob``: the twin head's probabilities, ``quality``: the edge fits' quality in [0, 1] (0 where a
    fit failed), ``verifier_prob``: the twin verifier's probabilities (None: not used); same shape,
    (..., n_twins), any leading batch shape.
    """
    prob = np.asarray(prob, dtype=float)
    quality = np.asarray(quality, dtype=float)
    if prob.shape != quality.shape:
        raise ValueError(f"prob and quality: expected the same shape (..., n_twins), got {prob.shape} and "
                         f"{quality.shape}")
    score = np.log(prob + 1e-6) + edge_weight * np.log(quality + 1e-3)
    if verifier_prob is not None:
        verifier_prob = np.asarray(verifier_prob, dtype=float)
        if verifier_prob.shape != prob.shape:
            raise ValueError(f"verifier_prob: expected the shape of prob {prob.shape}, got {verifier_prob.shape}")
        score = score + verifier_weight * np.log(verifier_prob + 1e-6)
    return score


def twin_starts(pose: Pose, order, twins) -> list[Pose]:
    """Every box twin of ``pose`` (which is twin ``order[0]`` of the keypoints' pose P), in ``order``:
    twin k of P is pose @ S[order[0]] @ S[k], S = [identity, *twins] (``twins``: list of :class:`Pose`)."""
    S = [Pose.identity(), *twins]
    first = S[order[0]]
    return [pose] + [pose @ first @ S[k] for k in order[1:]]


def best_fitted_start(fit, starts, head_prob, verifier_prob=None, edge_weight: float = TWIN_EDGE_WEIGHT):
    """(index, fit) of the start of highest :func:`twin_scores` after its fit — what fitting every start
    and taking the first best score gives, with fewer fits: a fit's quality is at most 1, so
    ``twin_scores`` at quality 1 bounds what a start can reach, and the starts are fitted in the order
    of that bound until the best score so far beats every bound left (where the head is unsure ≈ 2
    fits instead of 4; :meth:`TwinChoice.pooled` prunes its candidates alike).

    ``fit``: start → an object with ``quality`` in [0, 1], or None where the fit failed (quality 0);
    ``head_prob``, ``verifier_prob`` (None: no verifier): per start, as :func:`twin_scores` takes them.
    """
    # a weight that rewards poor fits has no such bound: then they are all fitted
    bound = (twin_scores(head_prob, np.ones(len(starts)), edge_weight=edge_weight, verifier_prob=verifier_prob)
             if edge_weight >= 0 else np.full(len(starts), np.inf))
    best, best_fit, best_score = 0, None, -np.inf
    for i in sorted(range(len(starts)), key=lambda k: (-bound[k], k)):
        if best_score > bound[i]:
            break
        result = fit(starts[i])
        score = twin_scores([head_prob[i]], [result.quality if result else 0.0], edge_weight=edge_weight,
                            verifier_prob=None if verifier_prob is None else [verifier_prob[i]])[0]
        # the lower index wins a tie, as np.argmax over all of them would
        if score > best_score or (score == best_score and i < best):
            best, best_fit, best_score = i, result, score
    return best, best_fit


class TwinChoice:
    """Chooses and edge-fits the returned twin of a keypoint estimate.

    Args:
        twin_check: the object's model view and box twins (:class:`~hybridpose.regressors.verify.TwinCheck`).
        twins: the box twins the twin head names (list of :class:`Pose`; empty: ``twin_check``'s).
        verifier: a :class:`~hybridpose.regressors.twin_verifier.TwinVerifier` weighed where the head
            is unsure (None: none).
        mirror_verifier: a verifier of edge-on mirrors (None: no mirror check).
    """

    def __init__(self, twin_check: TwinCheck, twins: list, verifier=None, mirror_verifier=None) -> None:
        self.twin_check, self.verifier, self.mirror_verifier = twin_check, verifier, mirror_verifier
        self.twins = list(twins) or list(twin_check.twins)
        self.view = twin_check.view

    @property
    def sure_from(self) -> float:
        """The twin-head probability from which the head decides alone (higher with a verifier)."""
        return TWIN_SURE if self.verifier is None else VERIFIER_SURE

    def starts(self, pose: Pose, order) -> list[Pose]:
        """:func:`twin_starts` of ``pose`` with this object's twins."""
        return twin_starts(pose, order, self.twins)

    def refine(self, frame: Frame, pose: Pose, order, prob=None, check_twins: bool = True) -> tuple[Pose, int]:
        """Edge fit from the CNN pose and, with ``check_twins``, from its box twins: (pose, the
        symmetry index of the twin it settled on, as in ``order``). ``frame``: undistorted.

        With a twin head (``prob``): when the head is sure (p ≥ :attr:`sure_from`) only its twin is
        fitted; else every twin is weighed (fitted until none left can win), and the one with the
        best ``log p + TWIN_EDGE_WEIGHT · log quality`` wins (with a verifier: ``log p +
        VERIFIER_EDGE_WEIGHT · log quality + VERIFIER_WEIGHT · log p_verifier``, and where
        ``VERIFIER_EDGE_WEIGHT`` is 0 the twin is chosen before fitting and only it is fitted).
        Without one, the fit most model edges agree with (inliers × quality) wins. A winning fit
        below ``REFINE_MIN_QUALITY`` is not used (the unrefined pose of its twin with a head, the CNN
        pose without).
        """
        from ..edges.fit import fit_edges, to_gray

        gray = to_gray(frame.image)
        if not check_twins:
            starts = [pose]
        else:
            starts = self.starts(pose, order)
            if prob is not None and prob[order[0]] >= self.sure_from:
                starts = starts[:1]
        twin_of = list(order[:len(starts)])  # symmetry index of each start
        head_prob = None if prob is None else [prob[k] for k in twin_of]
        # the verifier's strip is cut along the head's choice, as in its training (any twin gives it)
        ver = (self.verifier.probabilities(frame.image, frame.camera.K, starts)
               if prob is not None and self.verifier is not None and len(starts) > 1 else None)
        edge_weight = TWIN_EDGE_WEIGHT if ver is None else VERIFIER_EDGE_WEIGHT
        if ver is not None and edge_weight == 0:  # the fits would not change the choice: fit the chosen twin only
            k = int(np.argmax(twin_scores(head_prob, np.ones(len(starts)), edge_weight=0.0, verifier_prob=ver)))
            starts, twin_of, head_prob, ver = [starts[k]], [twin_of[k]], [head_prob[k]], None
        if prob is not None:
            best, fit = best_fitted_start(
                lambda start: fit_edges(self.view, frame, start, gray=gray, search_px=REFINE_SEARCH_PX),
                starts, head_prob, ver, edge_weight)
        else:
            fits = [fit_edges(self.view, frame, p, gray=gray, search_px=REFINE_SEARCH_PX) for p in starts]
            ranked = [(f.samples * f.quality, i) for i, f in enumerate(fits) if f]
            best = max(ranked)[1] if ranked else 0
            fit = fits[best]
        if fit is not None and fit.quality >= REFINE_MIN_QUALITY:
            return fit.pose, twin_of[best]
        # a poor fit: the twin the head and edges chose, unrefined; without a head, the CNN's own pose
        return (starts[best], twin_of[best]) if prob is not None else (pose, order[0])

    def pooled(self, frame: Frame, ests: list[KeypointEstimate]) -> tuple[KeypointEstimate, Pose, float]:
        """The best of every box twin of every estimate (``expert_rule="pooled"``): (its estimate, the
        pose, edge-fitted where the fit reaches ``REFINE_MIN_QUALITY``, the head's probability of it).
        Best: the highest ``log p_head + VERIFIER_EDGE_WEIGHT · log q_fit + VERIFIER_WEIGHT · log
        p_verifier + POOLED_PNP_WEIGHT · log q_pnp`` (:func:`twin_scores` of its own estimate's head
        and verifier, plus its estimate's :func:`pnp_quality`). Candidates are edge-fitted in order of
        their score with a perfect fit (an upper bound) until no unfitted one can win: the result is
        that of fitting all of them (≈ 2.3 fits instead of 8 near edge-on views). ``frame``: undistorted."""
        from ..edges.fit import fit_edges, to_gray

        edge_weight = TWIN_EDGE_WEIGHT if self.verifier is None else VERIFIER_EDGE_WEIGHT
        candidates = []  # (upper bound, estimate, start pose, head p, verifier p, q_pnp)
        starts_of = [self.starts(est.result.pose, est.order) for est in ests]
        # both estimates' twins in one verifier batch
        vers = (self.verifier.probabilities_of_sets(frame.image, frame.camera.K, starts_of)
                if self.verifier is not None else [None] * len(ests))
        for est, starts, ver in zip(ests, starts_of, vers):
            head = np.array([est.prob[k] for k in est.order])
            q_pnp = pnp_quality(est)
            bound = (twin_scores(head, np.ones(len(starts)), edge_weight=edge_weight, verifier_prob=ver)
                     + POOLED_PNP_WEIGHT * np.log(q_pnp + 1e-3))
            for j, start in enumerate(starts):
                candidates.append((float(bound[j]), est, start, head[j], None if ver is None else ver[j], q_pnp))
        candidates.sort(key=lambda c: -c[0])
        gray = to_gray(frame.image)
        best, best_score = None, -np.inf
        for bound, est, start, head_p, ver_p, q_pnp in candidates:
            if best_score >= bound:
                break
            fit = fit_edges(self.view, frame, start, gray=gray, search_px=REFINE_SEARCH_PX)
            score = float(twin_scores([head_p], [0.0 if fit is None else fit.quality], edge_weight=edge_weight,
                                      verifier_prob=None if ver_p is None else [ver_p])[0]
                          + POOLED_PNP_WEIGHT * np.log(q_pnp + 1e-3))
            if score > best_score:
                pose = fit.pose if fit is not None and fit.quality >= REFINE_MIN_QUALITY else start
                best, best_score = (est, pose, head_p), score
        return best

    def mirror_check(self, frame: Frame, pose: Pose, switch_p: float = MIRROR_SWITCH_P
                     ) -> tuple[Pose, float, int] | None:
        """Where ``pose`` is within ``MIRROR_BELOW_DEG`` of edge-on and a mirror verifier is loaded:
        (pose returned, the verifier's probability of it, its index among the candidates); else None.
        The candidates are ``pose``'s box twins (index 0: ``pose`` itself, 1–3) and those of its
        edge-on mirror (4–7), the strip cut along ``pose``, as ``train-verifier --mirrors`` cuts them
        around the regressor's estimate. The verifier's favourite is returned, edge-fitted where the
        fit reaches ``REFINE_MIN_QUALITY``, when its probability is ≥ ``switch_p``; else ``pose``
        (index 0). ``frame``: undistorted."""
        if self.mirror_verifier is None:
            return None
        obj = self.view.object
        if view_elevation_deg(pose, obj) >= MIRROR_BELOW_DEG:
            return None
        S = [Pose.identity(), *self.twin_check.twins]
        mirror = edge_on_mirror(pose, obj)
        cands = [pose @ s for s in S] + [mirror @ s for s in S]
        p = self.mirror_verifier.probabilities(frame.image, frame.camera.K, cands, strip_pose=pose)
        k = int(np.argmax(p))
        if k == 0 or p[k] < switch_p:
            return pose, float(p[0]), 0
        from ..edges.fit import fit_edges

        fit = fit_edges(self.view, frame, cands[k], search_px=REFINE_SEARCH_PX)
        return (fit.pose if fit is not None and fit.quality >= REFINE_MIN_QUALITY else cands[k]), float(p[k]), k
