"""``hybridpose fit --refine-on``: a fitted network fine-tuned on frames the tracker holds in the user's
footage, measured before and after on a later stretch it never trained on."""
import json

import numpy as np
import pytest

from hybridpose.geometry import Camera
from hybridpose.io import write_image
from hybridpose.objects import load_object
from hybridpose.refine import HELD_BACK, MIN_TRAIN_FRAMES, PATIENCE_EPOCHS, refine_on_footage, refine_report

CAM = Camera.default().scaled(160)


def test_nothing_to_refine_without_a_fit(tmp_path):
    with pytest.raises(FileNotFoundError, match="hybridpose fit"):
        refine_on_footage(tmp_path / "nofit", tmp_path, load_object("truss"), CAM)


@pytest.mark.parametrize("patience", [-1, 2.5, True, "30"])
def test_a_patience_that_is_not_a_whole_number_of_epochs_is_refused_before_any_work(tmp_path, patience):
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "best.pt").write_bytes(b"")
    with pytest.raises(ValueError, match="patience: expected a whole number of epochs >= 0"):
        refine_on_footage(tmp_path / "fit", tmp_path / "none.mp4", load_object("truss"), CAM, patience=patience)
    assert not (tmp_path / "fit" / "refine").exists()


def test_the_report_says_what_stopped_the_training():
    record = {"tracker": "combined", "source": "v.mp4", "from_initial_pose": False, "train_frames": 90,
              "held_back_from": 91, "epochs_trained": 57, "patience_epochs": 30, "stopped_early": True}
    assert "It trained 57 epochs (stopped by its loss on frames kept out of the training no better for 30 epochs)" \
        in refine_report(record)
    assert "It trained 57 epochs (stopped by the budget)" in refine_report({**record, "stopped_early": False})


def test_an_initial_pose_the_tracker_cannot_hold_and_too_few_tracked_frames_are_refused(tmp_path):
    from hybridpose.datasets import render_sequence_dataset
    from hybridpose.datasets.bop import BopScene
    from hybridpose.geometry import Pose
    from hybridpose.render.sequences import SequenceSpec

    truss = load_object("truss")
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "best.pt").write_bytes(b"")  # never read: the tracker alone labels the frames
    for k in range(2):
        write_image(tmp_path / "dark" / f"{k:03d}.png", np.full((CAM.height, CAM.width, 3), 30, np.uint8))
    with pytest.raises(ValueError, match="--init-pose: pose: .* is the object in view and the pose right"):
        refine_on_footage(tmp_path / "fit", tmp_path / "dark", truss, CAM, tracker="edges",
                          init_pose=Pose.from_rotvec_t([0.3, 0.2, 0.1], [0.0, 0.0, 0.8]))
    scene = render_sequence_dataset(tmp_path / "seq", truss, CAM, SequenceSpec(trajectory="tumble", frames=4, seed=4))
    with pytest.raises(ValueError, match=f"on [0-4] frames \\(at least {MIN_TRAIN_FRAMES} needed\\)"):
        refine_on_footage(tmp_path / "fit", scene / "rgb", truss, CAM, tracker="edges",
                          init_pose=BopScene(scene).image(0).pose)


def test_the_fit_command_checks_its_refine_options_before_fitting(tmp_path, capsys):
    from hybridpose.cli import main

    assert main(["fit", "truss", "--out", str(tmp_path / "f"), "--refine-on", str(tmp_path / "none.mp4")]) == 2
    assert "--refine-on" in capsys.readouterr().err
    (tmp_path / "pose.json").write_text(json.dumps({"quat_wxyz": [1, 0, 0, 0], "t_m": [0, 0, 0.8]}))
    assert main(["fit", "truss", "--out", str(tmp_path / "f"), "--init-pose", str(tmp_path / "pose.json")]) == 2
    assert "give --refine-on too" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
