"""The twin verifier: strips, hypothesis drawings (against the renderer's masks), network, training, loading."""
import json

import cv2
import numpy as np
import pytest
import torch

from hybridpose.datasets import render_random_dataset
from hybridpose.datasets.bop import BopScene, find_scenes
from hybridpose.geometry import Camera, Pose
from hybridpose.training.train_verifier import build_pairs, load_pairs, noisy_pose, train_verifier
from hybridpose.regressors.twin_verifier import (STRIP_H, STRIP_W, HypothesisRenderer, TwinVerifier, TwinVerifierNet,
                                                 strip_affine, verifier_inputs)
from hybridpose.regressors.verify import box_half_turns


@pytest.fixture(scope="module")
def views(truss, tmp_path_factory):
    out = tmp_path_factory.mktemp("tv") / "ds"
    render_random_dataset(out, truss, Camera.default().scaled((320, 240)), count=8, seed=3, in_view=True)
    return out


def _axis_ends(truss):
    c = truss.center
    return np.array([c - [truss.extents[0] / 2, 0, 0], c + [truss.extents[0] / 2, 0, 0]])


def _strip_xy(A, uv):
    return uv @ A[:, :2].T + A[:, 2]


def test_strip_lays_the_long_axis_along_x_and_holds_the_object(truss, camera, rng):
    for _ in range(20):
        pose = Pose.from_rotvec_t(rng.normal(size=3), [rng.uniform(-.1, .1), rng.uniform(-.1, .1), rng.uniform(.4, 1.2)])
        A = strip_affine(pose, truss, camera.K)
        # independent projection: OpenCV's
        uv, _ = cv2.projectPoints(_axis_ends(truss), cv2.Rodrigues(pose.R)[0], pose.t, camera.K, None)
        ends = _strip_xy(A, uv[:, 0])
        assert abs(ends[0, 1] - ends[1, 1]) < 1e-6 * STRIP_W + 1e-6
        corners, _ = cv2.projectPoints(truss.bbox_corners, cv2.Rodrigues(pose.R)[0], pose.t, camera.K, None)
        st = _strip_xy(A, corners[:, 0])
        assert st.min() >= -0.5 and st[:, 0].max() <= STRIP_W - 0.5 and st[:, 1].max() <= STRIP_H - 0.5
        # the object fills the strip in one direction (margin 1.15)
        span = st.max(0) - st.min(0)
        assert max(span[0] / STRIP_W, span[1] / STRIP_H) == pytest.approx(1 / 1.15, rel=0.02)
        # a pose and its box twins share the strip
        for s in box_half_turns(truss):
            np.testing.assert_allclose(strip_affine(pose @ s, truss, camera.K), A, atol=1e-6)


def test_strip_refuses_an_object_behind_the_camera(truss, camera):
    with pytest.raises(ValueError, match="behind the camera"):
        strip_affine(Pose.from_rotvec_t([0, 0, 0], [0, 0, 0.01]), truss, camera.K)


def test_drawing_covers_what_the_renderer_masks(views, truss):
    """The flat-shaded drawing's silhouette against MuJoCo's object mask, both in the strip."""
    scene = BopScene(find_scenes(views)[0])
    renderer = HypothesisRenderer(truss)
    ious, twin_ious = [], []
    for im_id in scene.image_ids:
        gt = scene.image(im_id)
        A = strip_affine(gt.pose, truss, gt.camera.K)
        mask = cv2.warpAffine(scene.mask(im_id, visible=False).astype(np.uint8), A, (STRIP_W, STRIP_H),
                              flags=cv2.INTER_NEAREST) > 0
        drawn = renderer.draw(gt.pose, gt.camera.K, A) > 0
        ious.append((mask & drawn).sum() / (mask | drawn).sum())
        flip = renderer.draw(gt.pose @ box_half_turns(truss)[2], gt.camera.K, A) > 0
        twin_ious.append((mask & flip).sum() / (mask | flip).sum())
    assert min(ious) > 0.85
    # the twins are near-symmetric but not identical, and the drawing tells them apart
    assert np.mean(ious) > np.mean(twin_ious)


