"""``hybridpose track`` on a user's image folder / video with a camera file and an initial pose file."""
import csv
import json

import cv2
import numpy as np
import pytest

from hybridpose import HybridConfig
from hybridpose.cli import main
from hybridpose.datasets.bop import pose_to_bop
from hybridpose.geometry import Camera, Pose
from hybridpose.metrics import rotation_error_deg
from hybridpose.render import Renderer, SpaceLighting
from hybridpose.render.sequences import SequenceSpec, make_sequence
from hybridpose.tracking import load_pose


@pytest.fixture(scope="module")
def clip(truss, tmp_path_factory):
    """12 frames of a slow tumble as a PNG folder and an .mp4, with camera.json and the true poses."""
    root = tmp_path_factory.mktemp("clip")
    camera = Camera.default()
    frames = make_sequence(SequenceSpec("tumble", frames=12, fps=30, seed=2), truss, camera)
    (root / "png").mkdir()
    video = cv2.VideoWriter(str(root / "clip.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (camera.width, camera.height))
    with Renderer(truss, camera) as r:
        for f in frames:
            bgr = cv2.cvtColor(r.render(f.pose, rng=f.index).rgb, cv2.COLOR_RGB2BGR)
            cv2.imwrite(str(root / "png" / f"{f.index:06d}.png"), bgr)
            video.write(bgr)
    video.release()
    (root / "camera.json").write_text(json.dumps(camera.to_dict()))
    p0 = frames[0].pose
    (root / "pose.json").write_text(json.dumps({"quat_wxyz": p0.quat_wxyz.tolist(), "t_m": p0.t.tolist()}))
    return root, [f.pose for f in frames]


def _read_poses(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    return [Pose.from_quat_t([float(r[k]) for k in ("qw", "qx", "qy", "qz")], [float(r[k]) for k in ("tx_m", "ty_m", "tz_m")])
            for r in rows], rows


def test_track_image_folder_writes_overlay_csv_and_bop(clip, tmp_path, capsys):
    root, truth = clip
    rc = main(["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
               "--init-pose", str(root / "pose.json"), "--tracker", "edges", "--fps", "25",
               "--out", str(tmp_path / "run")])
    assert rc == 0
    out = tmp_path / "run"
    poses, rows = _read_poses(out / "poses.csv")
    assert len(poses) == len(truth) and rows[0]["frame"] == "0"
    # the pose given has no uncertainty of ours; the tracker's fits carry theirs
    assert rows[0]["sd_rx_deg"] == "" and all(float(r["sd_tz_m"]) > 0 for r in rows[1:] if r["lost"] == "0")
    assert np.median([rotation_error_deg(p, t) for p, t in zip(poses, truth)]) < 1.0
    gt = json.loads((out / "scene_gt.json").read_text())
    assert np.allclose(gt["5"][0]["cam_t_m2c"], poses[5].t * 1000, atol=1e-3)  # BOP is in mm
    (video,) = out.glob("overlay.*")  # WebM, or H.264 .mp4 where OpenCV has it
    cap = cv2.VideoCapture(str(video))
    assert cap.isOpened() and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == len(truth)
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(25, abs=0.01)  # plays at the source's rate
    assert float(rows[1]["timestamp_s"]) == pytest.approx(1 / 25)
    said = capsys.readouterr().out
    assert "12 frames with edges" in said and "ms/frame with reading the source and writing the overlay" in said
    # what was run, with what, on what: enough to run it again and compare
    record = json.loads((out / "run.json").read_text())
    assert record["mode"] == "tracker" and record["frames"] == 12 and record["options"]["tracker"] == "edges"
    assert record["camera"]["width"] == 640 and record["object"]["name"] == "truss" and record["versions"]["numpy"]
    assert record["cpu"]["cpus"] >= 1 and "policy" not in record
    assert record["wall_ms_per_frame"] > 0  # the whole loop's cost beside the tracker's own


def test_a_run_stopped_by_the_user_keeps_the_frames_it_tracked(clip, tmp_path, monkeypatch, capsys):
    """Ctrl-C in the middle of a long video: the overlay, poses.csv, scene_gt.json and run.json hold
    the frames done, and the exit status is 130."""
    import hybridpose.tracking as tracking

    root, _ = clip
    real = tracking.read_frames

    def stopped_after_three(source, camera, fps=None):
        for k, frame in enumerate(real(source, camera, fps)):
            if k == 3:
                raise KeyboardInterrupt
            yield frame

    monkeypatch.setattr(tracking, "read_frames", stopped_after_three)
    out = tmp_path / "stopped"
    assert main(["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
                 "--init-pose", str(root / "pose.json"), "--out", str(out)]) == 130
    poses, _ = _read_poses(out / "poses.csv")
    assert len(poses) == 3 and len(json.loads((out / "scene_gt.json").read_text())) == 3
    assert json.loads((out / "run.json").read_text())["interrupted"] is True and list(out.glob("overlay.*"))
    assert "stopped by the user after 3 frames" in capsys.readouterr().out


def test_track_video_file(clip, tmp_path):
    root, truth = clip
    assert main(["track", str(root / "clip.mp4"), "--object", "truss", "--camera", str(root / "camera.json"),
                 "--init-pose", str(root / "pose.json"), "--tracker", "klt-pnp", "--max-frames", "6",
                 "--out", str(tmp_path / "v")]) == 0
    poses, _ = _read_poses(tmp_path / "v" / "poses.csv")
    assert len(poses) == 6
    assert max(rotation_error_deg(p, t) for p, t in zip(poses, truth)) < 3.0  # mp4 compression costs a little


def test_track_with_a_visp_tracker_configuration_as_the_camera(clip, tmp_path, capsys):
    """ViSP's tracker configuration gives px, py, u0, v0 and no image size: the frames give it."""
    root, truth = clip
    cam = json.loads((root / "camera.json").read_text())
    (tmp_path / "cube.xml").write_text(f"<?xml version='1.0'?><conf><camera><u0>{cam['cx']}</u0><v0>{cam['cy']}</v0>"
                                       f"<px>{cam['fx']}</px><py>{cam['fy']}</py></camera></conf>")
    assert main(["track", str(root / "png"), "--object", "truss", "--camera", str(tmp_path / "cube.xml"),
                 "--init-pose", str(root / "pose.json"), "--max-frames", "4", "--out", str(tmp_path / "x")]) == 0
    poses, _ = _read_poses(tmp_path / "x" / "poses.csv")
    assert max(rotation_error_deg(p, t) for p, t in zip(poses, truth)) < 1.0
    assert main(["fit", "truss", "--camera", str(tmp_path / "cube.xml"), "--out", str(tmp_path / "f")]) == 2
    assert "fit renders views of that size; write a camera file with width and height" in capsys.readouterr().err


def test_the_overlay_shows_the_trackers_sites_on_request(clip, tmp_path):
    """--draw-sites: the overlay carries the edge fit's sites (cyan where matched) and their legend,
    for the tracker alone and for the hybrid; without it, none."""
    from hybridpose.estimator import HybridEstimator
    from hybridpose.geometry import load_camera
    from hybridpose.objects import load_object
    from hybridpose.registry import create
    from hybridpose.tracking import load_pose, read_frames, run_hybrid_on_frames, track_sequence
    from hybridpose.viz import SITE_COLOURS

    root, _ = clip
    truss, camera = load_object("truss"), load_camera(root / "camera.json")

    def cyan_pixels(run, **kw):
        seen = []
        run(list(read_frames(root / "png", camera))[:3], out=tmp_path / f"o{len(seen)}", max_frames=3,
            on_frame=lambda frame, result, overlay: seen.append(int(np.all(overlay == SITE_COLOURS["inlier"], -1).sum())),
            **kw)
        return seen

    def alone(frames, **kw):
        return track_sequence(frames, create("tracker", "edges", object=truss), load_pose(root / "pose.json"), **kw)

    def hybrid(frames, **kw):
        return run_hybrid_on_frames(frames, HybridEstimator.from_names(object=truss), **kw)

    for run in (alone, hybrid):
        assert all(n > 100 for n in cyan_pixels(run, draw_sites=True)[1:])
        assert cyan_pixels(run) == [0, 0, 0]
    assert main(["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
                 "--init-pose", str(root / "pose.json"), "--max-frames", "2", "--draw-sites",
                 "--out", str(tmp_path / "cli")]) == 0


def test_track_with_the_suns_direction(clip, tmp_path, capsys):
    """The clip is lit by the renderer's sun: given its direction the tracker still holds the truss;
    a direction that is none is refused naming the option."""
    root, truth = clip
    args = ["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
            "--init-pose", str(root / "pose.json")]
    sun = ",".join(str(x) for x in SpaceLighting().sun_direction_cam)
    assert main([*args, "--sun-dir", sun, "--out", str(tmp_path / "run")]) == 0
    poses, _ = _read_poses(tmp_path / "run" / "poses.csv")
    assert np.median([rotation_error_deg(p, t) for p, t in zip(poses, truth)]) < 1.0
    assert main([*args, "--sun-dir", "0,0", "--out", str(tmp_path / "bad")]) == 2
    assert "--sun-dir: expected x,y,z" in capsys.readouterr().err


def test_the_suns_direction_over_time_from_a_sun_sensor_log(clip, tmp_path, capsys):
    """--sun-dir FILE.csv: by time, interpolated between rows and held beyond them; by frame, only
    the listed frames; a bad log refused naming its line."""
    from hybridpose.core import Frame
    from hybridpose.geometry import Camera
    from hybridpose.tracking import with_sun

    frames = [Frame(np.zeros((4, 4, 3), np.uint8), Camera.default().scaled(4), k / 10, k) for k in range(4)]
    (tmp_path / "sun.csv").write_text("timestamp_s,x,y,z\n0.05,1,0,0\n0.25,0,1,0\n")
    got = [f.sun_direction_cam for f in with_sun(frames, str(tmp_path / "sun.csv"))]
    np.testing.assert_allclose(got[0], [1, 0, 0])                         # before the first row: held
    np.testing.assert_allclose(got[1], [0.75, 0.25, 0] / np.hypot(0.75, 0.25))  # 0.1 s: a quarter of the way
    np.testing.assert_allclose(got[3], [0, 1, 0])                         # after the last: held
    (tmp_path / "by_frame.csv").write_text("frame,x,y,z\n1,0,0,1\n")
    assert [f.sun_direction_cam is None for f in with_sun(frames, str(tmp_path / "by_frame.csv"))] == [True, False, True, True]
    root, truth = clip
    sun = SpaceLighting().sun_direction_cam
    (tmp_path / "log.csv").write_text("timestamp_s,x,y,z\n" + "".join(f"{t},{sun[0]},{sun[1]},{sun[2]}\n" for t in (0, 1)))
    args = ["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
            "--init-pose", str(root / "pose.json")]
    assert main([*args, "--sun-dir", str(tmp_path / "log.csv"), "--out", str(tmp_path / "run")]) == 0
    poses, _ = _read_poses(tmp_path / "run" / "poses.csv")
    assert np.median([rotation_error_deg(p, t) for p, t in zip(poses, truth)]) < 1.0
    (tmp_path / "bad.csv").write_text("timestamp_s,x,y,z\n0,1,0,0\n0.1,0,0,0\n")
    assert main([*args, "--sun-dir", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "b")]) == 2
    assert "bad.csv: line 3: expected numbers timestamp_s, x, y, z" in capsys.readouterr().err
    (tmp_path / "cols.csv").write_text("t,sx,sy,sz\n0,1,0,0\n")
    assert main([*args, "--sun-dir", str(tmp_path / "cols.csv"), "--out", str(tmp_path / "c")]) == 2
    assert "expected a header with timestamp_s (or frame), x, y, z" in capsys.readouterr().err


def test_pose_file_formats_agree(tmp_path):
    q = np.array([0.9, 0.1, -0.3, 0.2])
    p = Pose.from_quat_t(q / np.linalg.norm(q), [0.05, -0.02, 0.7])
    files = {
        "quat.json": {"quat_wxyz": p.quat_wxyz.tolist(), "t_m": p.t.tolist()},
        "R.json": {"R": p.R.tolist(), "t_m": p.t.tolist()},
        "bop.json": pose_to_bop(p),
    }
    for name, data in files.items():
        (tmp_path / name).write_text(json.dumps(data))
        assert load_pose(tmp_path / name).allclose(p, atol=1e-9), name
    (tmp_path / "bad.json").write_text(json.dumps({"quat_wxyz": [1, 0, 0, 0]}))
    with pytest.raises(ValueError, match="bad.json: missing t_m"):
        load_pose(tmp_path / "bad.json")


def test_track_errors_name_the_problem(clip, tmp_path, capsys):
    root, _ = clip
    small = Camera.default().scaled(320)
    (tmp_path / "small.json").write_text(json.dumps(small.to_dict()))
    args = ["--object", "truss", "--init-pose", str(root / "pose.json"), "--out", str(tmp_path / "x")]
    assert main(["track", str(root / "png"), "--camera", str(tmp_path / "small.json"), *args]) == 2
    assert "640×480 but the camera file says 320×320" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["track", str(tmp_path / "empty"), "--camera", str(root / "camera.json"), *args]) == 2
    assert "no images" in capsys.readouterr().err
    behind = tmp_path / "behind.json"
    behind.write_text(json.dumps({"quat_wxyz": [1, 0, 0, 0], "t_m": [0, 0, -1]}))
    assert main(["track", str(root / "png"), "--camera", str(root / "camera.json"), "--object", "truss",
                 "--init-pose", str(behind), "--out", str(tmp_path / "y")]) == 2
    err = capsys.readouterr().err
    # on a line of its own, not glued onto the progress bar's
    assert "behind the camera" in err and any(line.startswith("hybridpose track: error") for line in err.splitlines())
    # a run that failed before its first frame leaves no folder behind
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_track_without_an_initial_pose_runs_the_hybrid(clip, tmp_path, capsys):
    root, truth = clip
    rc = main(["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
               "--out", str(tmp_path / "hyb")])
    assert rc == 0
    out = tmp_path / "hyb"
    with open(out / "poses.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(truth) and rows[0]["status"] == "init" and "regressor:default" in rows[0]["sources"]
    trusted = [(r, t) for r, t in zip(rows, truth) if r["status"] != "lost" and r["qw"]]
    errs = [rotation_error_deg(Pose.from_quat_t([float(r[k]) for k in ("qw", "qx", "qy", "qz")],
                                                [float(r[k]) for k in ("tx_m", "ty_m", "tz_m")]), t) for r, t in trusted]
    assert len(errs) >= 10 and np.median(errs) < 1.0
    assert len(list(out.glob("overlay.*"))) == 1 and "with the hybrid" in capsys.readouterr().out
    record = json.loads((out / "run.json").read_text())
    assert record["mode"] == "hybrid" and record["policy"]["fields"]["check_period"] == 10 and record["reinits"] >= 0
    # each trusted pose comes with its 1-σ: small against the truss, and the truth mostly within 3 σ of it
    sd = np.array([[float(r[k]) for k in ("sd_rx_deg", "sd_ry_deg", "sd_rz_deg", "sd_tx_m", "sd_ty_m", "sd_tz_m")]
                   for r, _ in trusted])
    assert np.all(sd > 0) and np.all(sd[:, :3] < 5.0) and np.all(sd[:, 3:] < 0.05)
    t_err = np.array([[float(r[k]) for k in ("tx_m", "ty_m", "tz_m")] - t.t for r, t in trusted])
    assert np.mean(np.abs(t_err) <= 3 * sd[:, 3:]) >= 0.8
    # the whole camera-frame covariance too (upper triangle): its diagonal is the σ², and it is one
    from hybridpose.tracking import COV_FIELDS

    r0 = trusted[0][0]
    upper = np.array([float(r0[k]) for k in COV_FIELDS])
    cov = np.zeros((6, 6))
    cov[np.triu_indices(6)] = upper
    cov = cov + np.triu(cov, 1).T
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), np.r_[np.radians(sd[0, :3]), sd[0, 3:]], atol=2e-6)  # σ columns: µm, 1e-4°
    assert np.all(np.linalg.eigvalsh(cov) > 0) and len(COV_FIELDS) == 21 and "cov_rx_tz" in COV_FIELDS


