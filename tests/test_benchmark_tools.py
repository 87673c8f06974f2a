"""Helpers of the benchmark scripts that decide what their tables say (benchmarks/ is not a package)."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import own_object  # noqa: E402
import paper_check  # noqa: E402
import predict_stages  # noqa: E402
from _common import test_views as views_of  # noqa: E402  (not a test: renamed so pytest does not collect it)
from hybridpose.datasets import render_random_dataset  # noqa: E402
from hybridpose.geometry import Camera  # noqa: E402
from hybridpose.regressors import keypoint_passes  # noqa: E402
from hybridpose.regressors.predictor import CheckpointRegressor  # noqa: E402
from hybridpose.regressors.checkpoints import shipped_checkpoint  # noqa: E402


def test_stage_timers_split_the_predict_path_and_put_every_function_back(truss, tmp_path):
    render_random_dataset(tmp_path / "ds", truss, Camera.default().scaled((320, 240)), count=3, seed=5, in_view=True)
    frames = [f for f, _ in views_of(tmp_path / "ds")]
    originals = [(owner, attr, getattr(owner, attr)) for owner, attr, _ in predict_stages.STAGES]
    calls = [getattr(owner, attr) for owner, attr in predict_stages.ENGINE_CALLS]
    rows = predict_stages.measure(CheckpointRegressor(shipped_checkpoint("default")), frames)
    assert len(rows) == 3
    for r in rows:
        stages = sum(r[s] for s in predict_stages.STAGE_NAMES)
        assert 0 < stages <= r["total"]                   # outermost calls only: nothing counted twice
        assert r["network_calls"] >= 1 and r["network_images"] >= r["network_calls"] and r["detection"] > 0
    assert sum(r["edge fits"] for r in rows) > 0  # the edge refinement is found where the regressor calls it
    g = predict_stages.summarise(rows)
    assert g["views"] == 3 and g["ms_other"] >= 0
    assert g["ms_total"] <= g["ms_max"] == pytest.approx(1e3 * max(r["total"] for r in rows)) and g["ms_p95"] <= g["ms_max"]
    assert all(getattr(owner, attr) is fn for owner, attr, fn in originals)
    assert [getattr(owner, attr) for owner, attr in predict_stages.ENGINE_CALLS] == calls
    with pytest.raises(RuntimeError, match="boom"):
        with predict_stages.stage_timers():
            assert keypoint_passes.solve_pnp is not originals[2][2]
            raise RuntimeError("boom")
    assert all(getattr(owner, attr) is fn for owner, attr, fn in originals)


def test_paper_check_verdict_reads_the_interval_against_the_paper():
    assert paper_check.verdict({"ci95": [3.9, 4.5]}, 4.61) == "below"
    assert paper_check.verdict({"ci95": [3.9, 4.8]}, 4.61) == "level"
    assert paper_check.verdict({"ci95": [4.7, 5.0]}, 4.61) == "above"
    rng = np.random.default_rng(0)
    c = paper_check.bootstrap(np.full(50, 2.0), np.mean, 200, rng)
    assert c == {"estimate": 2.0, "ci95": [2.0, 2.0]}
    x = rng.normal(5.0, 1.0, 400)
    c = paper_check.bootstrap(x, np.mean, 2000, rng)
    assert c["ci95"][0] < x.mean() < c["ci95"][1] and c["ci95"][1] - c["ci95"][0] == pytest.approx(4 * 1 / 20, rel=0.2)


def test_engine_benchmark_runs_every_engine_on_every_view_in_rotating_order(truss, tmp_path):
    import inference_engines

    render_random_dataset(tmp_path / "ds", truss, Camera.default().scaled((320, 240)), count=3, seed=6, in_view=True)
    order = []

    class Logged:
        def __init__(self, name):
            self.name, self.reg = name, CheckpointRegressor(shipped_checkpoint("default"), engine=name)

        def predict(self, frame):
            order.append(self.name)
            return self.reg.predict(frame)

    regs = {n: Logged(n) for n in ("torch", "onnxruntime")}
    rows = inference_engines.measure(regs, views_of(tmp_path / "ds"), block=2)
    # after the warm-up: views 0-1 torch then onnxruntime, view 2 onnxruntime then torch
    assert order[2:] == ["torch", "torch", "onnxruntime", "onnxruntime", "onnxruntime", "torch"]
    for n in regs:
        assert len(rows[n]["seconds"]) == len(rows[n]["rot_deg"]) == 3 and min(rows[n]["seconds"]) > 0
    np.testing.assert_allclose(rows["onnxruntime"]["rot_deg"], rows["torch"]["rot_deg"], atol=0.05)


def test_engine_benchmark_configurations_name_engine_and_cheaper_settings():
    import inference_engines

    assert inference_engines.regressor_options("torch") == {"engine": "torch"}
    assert inference_engines.regressor_options("onnxruntime-int8/no-expert/no-turns") == {
        "engine": "onnxruntime-int8", "edge_on_expert": None, "turns": "off"}
    with pytest.raises(ValueError, match="unknown setting 'fast'"):
        inference_engines.regressor_options("torch/fast")


def test_gpu_vgg_summary_reads_the_archive_and_marks_what_is_missing(tmp_path):
    """benchmarks/gpu/vgg_runs.py: best validation epoch, the test report's summary, '–' where a part
    did not come back from the machine."""
    import json

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks" / "gpu"))
    import vgg_runs

    run = tmp_path / "vgg16"
    run.mkdir()
    head = "epoch,train_loss,val_loss,rot_mean_deg,rot_median_deg,trans_mean_m,lr,epoch_s,train_images\n"
    (run / "metrics.csv").write_text(head + "0,22,22.2,126,129,0.16,1e-4,50,100\n1,21,21.0,110,112,0.15,1e-4,40,100\n"
                                     "2,20,21.5,115,118,0.14,1e-4,45,100\n")
    (tmp_path / "vgg16_eval").mkdir()
    (tmp_path / "vgg16_eval" / "report.json").write_text(json.dumps({"summary": {
        "images": 10, "rot_mean_deg": 111.0, "rot_median_deg": 115.0, "trans_mean_m": 0.149, "speed_score": 2.1,
        "add_0.1d_recall": 0.0, "gross_error_share": 0.968, "failures": 0, "ms_per_image": {"1_thread": 3.6}}}))
    (tmp_path / "vgg16_eval_roi").mkdir()  # `--roi truth`
    (tmp_path / "vgg16_eval_roi" / "report.json").write_text(json.dumps({"summary": {
        "rot_mean_deg": 20.0, "rot_median_deg": 10.0, "trans_mean_m": 0.05}}))
    runs = [vgg_runs.read_run(tmp_path, m) for m in vgg_runs.MODELS]
    assert runs[0]["epochs"] == 3 and runs[0]["val_best"]["epoch"] == 1 and runs[0]["epoch_s_mean"] == 45
    assert runs[0]["test"]["rot_mean_deg"] == 111.0 and runs[1] == {"model": "vgg19", "run": "vgg19"}
    md = vgg_runs.markdown(runs, "note")
    assert ("| **vgg16** | 3 × 45 | 110.0 / 112.0 / 0.150 (epoch 1) | 111.00 | 115.00 | 0.149 | 2.100 | 0.00 | 96.8% | "
            "3.6 | 20.00 / 10.00 / 0.050 |") in md
    assert "| **vgg19** | – × – | – | – | – | – | – | – | – | – | – |" in md
    assert "| paper: Parallel VGG-19 (their data, GPU, 100 epochs, ImageNet) | 100 | – | 4.61 | 4.41 | 0.03 |" in md
    # two runs of one model in folders of their own: one paper row, each run named by its folder
    (tmp_path / "seed1").mkdir()
    (tmp_path / "seed1" / "metrics.csv").write_text(head + "0,22,22.2,126,129,0.16,1e-4,50,100\n")
    two = [vgg_runs.read_run(tmp_path, "vgg16"), vgg_runs.read_run(tmp_path, "vgg16", "seed1")]
    md = vgg_runs.markdown(two, "note", title="Two runs")
    assert md.startswith("## Two runs") and md.count("| paper: VGG-16") == 1
    assert "| **vgg16 (`seed1`)** | 1 × 50 | 126.0 / 129.0 / 0.160 (epoch 0) | – |" in md


def test_the_own_object_tuning_sequences_never_share_a_seed_with_the_reported_ones():
    report, tuning = own_object.sequences("report"), own_object.sequences("tuning")
    assert len(report) == len(tuning) == 30
    assert {seed for *_, seed in report} == set(range(1, 31)) and {seed for *_, seed in tuning} == set(range(101, 131))
    # the same kinds, five seeds each, in both
    kinds = {(t, o) for t, o, _ in report}
    assert kinds == {(t, o) for t, o, _ in tuning} == set(own_object.KINDS)
    assert all(sum((t, o) == kind for t, o, _ in tuning) == 5 for kind in kinds)


def test_the_no_pose_hand_held_table_pools_wrong_frames_and_counts_sequences_that_never_start():
    import handheld_no_pose

    def row(seed, held, wrong, first):
        return {"kind": "printed-cube-photo", "seed": seed, "network": "no network", "model": "print", "memory": True,
                "frames": 90, "held_scored": held, "wrong": wrong, "first_pose": first, "ms_per_frame": 50.0,
                "memory_alone": {"in_basin": 3, "frames": 18}}

    rows = [row(1, 90, 0, 0), row(2, 45, 2, 10), row(3, 0, 0, None), row(4, 81, 1, 30)]
    line = handheld_no_pose.table(rows)[-1]
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[:4] == ["printed-cube-photo", "no network", "shape and print", "on"]
    median, p10, worst = (float(v.strip(" %")) for v in cells[4].split("/"))
    assert median == pytest.approx(np.median([100, 50, 0, 90])) and worst == 0 and 0 <= p10 <= median
    assert cells[5] == "3 of 360" and cells[6] == "10 / 30 (1 never)" and cells[7] == "12 of 72"


def test_the_no_pose_hand_held_benchmark_takes_more_tuning_seeds_and_keeps_the_reports():
    import handheld_no_pose

    names = [e.name for e in handheld_no_pose.scene_entries("tuning", ("printed-cube-photo",), "121-123,130")]
    assert names == [f"printed-cube-photo_s{s}" for s in (121, 122, 123, 130)]
    assert len(handheld_no_pose.scene_entries("tuning")) == 40  # 101-120 of both kinds
    with pytest.raises(ValueError, match="--seeds"):
        handheld_no_pose.scene_entries("tuning", seeds="5")  # a report seed
    with pytest.raises(SystemExit, match="only with --split tuning"):
        handheld_no_pose.main(["--seeds", "121"])


def test_the_refine_benchmark_refuses_a_fit_it_cannot_use_before_any_work(tmp_path, capsys):
    import refine_on_footage

    with pytest.raises(SystemExit, match="unknown video.*'castle'"):
        refine_on_footage.main(["--visp-repo", str(tmp_path), "--fit", f"castle={tmp_path}"])
    with pytest.raises(SystemExit, match="no best.pt in"):
        refine_on_footage.main(["--visp-repo", str(tmp_path), "--fit", f"teabox_left={tmp_path / 'nofit'}"])
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "best.pt").write_bytes(b"")
    with pytest.raises(SystemExit, match="--patience: expected whole numbers"):
        refine_on_footage.main(["--visp-repo", str(tmp_path), "--fit", f"teabox_left={tmp_path / 'fit'}",
                                "--patience", "0,ten"])


def test_the_refine_benchmark_cells_read_before_and_after():
    import refine_on_footage

    assert refine_on_footage._cnn_cell({"in_basin": 3, "frames": 65, "rot_median_deg": 27.43}) == "3 of 65 (27.4°)"
    assert refine_on_footage._cnn_cell({"in_basin": 0, "frames": 0, "rot_median_deg": None}) == "0 of 0 (—)"
    h = {"first_pose": None, "held": 0, "frames": 30, "wrong": 0}
    assert refine_on_footage._hybrid_cell(h) == "never; 0 of 30; 0"
    assert refine_on_footage._hybrid_cell({**h, "first_pose": 197, "held": 64, "frames": 64}) == "frame 197; 64 of 64; 0"
    rec = {"epochs_trained": 57, "minutes": {"train": 1.84}, "stopped_early": True, "patience_epochs": 30,
           "training_bf16": True}
    assert refine_on_footage._training_cell(rec) == "30; 57, 1.8 (no better for 30 epochs, bfloat16)"
    assert refine_on_footage._training_cell({**rec, "stopped_early": False, "training_bf16": False,
                                             "patience_epochs": 0}) == "none; 57, 1.8 (the budget)"
