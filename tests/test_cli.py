"""The commands of issue 3 run as a user types them (in-process, tiny sizes)."""
import json

import numpy as np
import pytest

from hybridpose.cli import main
from hybridpose.io import read_image


def test_render_random_and_sequence_then_verify(tmp_path, capsys):
    out = tmp_path / "rand"
    assert main(["render", "--object", "truss", "--kind", "random", "--count", "4", "--size", "64", "--seed", "0", "--out", str(out)]) == 0
    assert (out / "labels.csv").read_text().count("\n") == 5
    seq = tmp_path / "seq"
    assert main(["render", "--object", "truss", "--kind", "sequence", "--trajectory", "tumble", "--occlusion", "arm",
                 "--frames", "10", "--fps", "30", "--size", "160x120", "--seed", "1", "--out", str(seq)]) == 0
    cfg = json.loads((seq / "hybridpose.json").read_text())
    assert cfg["camera"]["width"] == 160 and cfg["camera"]["fx"] == pytest.approx(150.0)
    sheet = tmp_path / "verify.png"
    assert main(["verify", str(seq), "--out", str(sheet)]) == 0
    assert "IoU mean 0.9" in capsys.readouterr().out
    img = read_image(sheet)
    assert img.shape[2] == 3 and img.max() > 0 and (img[..., 1] == 255).any()  # green wireframe
    magenta = (img[..., 0] > 200) & (img[..., 1] < 80) & (img[..., 2] > 200)
    assert magenta.sum() > 500  # the mask's outline shows, not hidden under the wireframe


def test_render_views_near_edge_on(tmp_path, truss):
    from hybridpose.datasets import read_labels
    from hybridpose.objects import view_elevation_deg

    out = tmp_path / "edge_on"
    args = ["render", "--object", "truss", "--kind", "random", "--count", "3", "--size", "64", "--seed", "0",
            "--in-view", "--elevation", "0,12", "--out", str(out)]
    assert main(args) == 0
    labels = read_labels(out / "labels.csv")
    assert len(labels) == 3
    assert all(view_elevation_deg(lb.pose, truss) <= 12.0 for lb in labels)
    assert json.loads((out / "hybridpose.json").read_text())["elevation_range_deg"] == [0.0, 12.0]
    assert main(args) == 0  # the same job resumes
    assert main(args[:-4] + ["--out", str(out)]) == 2  # another band is another dataset


def test_cli_errors_are_clear(tmp_path, capsys):
    assert main(["render", "--object", str(tmp_path / "nope.stl"), "--kind", "random", "--count", "1", "--out", str(tmp_path / "x")]) == 2
    assert "neither a built-in object" in capsys.readouterr().err
    assert main(["verify", str(tmp_path / "missing")]) == 2
    assert "dataset not found" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["render", "--kind", "sequence", "--trajectory", "spiral", "--out", str(tmp_path / "y")])
    assert main(["eval", "--checkpoint", "defualt", "--data", str(tmp_path), "--out", str(tmp_path / "r")]) == 2
    assert "defualt: checkpoint not found (no such file, and not the name of one shipped" in capsys.readouterr().err


def test_demo(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "demo"), "--frames", "12", "--size", "160x120"]) == 0
    assert (tmp_path / "demo" / "verify.png").is_file()
    assert np.asarray(read_image(tmp_path / "demo" / "verify.png")).mean() > 1
    # at 160×120 the CNN never starts the hybrid: no tracked frame, no picture of the tracker's sites
    assert not (tmp_path / "demo" / "sites.png").exists()
    out = capsys.readouterr().out
    assert "1st frame" in out and "demo: the hybrid never started" in out


def test_a_camera_with_lens_distortion_renders_through_its_pinhole(tmp_path, capsys):
    import json

    (tmp_path / "lens.json").write_text(json.dumps({"width": 160, "height": 120, "fx": 150, "fy": 150, "cx": 79.5,
                                                    "cy": 59.5, "dist": [-0.2, 0.05, 0, 0, 0]}))
    assert main(["render", "--camera", str(tmp_path / "lens.json"), "--kind", "random", "--count", "1",
                 "--out", str(tmp_path / "ds")]) == 0
    assert "pinhole model (same K" in capsys.readouterr().out
    written = json.loads((tmp_path / "ds" / "camera.json").read_text())
    assert written["fx"] == 150 and not written.get("dist")


