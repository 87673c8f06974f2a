"""Training of the twin verifier (:mod:`hybridpose.regressors.twin_verifier`).

``hybridpose train-verifier --data DIR [DIR ...] --out runs/twinver`` (1) cuts, once, the image
strip and the four candidate drawings of every labelled view into ``out/pairs/chunk_NNNNN.npz``
(atomic, one file per ``CHUNK`` views, resumable: existing chunks are kept) and (2) trains
:class:`TwinVerifierNet` on them with a softmax over each view's four candidates, checkpointing
every epoch atomically (``last.pt``, ``--resume``) and keeping the best validation accuracy
(``best.pt``, the file :class:`TwinVerifier` loads).

The candidates are either the ground-truth pose perturbed by one draw of the pose noise a regressor
makes (``ROT_NOISE_MIX``, ``TRANS_NOISE``) and its three box twins, with that same error (at inference
the twins are generated from the one estimated pose), or, with ``estimates_from=CHECKPOINT``
(``--estimates-from``), exactly what the verifier is shown at inference: the box twins of that
keypoint regressor's own PnP pose of the view (:meth:`CheckpointRegressor.twin_candidates`), with
its real errors. With ``mirrors=True`` (``--mirrors``) only views seen within ``MIRROR_BELOW_DEG`` of
edge-on (by the estimate) are cut, and each gets eight candidates: the four twins and the four twins of
their edge-on mirror (:func:`~hybridpose.regressors.verify.edge_on_mirror`), the checkpoint the
predictor's edge-on mirror check loads. Their order is shuffled; the label is the place of the true one (the twin nearest
the ground truth; views where even that one is more than ``LABEL_MAX_DEG`` off teach nothing about
the twin choice and are left out; ``--label-max-deg`` widens this to teach the views whose keypoints
are poor too, where the nearest twin is still the one to pick).
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..core import Frame
from ..datasets.labels import read_labels
from ..geometry import Pose, load_camera
from ..metrics import rotation_error_deg
from ..io import atomic_write_json, atomic_write_with, read_json
from ..regressors.checkpoints import save_checkpoint
from ..regressors.twin_verifier import (CHECKPOINT_FORMAT, STRIP_H, STRIP_W, HypothesisRenderer, TwinVerifierNet,
                            verifier_inputs)
from ..regressors.verify import MIRROR_BELOW_DEG, box_half_turns, edge_on_mirror
from ..workers import spawn_pool

log = logging.getLogger(__name__)

CHUNK = 2000
# the candidates' shared rotation error: |N(0, σ)| about a random axis, σ drawn per view from this
# (share, σ°) mixture. The regressor's PnP poses before the edge fit are 2.5° off in the median and
# 5–30° off in the hard views where the head doubts: a first verifier trained with σ = 2° (8° for 10 %)
# failed mostly on those
ROT_NOISE_MIX = ((0.5, 2.0), (0.35, 6.0), (0.15, 12.0))
TRANS_NOISE = (0.004, 0.004, 0.02)  # σ of the translation error as a fraction of the distance (x, y, depth)
# with regressor estimates: a view whose nearest twin is further off than this has no right twin to learn
# (the default; runs 1–3 used it, so the views with poor keypoints, where a wrong twin costs most, were
# never shown: ``label_max_deg`` widens it)
LABEL_MAX_DEG = 20.0


def noisy_pose(pose: Pose, rng: np.random.Generator) -> Pose:
    """``pose`` with a random rotation error (about a random axis through the object origin, angle
    ~ |N(0, σ)| with σ from the ``ROT_NOISE_MIX`` mixture) and a translation error proportional to
    the distance (``TRANS_NOISE``)."""
    shares, sigmas = zip(*ROT_NOISE_MIX)
    sigma = sigmas[int(rng.choice(len(sigmas), p=np.asarray(shares) / sum(shares)))]
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    dR = Rotation.from_rotvec(np.radians(abs(rng.normal(0, sigma))) * axis).as_matrix()
    z = float(pose.t[2])
    t = pose.t + rng.normal(0, 1, 3) * np.asarray(TRANS_NOISE) * z
    return Pose(pose.R @ dR, t)


def _label_sets(dirs) -> list[tuple[Path, list, object]]:
    out = []
    for d in dirs:
        d = Path(d)
        if not (d / "labels.csv").is_file():
            raise FileNotFoundError(f"data: {d} has no labels.csv (render one with `hybridpose render`)")
        labels = read_labels(d / "labels.csv")
        if not labels:
            raise ValueError(f"data: {d}/labels.csv lists no images")
        out.append((d, labels, load_camera(d / "camera.json")))
    return out


def build_pairs(dirs, out, obj, seed: int = 0, limit: int | None = None, progress: bool = True,
                workers: int = 1, chunk: int = CHUNK, estimates_from=None,
                label_max_deg: float = LABEL_MAX_DEG, mirrors: bool = False, folder: str = "pairs") -> Path:
    """Cut strips and drawings of every view in the datasets ``dirs`` into ``out/folder`` (see module doc).

    Chunks already there are kept (a killed run resumes) when ``out/folder/meta.json`` records the same
    settings; pairs cut with other settings are refused (ValueError), not mixed. Each chunk is written
    atomically. Chunk ``c``'s
    noise comes from the seed ``(seed, c)``, so the pairs do not depend on ``workers`` (processes).
    Returns the pairs directory. ``limit``: at most this many views (tests); ``chunk``: views per file;
    ``estimates_from``: a keypoint-regressor checkpoint with a twin head whose own estimates give the
    candidates (instead of noise on the ground truth; ≈ 15 ms more per view); ``label_max_deg``: with
    ``estimates_from``, views whose nearest twin is further off (degrees) are left out; ``mirrors``:
    eight candidates (the twins and the twins of the edge-on mirror) of the views estimated within
    ``MIRROR_BELOW_DEG`` of edge-on only. ``folder``: the pairs directory's name in ``out`` (one per
    estimator when the views are cut with several: :func:`estimator_folders`).
    """
    if chunk < 1 or workers < 1:
        raise ValueError(f"chunk, workers: expected positive counts, got {chunk}, {workers}")
    if not 0 < label_max_deg <= 180:
        raise ValueError(f"label_max_deg: expected degrees in (0, 180], got {label_max_deg}")
    if estimates_from is not None:
        estimates_from = str(estimates_from)
        _estimator(estimates_from)  # a bad checkpoint fails here, not in every worker
    if not folder or Path(folder).name != folder:
        raise ValueError(f"folder: expected a plain directory name inside out, got {folder!r}")
    pairs = Path(out) / folder
    pairs.mkdir(parents=True, exist_ok=True)
    views = [(d, lab, cam) for d, labels, cam in _label_sets(dirs) for lab in labels][:limit]
    n_views = len(views)
    n_chunks = (n_views + chunk - 1) // chunk
    settings = {"views": n_views, "chunks": n_chunks, "chunk": chunk, "seed": seed, "data": [str(d) for d in dirs],
                "object": obj.name, "estimates_from": estimates_from, "label_max_deg": label_max_deg}
    if mirrors:  # recorded only when set, so pairs cut before the option existed still resume
        settings["mirrors"] = {"below_elevation_deg": MIRROR_BELOW_DEG}
    _open_pairs(pairs, settings, out)
    todo = [c for c in range(n_chunks) if not (pairs / f"chunk_{c:05d}.npz").is_file()]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_chunks, initial=n_chunks - len(todo), desc="twin-verifier pairs", unit="chunk")
    jobs = [(views[c * chunk:(c + 1) * chunk], pairs, obj, seed, c, estimates_from, label_max_deg, mirrors)
            for c in todo]
    if workers > 1 and len(jobs) > 1:
        with spawn_pool(min(workers, len(jobs))) as pool:
            for _ in pool.imap_unordered(_build_chunk, jobs):
                if bar is not None:
                    bar.update(1)
    else:
        for job in jobs:
            _build_chunk(job)
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    return pairs


def estimator_folders(estimates_from) -> list[tuple[str | None, str]]:
    """(estimator checkpoint or None, pairs folder) for each estimator the views are cut with: ``pairs`` for
    the first (or for noise on the ground truth when ``estimates_from`` is None or empty), ``pairs2``,
    ``pairs3``… for the others. Several estimators: the predictor's pooled rule shows the verifier the box
    twins of every estimate it pools (the default's and the edge-on expert's), so a verifier can be taught
    on each's own errors; the folders keep their own records (``meta.json``) and resume on their own."""
    if estimates_from is None or isinstance(estimates_from, (str, Path)):
        estimates_from = [] if estimates_from is None else [estimates_from]
    checkpoints = [str(c) for c in estimates_from]
    if len(set(checkpoints)) != len(checkpoints):
        raise ValueError(f"estimates_from: the same checkpoint twice in {checkpoints} (its pairs would count double)")
    if not checkpoints:
        return [(None, "pairs")]
    return [(c, "pairs" if k == 0 else f"pairs{k + 1}") for k, c in enumerate(checkpoints)]