def test_verifier_inputs_share_the_strip_and_differ_in_the_drawings(views, truss):
    scene = BopScene(find_scenes(views)[0])
    gt = scene.image(scene.image_ids[0])
    gray = cv2.cvtColor(scene.rgb(gt.im_id), cv2.COLOR_RGB2GRAY)
    cands = [gt.pose] + [gt.pose @ s for s in box_half_turns(truss)]
    strip, drawings = verifier_inputs(gray, gt.camera.K, cands, truss)
    assert strip.shape == (STRIP_H, STRIP_W) and strip.dtype == np.uint8 and strip.max() > 50
    assert drawings.shape == (4, STRIP_H, STRIP_W) and drawings.dtype == np.uint8
    assert all(np.any(drawings[0] != drawings[k]) for k in range(1, 4))


def test_net_scores_each_candidate_and_checks_its_input():
    net = TwinVerifierNet(width=8).eval()
    x = torch.rand(2, 4, 2, STRIP_H, STRIP_W)
    y = net(x)
    assert y.shape == (2, 4)
    # candidates are scored independently: the order of the candidates permutes the scores
    torch.testing.assert_close(net(x[:, [2, 0, 3, 1]]), y[:, [2, 0, 3, 1]])
    with pytest.raises(ValueError, match=r"\(B, C, 2, H, W\)"):
        net(torch.rand(2, 3, STRIP_H, STRIP_W))


def test_noisy_pose_is_near_the_pose(truss, rng):
    pose = Pose.from_rotvec_t([0.3, -0.2, 0.1], [0.0, 0.0, 1.0])
    angles = []
    for _ in range(500):
        p = noisy_pose(pose, rng)
        angles.append(np.degrees(np.linalg.norm(cv2.Rodrigues(pose.R.T @ p.R)[0])))
        assert abs(p.t[2] - 1.0) < 0.2
    assert 0.5 < np.median(angles) < 4 and max(angles) < 45


def test_train_verifier_builds_pairs_resumes_and_loads(views, truss, tmp_path, camera):
    out = tmp_path / "tv"
    pairs = build_pairs([views], out, truss, seed=1, progress=False)
    strips, drawings, labels = load_pairs(pairs)
    assert strips.shape == (8, STRIP_H, STRIP_W) and drawings.shape == (8, 4, STRIP_H, STRIP_W)
    assert set(labels.tolist()) <= {0, 1, 2, 3}
    # chunks that exist are kept (a killed run resumes)
    chunk = next(pairs.glob("chunk_*.npz"))
    stamp = chunk.stat().st_mtime_ns
    build_pairs([views], out, truss, seed=1, progress=False)
    assert chunk.stat().st_mtime_ns == stamp
    # …but not when they were cut another way: kept chunks would mix two jobs
    with pytest.raises(ValueError, match=r"cut with other settings \(differs in: chunk, chunks, seed\)"):
        build_pairs([views], out, truss, seed=2, chunk=4, progress=False)
    assert chunk.stat().st_mtime_ns == stamp
    record = (pairs / "meta.json").read_bytes()
    (pairs / "meta.json").unlink()
    with pytest.raises(ValueError, match="no record of how they were cut"):
        build_pairs([views], out, truss, seed=1, progress=False)
    (pairs / "meta.json").write_bytes(record)
    best = train_verifier(pairs, out, truss, epochs=1, batch=4, width=8, val_fraction=0.25, progress=False)
    hist = json.loads((out / "history.json").read_text())
    assert len(hist) == 1 and 0 <= hist[0]["val_acc"] <= 1
    train_verifier(pairs, out, truss, epochs=2, batch=4, width=8, val_fraction=0.25, resume=True, progress=False)
    assert [h["epoch"] for h in json.loads((out / "history.json").read_text())] == [0, 1]
    ver = TwinVerifier(best, truss)
    scene = BopScene(find_scenes(views)[0])
    gt = scene.image(scene.image_ids[0])
    gray = cv2.cvtColor(scene.rgb(gt.im_id), cv2.COLOR_RGB2GRAY)
    p = ver.probabilities(gray, gt.camera.K, [gt.pose] + [gt.pose @ s for s in box_half_turns(truss)])
    assert p.shape == (4,) and np.isclose(p.sum(), 1) and np.all(p > 0)