def test_a_fit_refined_on_tracked_frames_is_measured_on_a_later_stretch(tiny_checkpoint, tmp_path, monkeypatch):
    import shutil

    import hybridpose.training.precision as precision
    import hybridpose.training.train as train_module

    from hybridpose.datasets import render_sequence_dataset
    from hybridpose.datasets.bop import BopScene
    from hybridpose.render.sequences import SequenceSpec

    truss = load_object("truss")
    fit_dir = tmp_path / "fit"
    (fit_dir / "data").mkdir(parents=True)
    shutil.copy(tiny_checkpoint, fit_dir / "best.pt")
    shutil.copytree(tiny_checkpoint.parent.parent / "ds", fit_dir / "data" / "calib")
    before = (fit_dir / "best.pt").read_bytes()
    scene = render_sequence_dataset(tmp_path / "seq", truss, CAM, SequenceSpec(trajectory="tumble", frames=48, fps=30.0,
                                                                                seed=4))
    first = BopScene(scene).image(0).pose
    # the refinement trains as the fit does: in bfloat16 where the device runs it fast (said so here, where
    # this CPU may have no AMX), its crops cut from frames decoded once
    monkeypatch.setattr(precision, "fast_bf16", lambda device: True)
    configs, real_train = [], train_module.train
    monkeypatch.setattr(train_module, "train", lambda cfg, **kw: configs.append(cfg) or real_train(cfg, **kw))
    said = []
    record = refine_on_footage(fit_dir, scene / "rgb", truss, CAM, budget_min=0.05, tracker="edges", init_pose=first,
                               progress=said.append)
    assert [(c.amp, bool(c.cache_images), c.patience) for c in configs] == [(True, True, PATIENCE_EPOCHS)]
    assert any("training for 0.05 minutes from the fit's weights in bfloat16" in line for line in said)
    assert record["training_bf16"] is True and record["epochs_trained"] >= 1
    assert record["patience_epochs"] == PATIENCE_EPOCHS and record["stopped_early"] in (True, False)
    assert not (fit_dir / "refine" / "data" / "decoded").exists()  # the decoded frames are not kept
    tracked = record["train_frames"] + record["held_back_frames"]
    assert record["frames"] == 48
    assert record["train_frames"] >= MIN_TRAIN_FRAMES and tracked <= 48
    assert record["held_back_frames"] == tracked - round(tracked * (1 - HELD_BACK))
    train, held = (BopScene(fit_dir / "refine" / "data" / s / "000000") for s in ("train", "held_back"))
    assert max(train.image_ids) < record["held_back_from"] <= min(held.image_ids)  # a later stretch, apart
    # the labels are the tracker's poses: within a degree of the truth on a clear render
    truth = BopScene(scene)
    from hybridpose.metrics import rotation_error_deg
    assert max(rotation_error_deg(held.image(i).pose, truth.image(i).pose) for i in held.image_ids) < 1.0
    for side in ("before", "after"):
        assert record[side]["views"] == record["held_back_frames"] and np.isfinite(record[side]["rot_median_deg"])
        hybrid = record[side]["hybrid"]  # the hybrid from no initial pose over the held-back stretch
        assert hybrid["scored"] <= hybrid["trusted"] <= 48 - record["held_back_from"]
        assert hybrid["within_5deg_2cm"] + hybrid["over_10deg"] <= hybrid["scored"]
    assert (fit_dir / "refine" / "best.pt").is_file() and (fit_dir / "best.pt").read_bytes() == before
    assert "## Refined on your footage" in (fit_dir / "report.md").read_text()
    from hybridpose.regressors.predictor import CheckpointRegressor
    assert CheckpointRegressor(fit_dir / "refine" / "best.pt").hybrid_config == {}  # the fit's (the truss's: none)
    # without an initial pose the hybrid labels the frames: a network that never finds the part gives none
    with pytest.raises(ValueError, match="on 0 frames.*--init-pose"):
        refine_on_footage(fit_dir, scene / "rgb", truss, CAM, budget_min=0.05, tracker="edges", progress=lambda *_: None)


def test_a_fit_folder_without_its_calibration_renders_is_refined_uncalibrated_and_says_why(tmp_path):
    from hybridpose.refine import recalibrated

    checkpoint = tmp_path / "best.pt"
    checkpoint.write_bytes(b"not read")
    assert "calibration renders are gone" in recalibrated(checkpoint, tmp_path / "fit" / "data" / "calib")
    assert checkpoint.read_bytes() == b"not read"