def check_estimators(checkpoints) -> None:
    """Load every estimator checkpoint (None entries skipped) before any pairs are cut: a missing file or a
    regressor without a twin head fails at once, not after the first estimator's cut."""
    for checkpoint in checkpoints:
        if checkpoint is not None:
            _estimator(str(checkpoint))


def _open_pairs(pairs: Path, settings: dict, out) -> None:
    """Record the cutting settings in ``pairs/meta.json`` before any chunk is cut, or refuse when the
    chunks there were cut with others (a resume must be the same job: kept chunks would otherwise
    be mixed with new ones and the record would describe neither)."""
    meta = pairs / "meta.json"
    if meta.is_file():
        old = read_json(meta)
        diff = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
        if diff:
            raise ValueError(f"out: {out} already holds twin-verifier pairs cut with other settings (differs in: "
                             f"{', '.join(diff)}); choose another --out or delete {pairs}")
        return
    if any(pairs.glob("chunk_*.npz")):
        raise ValueError(f"out: {pairs} holds pairs with no record of how they were cut (meta.json); "
                         f"choose another --out or delete {pairs}")
    atomic_write_json(meta, settings)


_ESTIMATORS: dict = {}


def _estimator(checkpoint: str):
    """The keypoint regressor giving the candidates, loaded once per process (one torch thread: the
    pair cutting runs one process per core)."""
    if checkpoint not in _ESTIMATORS:
        from ..regressors.predictor import CheckpointRegressor

        reg = CheckpointRegressor(checkpoint, threads=1, check_twins=False, refine_edges=False, verifier=None)
        reg.require_twin_head()
        _ESTIMATORS[checkpoint] = reg
    return _ESTIMATORS[checkpoint]


