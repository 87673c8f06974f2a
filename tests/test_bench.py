"""``hybridpose bench`` end to end on the smoke suite (short sequences): three modes on the same frames,
the results' structure and sanity (not speed), resuming, Ray, and bad input refused before long work."""
import json

import numpy as np
import pytest

from hybridpose.bench.suite import REPORT_SEEDS, SMOKE_SEEDS, TUNING_SEEDS, occlusion_suite, parse_seeds, suite
from hybridpose.cli import main

ROW_FIELDS = {"sequence", "mode", "tracker", "regressor", "fusion", "frames", "rot_mean_deg", "rot_median_deg",
              "trans_mean_m", "trans_mean_pct", "add_recall", "silent_failures", "frames_lost", "recover_frames_max",
              "ms_per_frame", "ms_tracker", "ms_regressor", "ms_fusion", "cnn_calls_per_100"}


def test_seed_splits_never_overlap_and_suites_are_what_they_say():
    assert not set(TUNING_SEEDS) & set(REPORT_SEEDS) and not set(SMOKE_SEEDS) & (set(TUNING_SEEDS) | set(REPORT_SEEDS))
    standard = suite("standard")
    assert len(standard) == 140 and len({e.name for e in standard}) == 140
    kinds = {e.name.rsplit("_s", 1)[0].split("_")[0] for e in standard}
    assert kinds == {"tumble", "fly-around", "approach", "distance-sweep", "tumble-eclipse", "tumble-fast", "tumble-edgeon"}
    assert {e.spec.seed for e in suite("standard", "tuning")}.isdisjoint({e.spec.seed for e in standard})
    assert len(occlusion_suite("report")) == 60
    with pytest.raises(ValueError, match="suite: expected one of"):
        suite("everything")


def test_a_split_takes_more_seeds_on_its_side_of_the_line():
    from hybridpose.bench.report import seed_ranges

    assert parse_seeds("920-923,930,921") == (920, 921, 922, 923, 930)
    assert seed_ranges(parse_seeds("920-923,930")) == "920–923, 930" and seed_ranges(REPORT_SEEDS) == "500–519"
    extra = occlusion_suite("tuning", seeds=parse_seeds("920-979"))
    assert len(extra) == 180 and {e.spec.seed for e in extra} == set(range(920, 980))
    assert sum(e.spec.occlusion == "arm-partial" for e in extra) == 60
    fresh = suite("standard", "report", seeds=parse_seeds("520-539"))
    assert len(fresh) == 140 and not {e.spec.seed for e in fresh} & (set(REPORT_SEEDS) | set(TUNING_SEEDS))


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    # rendered here, then run by two worker processes: the path where forked workers once hung
    rc = main(["bench", "--suite", "smoke", "--out", str(root / "out"), "--cache", str(root / "cache"), "--workers", "2"])
    assert rc == 0
    return root


