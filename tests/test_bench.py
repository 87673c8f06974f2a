"""The sequence benchmark's machinery end to end on the smoke split (short, low-resolution): three
modes on the same frames, rows with the reported fields, sane values, the seed splits apart."""
import numpy as np
import pytest

from hybridpose.bench.runner import RunSpec, run_all, summarise
from hybridpose.bench.suite import REPORT_SEEDS, SMOKE_SEEDS, TUNING_SEEDS, occlusion_suite, render_suite
from hybridpose.geometry import Camera


def test_seed_splits_never_overlap():
    assert not set(TUNING_SEEDS) & set(REPORT_SEEDS) and not set(SMOKE_SEEDS) & (set(TUNING_SEEDS) | set(REPORT_SEEDS))
    report = occlusion_suite("report")
    assert len(report) == 60 and len({e.name for e in report}) == 60
    assert {e.spec.trajectory for e in report} == {"tumble", "fly-around", "approach"}
    with pytest.raises(ValueError, match="split"):
        occlusion_suite("everything")


def test_smoke_suite_runs_three_modes_on_the_same_frames(tmp_path):
    entries = occlusion_suite("smoke", frames=12)[:1]
    scenes = render_suite(entries, tmp_path / "cache", camera=Camera.default())
    rows = run_all(scenes, RunSpec(), workers=1)
    assert [r["mode"] for r in rows] == ["tracker", "cnn", "hybrid"]
    for r in rows:
        assert r["frames"] == 12 and 0.0 <= r["coverage"] <= 1.0
        assert r["frames_lost"] <= 12 and r["silent_failures"] <= 12 and r["ms_per_frame"] > 0
    by_mode = {r["mode"]: r for r in rows}
    assert by_mode["cnn"]["cnn_calls_per_100"] == 100.0 and by_mode["tracker"]["cnn_calls_per_100"] == 0.0
    assert by_mode["hybrid"]["cnn_calls_per_100"] < 100.0
    assert np.isfinite(by_mode["hybrid"]["rot_median_deg"]) and by_mode["hybrid"]["rot_median_deg"] < 5.0
    s = summarise(rows)
    assert set(s) == {"tracker", "cnn", "hybrid"} and s["hybrid"]["sequences"] == 1
    # a second call reuses the rendered frames (resumable cache)
    assert render_suite(entries, tmp_path / "cache", camera=Camera.default()) == scenes