def _candidates(d: Path, lab, cam, rng, twins, estimates_from, label_max_deg: float = LABEL_MAX_DEG,
                mirror_of=None):
    """(grey image, candidate poses, strip pose, index of the true one, candidates' rotation errors °)
    of one view, or None when the estimator loses it or none of its twins is within ``label_max_deg``.
    ``mirror_of``: the object, to add the twins of the edge-on mirror (views estimated more than
    ``MIRROR_BELOW_DEG`` from edge-on: None)."""
    if estimates_from is None:
        gray = _read_image(d / lab.image, cv2.IMREAD_GRAYSCALE)
        estimate = noisy_pose(lab.pose, rng)
        starts = _with_mirrors([estimate @ s for s in twins], twins, mirror_of)
        if starts is None:
            return None
        order = rng.permutation(len(starts))
        cands = [starts[k] for k in order]
        errors = np.array([rotation_error_deg(p, lab.pose) for p in cands])
        return gray, cands, cands[int(rng.integers(len(cands)))], int(errors.argmin()), errors
    rgb = cv2.cvtColor(_read_image(d / lab.image, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    found = _estimator(estimates_from).twin_candidates(Frame(rgb, cam, 0.0))
    if found is None:
        return None
    starts = _with_mirrors(found[0], twins, mirror_of)
    if starts is None:
        return None
    order = rng.permutation(len(starts))
    cands = [starts[k] for k in order]
    errors = np.array([rotation_error_deg(p, lab.pose) for p in cands])
    if errors.min() > label_max_deg:
        return None
    # the strip along the head's choice, as the predictor cuts it
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), cands, starts[0], int(errors.argmin()), errors


def _with_mirrors(starts: list, twins: list, obj) -> list | None:
    """``starts`` (the twins of one estimate, the estimate first) and, with ``obj``, the twins of the
    estimate's edge-on mirror after them; None where the estimate is not within ``MIRROR_BELOW_DEG``
    of edge-on (the predictor checks mirrors there only)."""
    if obj is None:
        return starts
    from ..objects import view_elevation_deg

    if view_elevation_deg(starts[0], obj) >= MIRROR_BELOW_DEG:
        return None
    mirror = edge_on_mirror(starts[0], obj)
    return list(starts) + [mirror @ s for s in twins]


def _read_image(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise FileNotFoundError(f"data: cannot read image {path}")
    return image


def _build_chunk(job) -> None:
    views, pairs, obj, seed, c, estimates_from, label_max_deg, mirrors = job
    cv2.setNumThreads(1)
    renderer, twins = HypothesisRenderer(obj), [Pose.identity(), *box_half_turns(obj)]
    rng = np.random.default_rng([seed, c])
    strips, drawings, labels, errors = [], [], [], []
    for d, lab, cam in views:
        view = _candidates(d, lab, cam, rng, twins, estimates_from, label_max_deg, obj if mirrors else None)
        if view is None:
            continue
        gray, cands, strip_pose, label, err = view
        strip, drawn = verifier_inputs(gray, cam.K, cands, obj, renderer, strip_pose=strip_pose)
        strips.append(strip)
        drawings.append(drawn)
        labels.append(label)
        errors.append(err)
    n = len(twins) * (2 if mirrors else 1)
    arrays = {"strips": np.stack(strips) if strips else np.zeros((0, STRIP_H, STRIP_W), np.uint8),
              "drawings": np.stack(drawings) if drawings else np.zeros((0, n, STRIP_H, STRIP_W), np.uint8),
              "labels": np.array(labels, np.int64), "rot_err_deg": np.array(errors, np.float32).reshape(-1, n)}
    atomic_write_with(pairs / f"chunk_{c:05d}.npz", lambda f: np.savez(f, **arrays))


def load_pairs(pairs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(strips (N, H, W), drawings (N, C, H, W), labels (N,)) of one pairs directory or a list of them."""
    dirs = [pairs] if isinstance(pairs, (str, Path)) else list(pairs)
    files = []
    for d in dirs:
        found = sorted(Path(d).glob("chunk_*.npz"))
        if not found:
            raise FileNotFoundError(f"pairs: no chunk_*.npz in {d}")
        files += found
    parts = [np.load(f) for f in files]
    return tuple(np.concatenate([p[k] for p in parts]) for k in ("strips", "drawings", "labels"))


def _augment(x: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """Space-imagery photometrics on the image channel (gain, gamma, noise) and a half-turn of the
    whole pair (a valid view of the object: an in-plane rotation of the camera)."""
    b = x.shape[0]
    img = x[:, :, 0]
    gain = 0.6 + 0.8 * torch.rand(b, 1, 1, 1, generator=gen)
    gamma = torch.exp((torch.rand(b, 1, 1, 1, generator=gen) - 0.5) * 0.6)
    noise = torch.randn(img.shape, generator=gen) * (torch.rand(b, 1, 1, 1, generator=gen) * 0.02)
    x = x.clone()
    x[:, :, 0] = ((img * gain).clamp(0, 1) ** gamma + noise).clamp(0, 1)
    turn = torch.rand(b, generator=gen) < 0.5
    x[turn] = x[turn].flip(-1, -2)
    return x


def _batch(strips, drawings, idx) -> torch.Tensor:
    s = torch.from_numpy(strips[idx]).float().div_(255.0)               # (B, H, W)
    d = torch.from_numpy(drawings[idx]).float().div_(255.0)             # (B, C, H, W)
    return torch.stack([s[:, None].expand_as(d), d], 2)                 # (B, C, 2, H, W)


def train_verifier(pairs, out, obj, epochs: int = 4, batch: int = 64, lr: float = 2e-3, width: int = 32,
                   val_fraction: float = 0.05, seed: int = 0, resume: bool = False, progress: bool = True,
                   init_from=None) -> Path:
    """Train on ``pairs`` (from :func:`build_pairs`); writes ``out/last.pt`` every epoch, ``out/best.pt``
    at the best validation accuracy and ``out/history.json``. Returns the path of ``best.pt``.
    ``init_from``: a twin-verifier checkpoint of the same ``width`` to start from (ignored on ``resume``
    once ``last.pt`` exists)."""
    if epochs < 1 or batch < 1 or lr <= 0 or width < 2:
        raise ValueError(f"epochs, batch, lr, width: expected ≥ 1, ≥ 1, > 0, ≥ 2, got {epochs}, {batch}, {lr}, {width}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    strips, drawings, labels = load_pairs(pairs)
    n = len(labels)
    if n < 2:
        raise ValueError(f"pairs: need at least 2 views, {pairs} has {n}")
    torch.manual_seed(seed)
    perm = np.random.default_rng(seed).permutation(n)
    n_val = max(1, int(round(val_fraction * n)))
    val, train = np.sort(perm[:n_val]), perm[n_val:]
    net = TwinVerifierNet(width)
    if init_from is not None:
        from ..regressors.twin_verifier import TwinVerifier

        start_net = TwinVerifier(init_from, obj, engine="torch").net
        if start_net.width != width:
            raise ValueError(f"init_from: {init_from} has width {start_net.width}, the run asks for width {width}")
        net.load_state_dict(start_net.state_dict())
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    steps_per_epoch = max(1, len(train) // batch)
    history, start, best_acc = [], 0, -1.0
    if resume and (out / "last.pt").is_file():
        ck = torch.load(out / "last.pt", map_location="cpu", weights_only=False)
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        history, start, best_acc = ck["history"], ck["epoch"] + 1, ck["best_acc"]
        log.info("resumed %s at epoch %d", out / "last.pt", start)
    gen = torch.Generator().manual_seed(seed)
    y_all = torch.from_numpy(labels)
    for epoch in range(start, epochs):
        net.train()
        order = np.random.default_rng([seed, epoch]).permutation(train)
        t0, total = time.perf_counter(), 0.0
        steps = range(steps_per_epoch)
        if progress:
            from tqdm import tqdm

            steps = tqdm(steps, desc=f"twin verifier epoch {epoch + 1}/{epochs}", unit="step")
        for s in steps:
            idx = order[s * batch:(s + 1) * batch]
            x = _augment(_batch(strips, drawings, idx), gen)
            for group in opt.param_groups:
                group["lr"] = schedule_lr(lr, epoch * steps_per_epoch + s, epochs * steps_per_epoch)
            loss = torch.nn.functional.cross_entropy(net(x), y_all[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach())
        acc, val_loss = evaluate_pairs(net, strips, drawings, labels, val)
        row = {"epoch": epoch, "train_loss": total / steps_per_epoch, "val_loss": val_loss, "val_acc": acc,
               "seconds": time.perf_counter() - t0}
        history.append(row)
        log.info("twin verifier %s", row)
        payload = {"format": CHECKPOINT_FORMAT, "model": net.state_dict(), "width": width, "object": obj.name,
                   "diameter_m": float(obj.diameter), "history": history,
                   "pairs": str(pairs) if isinstance(pairs, (str, Path)) else [str(d) for d in pairs]}
        if acc > best_acc:
            best_acc = acc
            save_checkpoint(out / "best.pt", payload)
        save_checkpoint(out / "last.pt", {**payload, "optimizer": opt.state_dict(), "epoch": epoch, "best_acc": best_acc})
        atomic_write_json(out / "history.json", history)
    return out / "best.pt"


def schedule_lr(peak: float, step: int, total: int, warmup: float = 0.1) -> float:
    """Linear warm-up over the first ``warmup`` of ``total`` steps, then a cosine to 0. A function of
    the step (no scheduler state), so a run resumed with more ``--epochs`` follows the longer schedule."""
    w = max(1, int(warmup * total))
    if step < w:
        return peak * (step + 1) / w
    return 0.5 * peak * (1 + np.cos(np.pi * min(1.0, (step - w) / max(1, total - w))))


@torch.no_grad()
def evaluate_pairs(net, strips, drawings, labels, idx, batch: int = 256) -> tuple[float, float]:
    """(accuracy, mean cross-entropy) of ``net`` on the views ``idx``."""
    net.eval()
    right, loss = 0, 0.0
    for s in range(0, len(idx), batch):
        j = idx[s:s + batch]
        logits = net(_batch(strips, drawings, j))
        y = torch.from_numpy(labels[j])
        right += int((logits.argmax(1) == y).sum())
        loss += float(torch.nn.functional.cross_entropy(logits, y, reduction="sum"))
    return right / len(idx), loss / len(idx)