def test_verifier_checkpoint_errors(tmp_path, truss):
    from hybridpose.objects import ObjectModel

    with pytest.raises(FileNotFoundError, match="twin verifier"):
        TwinVerifier(tmp_path / "missing.pt", truss)
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pt"):
        TwinVerifier(bad, truss)
    foreign = tmp_path / "foreign.pt"
    torch.save({"model": {}}, foreign)
    with pytest.raises(ValueError, match="not a hybridpose twin-verifier"):
        TwinVerifier(foreign, truss)
    other = tmp_path / "other.pt"
    torch.save({"format": "hybridpose-twin-verifier/1", "width": 8, "model": TwinVerifierNet(8).state_dict(),
                "object": "box", "diameter_m": 1.0}, other)
    with pytest.raises(ValueError, match="not on 'truss'"):
        TwinVerifier(other, truss)
    assert isinstance(truss, ObjectModel)


def test_build_pairs_names_a_folder_without_labels(tmp_path, truss):
    with pytest.raises(FileNotFoundError, match="labels.csv"):
        build_pairs([tmp_path], tmp_path / "out", truss, progress=False)


def test_pairs_do_not_depend_on_the_number_of_workers(views, truss, tmp_path):
    one = load_pairs(build_pairs([views], tmp_path / "one", truss, seed=4, progress=False, chunk=3))
    two = load_pairs(build_pairs([views], tmp_path / "two", truss, seed=4, progress=False, chunk=3, workers=2))
    assert len(list((tmp_path / "two" / "pairs").glob("chunk_*.npz"))) == 3
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)


def test_schedule_warms_up_then_decays():
    from hybridpose.training.train_verifier import schedule_lr

    lrs = [schedule_lr(1.0, s, 100) for s in range(100)]
    assert lrs[0] == pytest.approx(0.1) and lrs[9] == pytest.approx(1.0)
    assert all(a >= b for a, b in zip(lrs[9:], lrs[10:])) and lrs[-1] < 0.01


def test_train_verifier_bad_arguments(tmp_path, truss):
    with pytest.raises(ValueError, match="epochs"):
        train_verifier(tmp_path, tmp_path / "out", truss, epochs=0)
    with pytest.raises(FileNotFoundError, match="no chunk"):
        train_verifier(tmp_path, tmp_path / "out", truss, epochs=1)


def _chunk_errors(pairs) -> np.ndarray:
    """(N, 4) candidates' rotation errors (°) stored in a pairs directory's chunks, in chunk order."""
    return np.concatenate([np.load(f)["rot_err_deg"] for f in sorted(pairs.glob("chunk_*.npz"))])


def test_pairs_from_the_regressors_own_estimates(views, truss, tmp_path):
    """--estimates-from: the candidates are the shipped regressor's box twins of its own pose of each
    view; the label is the twin nearest the truth, and views with no twin near it are left out."""
    from hybridpose.regressors.checkpoints import shipped_checkpoint
    from hybridpose.training.train_verifier import LABEL_MAX_DEG

    pairs = build_pairs([views], tmp_path / "est", truss, seed=2, progress=False, chunk=4,
                        estimates_from=shipped_checkpoint("default"))
    meta = json.loads((pairs / "meta.json").read_text())
    assert meta["estimates_from"].endswith("default.pt") and meta["views"] == 8
    strips, drawings, labels = load_pairs(pairs)
    errors = _chunk_errors(pairs)
    assert 4 <= len(labels) <= 8 and drawings.shape == (len(labels), 4, STRIP_H, STRIP_W)
    np.testing.assert_array_equal(labels, errors.argmin(1))
    assert np.all(errors.min(1) <= LABEL_MAX_DEG)
    # the four candidates are one pose's box twins: two of them ≈ 180° from the nearest
    assert np.all(np.sort(errors, 1)[:, 1] > 90)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        build_pairs([views], tmp_path / "bad", truss, progress=False, estimates_from=tmp_path / "missing.pt")