def test_smoke_suite_writes_results_report_and_plots(smoke):
    out = smoke / "out"
    result = json.loads((out / "results.json").read_text())
    assert set(result) >= {"config", "versions", "commit", "rows"}
    assert result["config"]["suite"] == "smoke" and result["versions"]["python"]
    rows = result["rows"]
    assert len(rows) == 9 and {r["mode"] for r in rows} == {"tracker", "cnn", "hybrid"}
    for r in rows:
        assert ROW_FIELDS <= set(r), ROW_FIELDS - set(r)
        assert r["frames"] == 12 and 0.0 <= r["coverage"] <= 1.0 and r["frames_lost"] <= 12
        assert len(r["per_frame"]["rot_err_deg"]) == 12
    by_mode = {m: [r for r in rows if r["mode"] == m] for m in ("tracker", "cnn", "hybrid")}
    assert all(r["cnn_calls_per_100"] == 100.0 for r in by_mode["cnn"])
    assert all(r["cnn_calls_per_100"] == 0.0 for r in by_mode["tracker"])
    assert all(r["cnn_calls_per_100"] <= 100.0 for r in by_mode["hybrid"])
    # the components' shares never exceed the frame's wall time; each mode spends on its own parts
    for r in rows:
        assert r["ms_tracker"] + r["ms_regressor"] + r["ms_fusion"] <= r["ms_per_frame"] * 1.001
    assert all(r["ms_regressor"] == 0.0 and r["ms_tracker"] > 0 for r in by_mode["tracker"])
    assert all(r["ms_tracker"] == 0.0 and r["ms_regressor"] > 0 for r in by_mode["cnn"])
    assert all(r["ms_tracker"] > 0 and r["ms_regressor"] > 0 for r in by_mode["hybrid"])
    # the hybrid's time by state adds up to its frames and time; the slowest frame bounds every mean
    for r in by_mode["hybrid"]:
        by_state = r["ms_by_state"]
        assert set(by_state) <= {"init", "tracking", "lost", "reinit"} and "init" in by_state
        assert sum(n for _, n in by_state.values()) == 12
        assert np.isclose(sum(ms for ms, _ in by_state.values()), 12 * r["ms_per_frame"])
        assert r["ms_frame_max"] >= max(ms / n for ms, n in by_state.values())
    assert all(r["ms_by_state"] == {} for r in by_mode["tracker"] + by_mode["cnn"])
    from hybridpose.bench.runner import summarise

    pooled = summarise(by_mode["hybrid"])["hybrid (edges+default+isam2)"]
    assert pooled["ms_starting"] > 0 and pooled["ms_frame_p99"] <= pooled["ms_frame_max"]
    assert np.isnan(summarise(by_mode["cnn"])["cnn (default)"]["ms_tracking"])
    assert np.nanmedian([r["rot_median_deg"] for r in by_mode["hybrid"]]) < 5.0
    report = (out / "report.md").read_text()
    assert "Targets for `hybrid (edges+default+isam2)`" in report and "| tracker (edges) |" in report
    assert "Targets for `tracker (edges)` (from the true first pose" in report
    assert "| run | tracker ms | CNN ms | fusion ms |" in report and "| frame ms p99 / slowest |" in report
    assert (out / "error_vs_distance.png").stat().st_size > 1000 and (out / "speed_accuracy.png").is_file()


def test_a_rerun_resumes_from_the_kept_rows(smoke, capsys):
    rows_dir = smoke / "out" / "rows"
    kept = {p: p.stat().st_mtime_ns for p in rows_dir.rglob("*.json")}
    victim = sorted(kept)[0]
    victim.unlink()
    assert main(["bench", "--suite", "smoke", "--out", str(smoke / "out"), "--cache", str(smoke / "cache")]) == 0
    after = {p: p.stat().st_mtime_ns for p in rows_dir.rglob("*.json")}
    assert set(after) == set(kept)
    assert [p for p in kept if after[p] != kept[p]] == [victim]  # only the missing row was computed again
    result = json.loads((smoke / "out" / "results.json").read_text())
    assert result["rows_reused"] == len(kept) - 1
    # its seconds time only the missing row: the report says so
    assert f"({len(kept) - 1} of {len(kept)} rows kept from an earlier run" in (smoke / "out" / "report.md").read_text()


def test_rows_made_by_other_code_are_made_again(smoke, monkeypatch):
    from hybridpose.bench import runner

    rows_dir = smoke / "out" / "rows"
    kept = {p: p.stat().st_mtime_ns for p in rows_dir.rglob("*.json")}
    monkeypatch.setattr(runner, "code_fingerprint", lambda: "other-code")
    assert main(["bench", "--suite", "smoke", "--out", str(smoke / "out"), "--cache", str(smoke / "cache")]) == 0
    assert all(p.stat().st_mtime_ns != t for p, t in kept.items())
    assert {json.loads(p.read_text())["code"] for p in kept} == {"other-code"}


def test_a_checkpoint_changed_under_the_same_path_makes_other_rows(tmp_path):
    from hybridpose.bench.runner import RunSpec

    ckpt = tmp_path / "best.pt"
    ckpt.write_bytes(b"weights, calibration 1")
    cnn, tracker = RunSpec("cnn", regressor=str(ckpt)), RunSpec("tracker", regressor=str(ckpt))
    before = cnn.key, tracker.key
    ckpt.write_bytes(b"weights, calibration 2")  # re-calibrated in place
    assert cnn.key != before[0], "a CNN row of the old file is not this file's"
    assert tracker.key == before[1], "the tracker alone never runs the CNN"
    assert RunSpec("cnn", regressor="default").key == RunSpec("cnn", regressor="default").key


