"""The realistic suite: hand-held scenes written as BOP sequences, its seeds, its parts, and
``hybridpose bench --suite realistic`` planning one part at a time."""
import numpy as np
import pytest

from hybridpose.bench.command import BenchRequest, plan
from hybridpose.bench.suite import REALISTIC_KINDS, REALISTIC_SEEDS, REALISTIC_TUNING_RANGE, suite
from hybridpose.geometry import Camera
from hybridpose.metrics import rotation_error_deg
from hybridpose.objects import load_object
from hybridpose.render.handheld import HandheldSpec


def test_built_in_parts_are_the_boxes_they_say():
    cube, box = load_object("cube"), load_object("box")
    assert cube.diameter == pytest.approx(0.085 * np.sqrt(3))
    assert box.diameter == pytest.approx(np.linalg.norm([0.18, 0.11, 0.07]))
    assert len(cube.symmetries) == 23 and len(box.symmetries) == 3  # besides the identity


def test_the_suite_has_its_own_seeds_on_both_sides_of_its_line():
    report, tuning = suite("realistic"), suite("realistic", "tuning")
    assert len(report) == len(REALISTIC_KINDS) * len(REALISTIC_SEEDS["report"])
    assert {e.spec.seed for e in report}.isdisjoint(REALISTIC_TUNING_RANGE)
    assert {e.spec.seed for e in tuning} <= set(REALISTIC_TUNING_RANGE)
    assert {e.object for e in report} == {"cube", "box"}
    assert all(e.spec.hand == ("hand" in e.name) for e in report)
    with pytest.raises(ValueError, match="--seeds: .*tuning seeds"):
        suite("realistic", "report", seeds=(101,))
    assert [e.spec.seed for e in suite("realistic", "report", seeds=(11,))] == [11] * len(REALISTIC_KINDS)


def test_runs_come_per_part_and_the_cnn_only_with_a_network_fitted_to_it(tmp_path):
    specs, _, entries = plan(BenchRequest(out="o", suite="realistic"))
    assert {e.object for e in entries} == {"cube", "box"}
    # the shipped network knows the truss: no CNN or hybrid run, combined as the tracker
    assert {(s.mode, s.tracker, s.object) for s in specs} == {("tracker", "combined", "cube"), ("tracker", "combined", "box")}
    fitted = tmp_path / "cube.pt"
    fitted.write_bytes(b"")
    specs, _, _ = plan(BenchRequest(out="o", suite="realistic", modes=("tracker", "cnn"), regressor=f"cube={fitted}"))
    assert {(s.mode, s.object) for s in specs} == {("tracker", "cube"), ("tracker", "box"), ("cnn", "cube")}
    assert next(s for s in specs if s.mode == "cnn").regressor == str(fitted)
    with pytest.raises(ValueError, match="--regressor: expected"):
        plan(BenchRequest(out="o", suite="realistic", regressor="cube="))
    with pytest.raises(ValueError, match="--regressor: 'nowhere.pt'"):
        plan(BenchRequest(out="o", suite="realistic", regressor="cube=nowhere.pt"))


def test_a_hand_held_sequence_reads_back_as_it_was_drawn(tmp_path):
    from hybridpose.bench.modes import load_sequence
    from hybridpose.datasets.handheld import render_handheld_dataset
    from hybridpose.render.handheld import handheld_sequence

    camera = Camera(200, 150, 190.0, 190.0, 100.0, 75.0)
    spec = HandheldSpec(frames=12, seed=4, background="clutter", hand=True, size_px=60.0)
    cube = load_object("cube")
    scene = render_handheld_dataset(tmp_path / "d", cube, camera, spec)
    drawn = handheld_sequence(spec, cube, camera)
    seq = load_sequence(scene)
    assert len(seq) == 12
    for s, f in zip(seq, drawn):
        assert rotation_error_deg(s.truth, f.pose) < 1e-6 and np.allclose(s.truth.t, f.pose.t, atol=1e-6)
        assert s.visible == pytest.approx(f.visible, abs=1e-6) and s.frame.timestamp == pytest.approx(f.timestamp)
        assert np.array_equal(s.frame.image, f.image) and s.frame.sun_direction_cam is None
    assert min(s.visible for s in seq) < 0.9  # the hand passed
    assert render_handheld_dataset(tmp_path / "d", cube, camera, spec) == scene  # kept, not drawn again
    with pytest.raises(ValueError, match="out: .* already holds a different dataset"):
        render_handheld_dataset(tmp_path / "d", cube, camera, HandheldSpec(frames=12, seed=5, size_px=60.0))


@pytest.mark.parametrize("printed", [True, False])
def test_the_scene_keeps_the_part_as_drawn_with_its_print(tmp_path, printed):
    """models/part.obj reads back as the part the frames show: a printed part's print correlates with
    the frame at the true pose (PrintView, an independent reader of the texture coordinates), not at a
    pose 1 cm aside; a plain part carries none."""
    from hybridpose.core import Frame
    from hybridpose.datasets.handheld import PART_FILE, part_model, render_handheld_dataset
    from hybridpose.edges import ModelView
    from hybridpose.edges.print_match import PrintView
    from hybridpose.geometry import Pose
    from hybridpose.render.handheld import handheld_sequence

    camera = Camera(320, 240, 300.0, 300.0, 160.0, 120.0)
    spec = HandheldSpec(frames=3, seed=2, background="clutter", printed=printed, size_px=120.0, blur=False, noise=False)
    cube = load_object("cube")
    scene = render_handheld_dataset(tmp_path / "d", cube, camera, spec)
    assert (tmp_path / "d" / PART_FILE).is_file()
    part = part_model(scene)
    assert np.allclose(part.bbox_min, cube.bbox_min) and len(part.symmetries) == len(cube.symmetries)
    if not printed:
        assert part.texture is None
        return
    view = PrintView(ModelView(part))
    for f in handheld_sequence(spec, cube, camera):
        frame = Frame(f.image, camera, f.timestamp, f.index)
        assert view.score(frame, f.pose) > 0.8
        assert view.score(frame, Pose(f.pose.R, f.pose.t + [0.01, 0.0, 0.0])) < 0.5
    (tmp_path / "d" / PART_FILE).unlink()
    with pytest.raises(FileNotFoundError, match="scene_dir: .*part.obj not found"):
        part_model(scene)


def test_save_object_refuses_another_format(tmp_path):
    from hybridpose.objects import save_object

    with pytest.raises(ValueError, match="path: expected a .obj"):
        save_object(load_object("cube"), tmp_path / "cube.ply")


def test_bench_runs_the_realistic_suite_and_says_what_it_left_out(tmp_path, capsys):
    from hybridpose.cli import main

    assert main(["bench", "--suite", "realistic", "--split", "tuning", "--modes", "tracker,hybrid",
                 "--sequences", "plain-box-photo_s101", "--out", str(tmp_path / "o"), "--cache", str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    assert "no CNN or hybrid run on the box" in out and "--regressor box=FIT/best.pt" in out
    assert "| tracker (combined) | 1 |" in out and "plain-box-photo" in out