def test_label_max_deg_chooses_which_estimates_teach(views, truss, tmp_path):
    """--label-max-deg: every view the regressor finds is kept at 180°; a tight bound keeps only the
    views whose nearest twin lies within it, and says so in meta.json."""
    from hybridpose.regressors.checkpoints import shipped_checkpoint

    ckpt = shipped_checkpoint("default")
    wide = build_pairs([views], tmp_path / "wide", truss, seed=2, progress=False, estimates_from=ckpt,
                       label_max_deg=180.0)
    errors = _chunk_errors(wide)
    bound = float(np.median(errors.min(1)))
    tight = build_pairs([views], tmp_path / "tight", truss, seed=2, progress=False, estimates_from=ckpt,
                        label_max_deg=bound)
    kept = _chunk_errors(tight)
    assert len(kept) == int(np.sum(errors.min(1) <= bound)) < len(errors)
    assert json.loads((tight / "meta.json").read_text())["label_max_deg"] == bound
    with pytest.raises(ValueError, match="label_max_deg"):
        build_pairs([views], tmp_path / "bad", truss, progress=False, estimates_from=ckpt, label_max_deg=0)


def test_fine_tuning_starts_from_the_given_verifier(views, truss, tmp_path):
    pairs = build_pairs([views], tmp_path / "a", truss, seed=1, progress=False)
    first = train_verifier(pairs, tmp_path / "a", truss, epochs=1, batch=4, width=8, val_fraction=0.25, progress=False)
    with pytest.raises(ValueError, match="width 8"):
        train_verifier(pairs, tmp_path / "b", truss, epochs=1, batch=4, width=16, init_from=first, progress=False)
    tuned = train_verifier(pairs, tmp_path / "c", truss, epochs=1, batch=4, width=8, lr=1e-12, val_fraction=0.25,
                           init_from=first, progress=False)
    a = torch.load(first, weights_only=True)["model"]
    b = torch.load(tuned, weights_only=True)["model"]
    # a vanishing learning rate leaves the weights where they started (BatchNorm statistics do move)
    for k in a:
        if k.endswith("weight") and a[k].ndim == 4:
            torch.testing.assert_close(a[k], b[k], atol=1e-6, rtol=0)


@pytest.fixture(scope="module")
def edge_on_views(truss, tmp_path_factory):
    out = tmp_path_factory.mktemp("tv_edge") / "ds"
    render_random_dataset(out, truss, Camera.default().scaled((320, 240)), count=6, seed=5, in_view=True,
                          elevation_range_deg=(0.0, 10.0))
    return out


def test_mirror_pairs_hold_the_twins_and_their_edge_on_mirrors(edge_on_views, views, truss, tmp_path):
    """--mirrors: views estimated near edge-on only, eight candidates each (a pose's four box twins
    and the four of its edge-on mirror), labelled by the one nearest the truth; recorded in meta.json,
    so a resume with other settings is refused."""
    from hybridpose.objects import view_elevation_deg
    from hybridpose.regressors.verify import MIRROR_BELOW_DEG

    pairs = build_pairs([edge_on_views], tmp_path / "m", truss, seed=1, progress=False, chunk=3, mirrors=True)
    assert json.loads((pairs / "meta.json").read_text())["mirrors"] == {"below_elevation_deg": MIRROR_BELOW_DEG}
    strips, drawings, labels = load_pairs(pairs)
    errors = _chunk_errors(pairs)
    assert len(labels) >= 4 and drawings.shape == (len(labels), 8, STRIP_H, STRIP_W) and errors.shape[1] == 8
    np.testing.assert_array_equal(labels, errors.argmin(1))
    assert np.all(errors.min(1) < 40)
    # the next nearest candidate is well away from the nearest: the mirrors do not repeat the twins
    assert np.all(np.sort(errors, 1)[:, 1] > errors.min(1) + 20)
    with pytest.raises(ValueError, match="mirrors"):
        build_pairs([edge_on_views], tmp_path / "m", truss, seed=1, progress=False, chunk=3)
    # far from edge-on, a view teaches nothing about mirrors and is left out
    scenes = [BopScene(s) for s in find_scenes(views)]
    near = sum(view_elevation_deg(s.image(i).pose, truss) < MIRROR_BELOW_DEG + 15 for s in scenes for i in s.image_ids)
    kept = load_pairs(build_pairs([views], tmp_path / "v", truss, seed=1, progress=False, mirrors=True))[2]
    assert len(kept) <= near < 8