def untimed(row: dict) -> dict:
    """A result row without what the clock decides (times, the code stamp)."""
    out = {k: v for k, v in row.items() if not k.startswith("ms_") and k != "code"}
    if out.get("per_frame"):
        out["per_frame"] = {k: v for k, v in out["per_frame"].items() if k != "ms"}
    return out


@pytest.mark.slow  # tens of seconds on a 2-core CPU: CI runs it in its slow step
def test_ray_gives_the_local_results(smoke, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    assert main(["bench", "--suite", "smoke", "--limit", "1", "--modes", "tracker,hybrid", "--ray", "local",
                 "--out", str(out), "--cache", str(smoke / "cache")]) == 0
    local = {(r["sequence"], r["label"]): r for r in json.loads((smoke / "out" / "results.json").read_text())["rows"]}
    for r in json.loads((out / "results.json").read_text())["rows"]:
        assert untimed(r) == untimed(local[(r["sequence"], r["label"])])


def test_a_ray_cluster_that_does_not_answer_is_an_error_before_any_work(tmp_path, capsys):
    pytest.importorskip("ray")
    assert main(["bench", "--suite", "smoke", "--ray", "auto", "--out", str(tmp_path / "o"),
                 "--cache", str(tmp_path / "cache")]) == 2
    err = capsys.readouterr().err
    assert "--ray auto: no Ray cluster answered" in err and "--ray local" in err and "Traceback" not in err
    assert not (tmp_path / "cache").exists()  # nothing rendered


def test_the_untimed_warm_up_changes_no_result(smoke, monkeypatch):
    """Each backend runs a few frames untimed before its first sequence in a process (the first calls
    compile kernels); every run starts afresh, so the rows are those of a run without it."""
    from hybridpose.bench import runner

    scene = sorted((smoke / "cache").glob("*/test/000000"))[0]
    specs = [runner.RunSpec("tracker"), runner.RunSpec("cnn"), runner.RunSpec("hybrid")]
    runner.forget_warm_up()
    warmed = runner.run_sequence("s", str(scene), specs)
    monkeypatch.setattr(runner, "WARMUP_FRAMES", 0)
    runner.forget_warm_up()
    cold = runner.run_sequence("s", str(scene), specs)
    for a, b in zip(warmed, cold):
        assert untimed(a) == untimed(b)


@pytest.mark.parametrize("args, message", [
    (["--suite", "everything"], "suite: expected one of"),
    (["--suite", "smoke", "--trackers", "edges,nope"], "--trackers: unknown tracker 'nope'"),
    (["--suite", "smoke", "--fusions", "kalman"], "--fusions: unknown fusion 'kalman'"),
    (["--suite", "smoke", "--regressor", "missing.pt"], "--regressor: 'missing.pt' is neither"),
    (["--suite", "smoke", "--modes", "oracle"], "--modes: unknown mode 'oracle'"),
    (["--suite", "smoke", "--check-periods", "ten"], "--check-periods: expected whole numbers"),
    (["--suite", "smoke", "--config", "tracker_resumes=maybe"], "--config: tracker_resumes: expected true or false"),
    (["--suite", "smoke", "--config", "start_quality=high"], "--config: start_quality: expected a number"),
    (["--suite", "smoke", "--tracker-option", "samples=800"], "--tracker-option: expected NAME=VALUE with a name among"),
    (["--suite", "smoke", "--tracker-option", "max_samples=many"], "--tracker-option: max_samples: expected a number"),
    (["--suite", "smoke", "--tracker-option", "search_px=0"], "--tracker-option: edges: search_px: expected ≥ 1"),
    (["--suite", "smoke", "--sun", "maybe"], "--sun: expected known and/or unknown"),
    (["--suite", "standard", "--seeds", "920-979"], "--seeds: [920, 921, 922, 923, 924] are tuning seeds"),
    (["--suite", "occlusion", "--split", "tuning", "--seeds", "500-505"], "--seeds: the tuning split's seeds lie in"),
    (["--suite", "smoke", "--seeds", "520-530"], "--seeds: the smoke suite has its own seeds"),
    (["--suite", "standard", "--seeds", "nine"], "--seeds: expected seeds like 920-979"),
    (["--data", "x", "--seeds", "520-530"], "--seeds: only with --suite"),
    (["--suite", "smoke", "--sequences", "approach_*"], "--sequences: 'approach_*' matches none of this run's"),
    (["--suite", "smoke", "--video", "tumble_none_s1"], "--video: no sequence 'tumble_none_s1' in this run"),
])
def test_bad_names_are_refused_before_any_work(args, message, tmp_path, capsys):
    assert main(["bench", *args, "--out", str(tmp_path / "o"), "--cache", str(tmp_path / "c")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "c").exists()  # nothing rendered


def test_sequences_are_chosen_by_name_patterns():
    from hybridpose.bench.command import BenchRequest, plan

    _, _, entries = plan(BenchRequest(out="o", suite="standard", sequences=("approach_arm-*", "tumble-fast_none_s503")))
    names = [e.name for e in entries]
    assert len(names) == 21 and "tumble-fast_none_s503" in names
    assert all(n.startswith("approach_arm-") for n in names if n != "tumble-fast_none_s503")
    _, _, limited = plan(BenchRequest(out="o", suite="standard", sequences=("approach_arm-*",), limit=3))
    assert [e.name for e in limited] == [n for n in names if n != "tumble-fast_none_s503"][:3]


def test_tracker_targets_name_the_worst_kind_of_sequence():
    from hybridpose.bench.report import TRACKER_TARGETS, tracker_target_checks, tracker_targets

    def row(seq, rot_median, trans_median, silent=0, ms=2.0):
        return {"label": "tracker (edges)", "sequence": seq, "rot_mean_deg": rot_median, "rot_median_deg": rot_median,
                "trans_median_pct": trans_median, "trans_mean_m": 0.001, "trans_mean_pct": trans_median,
                "speed_mean": 0.01, "coverage": 1.0, "silent_failures": silent, "false_alarms": 1,
                "clear_good_frames": 100, "frames": 60, "frames_lost": 0, "covered_tracking_10deg": 0,
                "recover_frames": [], "ms_per_frame": ms, "cnn_calls_per_100": 0.0}

    rows = [row("tumble_none_s500", 0.1, 0.05), row("tumble_none_s501", 0.15, 0.08),
            row("approach_none_s500", 0.3, 0.2, silent=3), row("approach_none_s501", 0.25, 0.06)]
    name, checks = tracker_target_checks(rows, ["cnn (default)", "tracker (edges)"])
    by_key = {c.key: c for c in checks}
    assert name == "tracker (edges)" and set(by_key) == set(TRACKER_TARGETS)
    # the per-kind targets give the worst kind's median of sequence medians, and name the kind
    assert by_key["rot_median_deg"].kind == "approach_none" and by_key["rot_median_deg"].value == pytest.approx(0.275)
    assert by_key["trans_median_pct"].kind == "approach_none" and by_key["trans_median_pct"].value == pytest.approx(0.13)
    assert not by_key["rot_median_deg"].met and not by_key["trans_median_pct"].met
    assert by_key["silent_pct"].value == pytest.approx(100 * 3 / 240) and not by_key["silent_pct"].met
    assert by_key["seq_rot_median_p90_deg"].met and by_key["false_alarm_pct"].met and by_key["ms_per_frame"].met
    # the text has a line per check, met or missed
    lines = tracker_targets(rows, ["cnn (default)", "tracker (edges)"]).splitlines()[1:]
    assert [line.startswith("- met") for line in lines] == [c.met for c in checks]
    assert tracker_target_checks(rows, ["cnn (default)"]) == (None, []) and tracker_targets(rows, ["cnn (default)"]) == ""


def test_config_fields_are_parsed_by_their_type():
    from hybridpose.bench.command import parse_config

    cfg = parse_config("start_quality=0.5, restart_unconfirmed=true,check_period=5,tracker_resumes=0")
    assert (cfg.start_quality, cfg.restart_unconfirmed, cfg.check_period, cfg.tracker_resumes) == (0.5, True, 5, False)
    assert isinstance(cfg.check_period, int) and isinstance(cfg.restart_unconfirmed, bool)
    assert parse_config("keep_quality=none").keep_quality is None
    from hybridpose.bench.runner import RunSpec
    label = RunSpec(mode="hybrid", config=parse_config("keep_quality=none, check_period=5")).label
    assert label == "hybrid (edges+default+isam2, check_period=5, keep_quality=none)"
    assert parse_config("keep_quality=0.3, keep_after=8").keep_quality == 0.3
    with pytest.raises(ValueError, match="start_quality: expected a number"):
        parse_config("start_quality=none")


def test_a_checkpoints_recommended_policy_is_the_default_row_and_named(tmp_path):
    """A fitted part's checkpoint recommends ``reacquire_deg``: the default hybrid row runs with it (as
    the estimator would), its label says so, and every ``--config`` row builds on it."""
    from hybridpose.bench.command import BenchRequest, plan
    from hybridpose.regressors.checkpoints import save_checkpoint

    save_checkpoint(tmp_path / "part.pt", {"hybrid_config": {"reacquire_deg": 20.0}})
    specs, _, _ = plan(BenchRequest(out="o", suite="smoke", modes=("hybrid",), regressor=str(tmp_path / "part.pt"),
                                    configs=("check_period=5", "reacquire_deg=none")))
    assert [s.label for s in specs] == ["hybrid (edges+part+isam2, reacquire_deg=20)",
                                        "hybrid (edges+part+isam2, check_period=5, reacquire_deg=20)",
                                        "hybrid (edges+part+isam2)"]
    assert specs[0].config.reacquire_deg == 20.0
    save_checkpoint(tmp_path / "odd.pt", {"hybrid_config": {"reacquire": 20.0}})
    with pytest.raises(ValueError, match="--regressor .*odd.pt.hybrid_config.*reacquire not a field of HybridConfig"):
        plan(BenchRequest(out="o", suite="smoke", regressor=str(tmp_path / "odd.pt")))


def test_tracker_options_reach_the_tracker_and_name_the_run():
    from hybridpose.bench.command import BenchRequest, plan
    from hybridpose.bench.runner import RunSpec, spec_backends

    specs, _, _ = plan(BenchRequest(out="o", suite="smoke", modes=("tracker", "cnn", "hybrid"),
                                    tracker_options=("max_samples=123", "explain=false")))
    labels = sorted(s.label for s in specs)
    assert labels == ["cnn (default)", "hybrid (edges+default+isam2; explain=False, max_samples=123)",
                      "tracker (edges; explain=False, max_samples=123)"]
    tracker_spec = next(s for s in specs if s.mode == "tracker")
    _, tracker = spec_backends(tracker_spec)
    assert tracker.max_samples == 123 and tracker.explain is False
    # the options make other rows; the run without them keeps the key it had before options existed
    assert tracker_spec.key != RunSpec("tracker").key
    assert next(s for s in specs if s.mode == "cnn").key == RunSpec("cnn").key


def test_space_lit_frames_carry_the_sun_and_the_unknown_sun_is_an_ablation(smoke, tmp_path):
    from hybridpose.bench.command import BenchRequest, plan
    from hybridpose.bench.modes import load_sequence, sun_is_only_light, without_sun
    from hybridpose.bench.runner import RunSpec
    from hybridpose.io import read_json

    scene = next((smoke / "cache").glob("*/test/000000"))
    seq = load_sequence(scene)
    recorded = read_json(scene / "scene_meta.json")["frames"][str(seq[0].frame.index)]["sun_direction_cam"]
    assert sun_is_only_light(scene) and np.allclose(seq[0].frame.sun_direction_cam, recorded)
    assert all(s.frame.sun_direction_cam is None for s in without_sun(seq))
    assert load_sequence(scene, sun=False)[0].frame.sun_direction_cam is None
    # a dataset with a randomised look (ambient light, lamps, a photo behind) is not lit by the sun alone
    config = read_json(scene.parent.parent / "hybridpose.json")
    (tmp_path / "test").mkdir()
    (tmp_path / "hybridpose.json").write_text(json.dumps({**config, "appearance": {"kind": "random"}}))
    assert not sun_is_only_light(tmp_path / "test" / "000000")
    specs, _, _ = plan(BenchRequest(out="o", suite="smoke", sun=("known", "unknown")))
    assert sorted(s.label for s in specs) == ["cnn (default)", "hybrid (edges+default+isam2)",
                                              "hybrid (edges+default+isam2; sun unknown)", "tracker (edges)",
                                              "tracker (edges; sun unknown)"]
    assert RunSpec("hybrid", sun=False).key != RunSpec("hybrid").key
    only_unknown, _, _ = plan(BenchRequest(out="o", suite="smoke", sun=("unknown",)))
    assert "cnn (default)" in {s.label for s in only_unknown}


def test_user_data_must_be_bop_and_the_regressor_must_fit_the_object(tmp_path, capsys):
    (tmp_path / "notbop").mkdir()
    assert main(["bench", "--data", str(tmp_path / "notbop"), "--out", str(tmp_path / "o")]) == 2
    assert "--data:" in (err := capsys.readouterr().err) and "no BOP scene" in err
    import trimesh

    box = tmp_path / "box.stl"
    trimesh.creation.box(extents=(0.1, 0.1, 0.1)).export(box)
    assert main(["bench", "--suite", "smoke", "--object", str(box), "--out", str(tmp_path / "o"),
                 "--cache", str(tmp_path / "c")]) == 2
    assert "object" in capsys.readouterr().err and not (tmp_path / "c").exists()


def test_your_own_bop_sequences(smoke, tmp_path):
    scene = smoke / "cache" / "tumble-fast_none_s950"
    out = tmp_path / "mine"
    assert main(["bench", "--data", str(scene), "--object", "truss", "--modes", "tracker,hybrid", "--out", str(out)]) == 0
    result = json.loads((out / "results.json").read_text())
    assert result["config"]["data"] == str(scene) and len(result["rows"]) == 2
    assert (out / "report.md").read_text().startswith(f"Sequences from `{scene}` (1), object `truss`")


def test_the_results_page_block_is_replaced_appended_or_made(smoke, tmp_path):
    from hybridpose.bench.command import write_results_page

    result = json.loads((smoke / "out" / "results.json").read_text())
    page = tmp_path / "page.md"
    write_results_page(page, result, block="mine")                       # no page yet: made with the block
    made = page.read_text()
    assert made.startswith("<!-- mine:begin -->") and made.rstrip().endswith("<!-- mine:end -->")
    page.write_text("# Title\n\nprose\n" + made + "after\n")
    write_results_page(page, result, block="mine")                       # replaced in place
    kept = page.read_text()
    assert kept.startswith("# Title\n\nprose\n<!-- mine:begin -->") and kept.endswith("<!-- mine:end -->\nafter\n")
    assert kept.count("<!-- mine:begin -->") == 1
    write_results_page(page, result, block="other")                      # another block: appended at the end
    assert page.read_text().startswith(kept) and page.read_text().rstrip().endswith("<!-- other:end -->")


def test_the_edge_distance_of_a_pose_reaching_behind_the_camera_is_infinite():
    from hybridpose.bench.modes import mean_edge_shift_px
    from hybridpose.geometry import Camera, Pose

    cam = Camera.default()
    pts = np.array([[-0.19, 0.0, 0.0], [0.19, 0.0, 0.0], [0.0, 0.1, 0.0]])
    truth = Pose.from_rotvec_t([0.2, 0.1, 0.0], [0.0, 0.0, 0.6])
    assert mean_edge_shift_px(cam, pts, truth, truth) == pytest.approx(0.0)
    nudged = Pose(truth.R, truth.t + [0.001, 0.0, 0.0])  # 1 mm at 0.6 m: 1 px at fx 600
    assert mean_edge_shift_px(cam, pts, nudged, truth) == pytest.approx(1.0, rel=0.05)
    end_on = Pose.from_rotvec_t([0.0, np.pi / 2, 0.0], [0.0, 0.0, 0.1])  # one end behind the camera
    assert mean_edge_shift_px(cam, pts, end_on, truth) == float("inf")
    grazing = Pose(np.eye(3), [0.19, 0.0, 1e-7])  # one point a hair in front of the camera plane
    assert mean_edge_shift_px(cam, pts, grazing, truth) == float("inf")