def test_the_demos_picture_of_the_edge_sites(truss):
    """The demo's sites.png: the object's box enlarged to at least 560 px, cyan sites on the truss."""
    from hybridpose.cli.tracking import sites_picture
    from hybridpose.core import Estimate, Frame
    from hybridpose.geometry import Camera, Pose
    from hybridpose.registry import create
    from hybridpose.render import Renderer

    cam, pose = Camera.default(), Pose.from_rotvec_t([0.4, -0.3, 0.2], [0.0, 0.0, 0.7])
    with Renderer(truss, cam) as r:
        frame = Frame(r.render(pose).rgb, cam, 0.0)
    trk = create("tracker", "edges", object=truss)
    trk.init(frame, pose)
    m = trk.track(frame)
    picture = sites_picture(frame, Estimate(pose=m.pose, covariance=m.covariance, timestamp=0.0, status="tracking"),
                            trk.last_sites, truss)
    assert picture.shape[1] >= 560 and np.all(picture == (0, 255, 255), axis=-1).sum() > 200


def test_user_mesh_in_mm_renders_and_verifies_from_the_dataset_model(tmp_path, truss, capsys):
    mesh = truss.mesh.copy()
    mesh.apply_scale(1000.0)
    mesh.export(tmp_path / "part_mm.stl")
    ds = tmp_path / "ds"
    assert main(["render", "--object", str(tmp_path / "part_mm.stl"), "--scale", "0.001", "--kind", "random",
                 "--count", "3", "--size", "160x120", "--out", str(ds)]) == 0
    assert main(["verify", str(ds), "--out", str(tmp_path / "v.png")]) == 0  # reads models/obj_000001.ply (mm)
    assert "IoU mean 0.9" in capsys.readouterr().out


def test_train_verifier_runs_as_typed(tmp_path, capsys):
    data = tmp_path / "views"
    assert main(["render", "--object", "truss", "--kind", "random", "--count", "6", "--size", "160x120", "--seed", "2",
                 "--in-view", "--out", str(data)]) == 0
    out = tmp_path / "tv"
    args = ["train-verifier", "--data", str(data), "--out", str(out), "--epochs", "1", "--width", "8", "--batch", "2"]
    assert main(args) == 0
    assert "best validation accuracy" in capsys.readouterr().out
    assert (out / "best.pt").is_file() and (out / "pairs" / "meta.json").is_file()
    # without --label-max-deg the library's bound applies (one definition, not a second CLI literal)
    from hybridpose.training.train_verifier import LABEL_MAX_DEG

    assert json.loads((out / "pairs" / "meta.json").read_text())["label_max_deg"] == LABEL_MAX_DEG
    assert main(args[:5] + ["--epochs", "0"]) == 2
    assert "--epochs: expected at least 1" in capsys.readouterr().err


def test_train_options_are_parsed_by_the_train_command(capsys):
    """`hybridpose train` keeps its options with the trainer (so the other commands start without
    torch); its --help and its errors still come from them, and other commands keep refusing
    unknown options."""
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    assert "--model" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["train", "--model", "nope", "--data", "x", "--out", "y"])
    assert "invalid choice: 'nope'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["verify", "x", "--out", "y", "--bogus"])
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err


def test_the_demo_says_which_path_brought_the_track_back():
    from hybridpose.cli.tracking import recoveries_text

    assert recoveries_text(["init", "tracking", "lost", "lost", "reinit", "tracking"]) == \
        "lost from frame 2, back at frame 4: the CNN re-initialised it"
    assert recoveries_text(["init", "tracking", "lost", "tracking"]).endswith("the tracker resumed from the prediction")
    assert recoveries_text(["init", "tracking"]) == "never lost the truss"
    assert recoveries_text(["init", "init"]).startswith("the hybrid never started")
    assert recoveries_text(["tracking", "lost"]).startswith("lost the truss and did not come back")