def test_estimator_folders_give_each_estimator_its_own_pairs():
    from hybridpose.training.train_verifier import estimator_folders

    assert estimator_folders(None) == [(None, "pairs")] and estimator_folders([]) == [(None, "pairs")]
    assert estimator_folders("a.pt") == [("a.pt", "pairs")]
    assert estimator_folders(["a.pt", "b.pt", "c.pt"]) == [("a.pt", "pairs"), ("b.pt", "pairs2"), ("c.pt", "pairs3")]
    with pytest.raises(ValueError, match="the same checkpoint twice"):
        estimator_folders(["a.pt", "a.pt"])


def test_train_verifier_on_the_estimates_of_the_default_and_its_edge_on_expert(views, truss, tmp_path, capsys):
    """hybridpose train-verifier --estimates-from A B: each view cut once per estimator, into its own
    folder with its own record, and the verifier trained on both (the pooled rule scores the twins of
    both estimates); a bad checkpoint among them fails before any pairs are cut."""
    from hybridpose.cli import main
    from hybridpose.regressors.checkpoints import shipped_checkpoint

    default, expert = shipped_checkpoint("default"), shipped_checkpoint("edge_on_expert")
    out = tmp_path / "tv"
    assert main(["train-verifier", "--data", str(views), "--out", str(out), "--epochs", "1", "--width", "8",
                 "--batch", "4", "--seed", "2", "--estimates-from", str(default), str(expert)]) == 0
    assert "best validation accuracy" in capsys.readouterr().out
    metas = [json.loads((out / f / "meta.json").read_text()) for f in ("pairs", "pairs2")]
    assert [m["estimates_from"] for m in metas] == [str(default), str(expert)]
    n = [len(load_pairs(out / f)[2]) for f in ("pairs", "pairs2")]
    assert all(k >= 2 for k in n)
    ck = torch.load(out / "best.pt", weights_only=False)
    assert ck["pairs"] == [str(out / "pairs"), str(out / "pairs2")]
    # the pairs of the default alone are the ones a one-estimator run cuts
    alone = build_pairs([views], tmp_path / "alone", truss, seed=2, progress=False, estimates_from=default)
    np.testing.assert_array_equal(load_pairs(alone)[1], load_pairs(out / "pairs")[1])
    bad = tmp_path / "bad"
    assert main(["train-verifier", "--data", str(views), "--out", str(bad), "--epochs", "1",
                 "--estimates-from", str(default), str(tmp_path / "missing.pt")]) == 2
    assert "missing.pt: checkpoint not found" in capsys.readouterr().err
    assert not (bad / "pairs").exists()


def test_verifier_on_onnxruntime_scores_what_torch_does(views, truss, tmp_path, monkeypatch, caplog):
    """The shipped verifier's probabilities on either engine agree to float rounding; "auto" falls back to
    torch (saying why) where ONNX Runtime is missing, "onnxruntime" then fails naming the package."""
    import logging
    import sys

    from hybridpose.regressors.checkpoints import WEIGHTS_DIR

    path = WEIGHTS_DIR / "twin_verifier.pt"
    on_torch, on_ort = TwinVerifier(path, truss, engine="torch"), TwinVerifier(path, truss)
    assert on_torch.engine == "torch" and on_ort.engine == "onnxruntime"
    scene = BopScene(find_scenes(views)[0])
    gt = scene.image(scene.image_ids[0])
    image = scene.rgb(gt.im_id)
    candidates = [gt.pose, *(gt.pose @ S for S in box_half_turns(truss))]
    p_torch = on_torch.probabilities_of_sets(image, gt.camera.K, [candidates, candidates[::-1]])
    p_ort = on_ort.probabilities_of_sets(image, gt.camera.K, [candidates, candidates[::-1]])
    assert p_ort.shape == (2, len(candidates))
    np.testing.assert_allclose(p_ort, p_torch, atol=1e-5)
    with pytest.raises(ValueError, match="engine: expected one of auto, torch, onnxruntime, got 'int8'"):
        TwinVerifier(path, truss, engine="int8")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # as if not installed
    with caplog.at_level(logging.INFO, logger="hybridpose.regressors.twin_verifier"):
        assert TwinVerifier(path, truss).engine == "torch"
    assert "needs the onnxruntime package" in caplog.text
    with pytest.raises(RuntimeError, match="pip install onnxruntime"):
        TwinVerifier(path, truss, engine="onnxruntime")