def test_a_hybrid_that_never_started_says_why_and_what_to_do(clip, tmp_path, capsys):
    """A run from no initial pose whose starts the image never confirmed ends saying the best fit's quality
    against the bars, and what to give instead."""
    root, truth = clip
    rc = main(["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
               "--out", str(tmp_path / "never"), "--max-frames", "3", "--hybrid-option", "start_quality=1.0"])
    out = capsys.readouterr().out
    assert rc == 0 and "track: the hybrid never started: the best fit from a network pose scored 0." in out
    assert "a start needs 1 (start_quality" in out and "--init-pose FILE" in out
    from hybridpose.hybrid_config import HybridConfig
    from hybridpose.tracking import never_started_text

    assert "no network pose gave a fit of the model at all" in never_started_text(0.0, HybridConfig())


def test_tracker_options_reach_the_tracker(clip, tmp_path, capsys):
    root, _ = clip
    args = ["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"),
            "--init-pose", str(root / "pose.json"), "--tracker", "edges", "--max-frames", "4"]
    # no fit reaches quality 1: every frame after the first (the given initial pose) flagged lost
    assert main([*args, "--tracker-option", "lost_quality=1", "--tracker-option", "explain=false",
                 "--out", str(tmp_path / "o")]) == 0
    assert "3 flagged lost" in capsys.readouterr().out
    assert main([*args, "--tracker-option", "search=3", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "--tracker-option: expected NAME=VALUE with a name among search_px" in err and "explain" in err
    assert main([*args, "--tracker-option", "explain=maybe", "--out", str(tmp_path / "q")]) == 2
    assert "explain: expected true or false" in capsys.readouterr().err
    assert main([*args, "--regressor-option", "fine_tiles=true", "--out", str(tmp_path / "r")]) == 2
    assert "--regressor-option: the tracker alone runs from --init-pose" in capsys.readouterr().err
    assert main([*args, "--hybrid-option", "reacquire_deg=20", "--out", str(tmp_path / "s")]) == 2
    assert "--hybrid-option: the tracker alone runs from --init-pose" in capsys.readouterr().err


def test_hybrid_options_reach_the_policy(clip, tmp_path, capsys, monkeypatch):
    from hybridpose.estimator import HybridEstimator

    root, _ = clip
    seen = []
    original = HybridEstimator.from_names.__func__

    def spy(cls, *a, **kw):
        est = original(cls, *a, **kw)
        seen.append(est.config)
        return est

    monkeypatch.setattr(HybridEstimator, "from_names", classmethod(spy))
    args = ["track", str(root / "png"), "--object", "truss", "--camera", str(root / "camera.json"), "--max-frames", "2"]
    assert main([*args, "--hybrid-option", "reacquire_deg=20", "--hybrid-option", "keep_quality=none",
                 "--out", str(tmp_path / "h")]) == 0
    assert seen[0].reacquire_deg == 20 and seen[0].keep_quality is None and seen[0].check_period == 10
    assert "policy keep_quality=none, reacquire_deg=20;" in capsys.readouterr().out
    # a checkpoint that recommends a policy gets it with no flag; a flag still changes it
    from hybridpose.regressors.checkpoints import load_checkpoint, save_checkpoint, shipped_checkpoint

    save_checkpoint(tmp_path / "fitted.pt", {**load_checkpoint(shipped_checkpoint("default")),
                                             "hybrid_config": {"reacquire_deg": 20.0}})
    fitted = [*args, "--regressor", str(tmp_path / "fitted.pt")]
    assert main([*fitted, "--out", str(tmp_path / "f")]) == 0
    assert seen[-1].reacquire_deg == 20 and "policy reacquire_deg=20;" in capsys.readouterr().out
    assert main([*fitted, "--hybrid-option", "reacquire_deg=none", "--out", str(tmp_path / "g")]) == 0
    assert seen[-1] == HybridConfig() and "policy" not in capsys.readouterr().out
    assert main([*args, "--hybrid-option", "reacquire=20", "--out", str(tmp_path / "i")]) == 2
    assert "--hybrid-option: expected NAME=VALUE with a name among check_period" in capsys.readouterr().err
    assert main([*args, "--hybrid-option", "reacquire_deg=0", "--out", str(tmp_path / "j")]) == 2
    assert "reacquire_deg: expected an angle" in capsys.readouterr().err


def test_backend_options_read_values_as_the_defaults_types():
    from hybridpose.registry import backend_options
    from hybridpose.registry import get

    opts = backend_options(["explain=0", "search_px=12", "lost_quality=0.45", "covariance_scale=2"], get("tracker", "edges"), "-o")
    assert opts == {"explain": False, "search_px": 12, "lost_quality": 0.45, "covariance_scale": 2.0}
    assert isinstance(opts["search_px"], int) and isinstance(opts["covariance_scale"], float)
    assert backend_options(["lost_quality=none"], get("tracker", "edges"), "-o") == {"lost_quality": None}
    with pytest.raises(ValueError, match="-o: search_px: expected a number"):
        backend_options(["search_px=wide"], get("tracker", "edges"), "-o")
    # every registered tracker names the keywords it takes, factories of several variants too
    for name in ("klt-pnp", "rapid", "rapid-ols", "rapid-gos"):
        assert backend_options(["lost_quality=0.4"], get("tracker", name), "-o") == {"lost_quality": 0.4}
    assert backend_options(["refine=false"], get("tracker", "rapid-gos"), "-o") == {"refine": False}
    assert backend_options(["modalities=texture, region"], get("tracker", "combined"), "-o") == {
        "modalities": ("texture", "region")}
    with pytest.raises(ValueError, match="-o: expected NAME=VALUE"):
        backend_options(["variant=rapid"], get("tracker", "rapid-gos"), "-o")


def test_regressor_options_are_keypoint_options(tmp_path, capsys):
    from hybridpose.registry import backend_options
    from hybridpose.regressors.options import KeypointOptions

    opts = backend_options(["fine_tiles=true", "turns=off", "passes=2", "max_depth_m=none"], KeypointOptions, "-r")
    assert opts == {"fine_tiles": True, "turns": "off", "passes": "2", "max_depth_m": None}
    assert KeypointOptions(**opts).passes == 2
    with pytest.raises(ValueError, match="-r: expected NAME=VALUE with a name among check_twins"):
        backend_options(["fine=true"], KeypointOptions, "-r")


def test_by_default_track_takes_edges_on_black_space_and_combined_on_a_lit_scene(clip, tmp_path, capsys):
    """``--tracker`` left out: the space clip (black around the truss) gets ``edges``; the same frames on a
    lit grey background — a lab, not space — get ``combined``; the choice is said and recorded."""
    root, _ = clip
    lit = tmp_path / "lit"
    lit.mkdir()
    for f in sorted((root / "png").iterdir())[:3]:
        cv2.imwrite(str(lit / f.name), np.maximum(cv2.imread(str(f)), 90))
    base = ["--object", "truss", "--camera", str(root / "camera.json"), "--init-pose", str(root / "pose.json"),
            "--max-frames", "3"]
    for source, expected in ((root / "png", "edges"), (lit, "combined")):
        out = tmp_path / f"run_{expected}"
        assert main(["track", str(source), *base, "--out", str(out)]) == 0
        said = capsys.readouterr().out
        assert f"track: tracker {expected} (auto:" in said and f"frames with {expected}" in said
        options = json.loads((out / "run.json").read_text())["options"]
        assert options["tracker"] == expected and options["tracker_chosen"].startswith("auto:")


def test_auto_tracker_reads_the_dark_share_of_the_first_frame():
    from hybridpose.tracking import SPACE_DARK_SHARE, auto_tracker

    space = np.zeros((48, 64, 3), np.uint8)
    space[10:30, 10:30] = 200  # the part, lit, on black
    assert auto_tracker(space)[0] == "edges" and auto_tracker(space)[1] == pytest.approx(1 - 400 / (48 * 64))
    lab = np.full((48, 64, 3), 120, np.uint8)
    assert auto_tracker(lab) == ("combined", 0.0)
    half = np.zeros((48, 64, 3), np.uint8)
    half[:, 32 + int(64 * (0.5 - SPACE_DARK_SHARE)):] = 50
    assert auto_tracker(half)[0] == "edges"  # at the threshold: space
    with pytest.raises(ValueError, match="image: expected"):
        auto_tracker(np.zeros((48, 64), np.uint8))


def test_an_overlay_is_encoded_beside_the_run_and_a_failed_encoding_is_said_at_close(tmp_path):
    """The overlay's frames are encoded on a thread of their own: what the caller wrote is what the
    video holds (it may reuse its image at once), at the rate asked; an encoder that fails says so at
    close, in the caller's thread, and leaves no partial file."""
    import threading

    from hybridpose.io import VideoFile

    video = VideoFile(tmp_path / "ok", 25.0, (64, 48))
    for k in range(5):
        image = np.full((48, 64, 3), 40 * k, np.uint8)
        video.write(image)
        image[:] = 255  # reused by the caller
    cap = cv2.VideoCapture(str(video.close()))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 5 and cap.get(cv2.CAP_PROP_FPS) == pytest.approx(25)
    shades = [cap.read()[1].mean() for _ in range(5)]
    assert np.allclose(shades, [0, 40, 80, 120, 160], atol=8), shades

    class FullDisk:
        def write(self, bgr):
            assert threading.current_thread() is not threading.main_thread()  # beside the run, not in it
            raise cv2.error("no space left on device")

        def release(self):
            pass

    video = VideoFile(tmp_path / "bad", 25.0, (64, 48))
    video.writer.release()
    video.writer = FullDisk()
    video.write(np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(cv2.error, match="no space left"):
        video.close()
    assert not [p.name for p in tmp_path.iterdir() if "bad" in p.name]
