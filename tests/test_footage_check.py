"""A network checked on the user's own frames without labels: how often the tracker confirms its pose."""
import numpy as np
import pytest

from hybridpose.footage_check import check_on_footage
from hybridpose.geometry import Camera
from hybridpose.io import write_image


@pytest.fixture(scope="module")
def clear_frames(tmp_path_factory):
    """Six frames of the truss tumbling in the sun, as an image folder."""
    from hybridpose.datasets import render_sequence_dataset
    from hybridpose.objects import load_object
    from hybridpose.render.sequences import SequenceSpec

    root = tmp_path_factory.mktemp("footage")
    scene = render_sequence_dataset(root / "seq", load_object("truss"), Camera.default(),
                                    SequenceSpec(trajectory="tumble", frames=6, fps=30.0, seed=2))
    return scene / "rgb"


def test_the_shipped_network_is_confirmed_on_clear_frames_of_its_part(clear_frames):
    from hybridpose.objects import load_object

    check = check_on_footage(clear_frames, load_object("truss"), Camera.default(), "default", tracker="edges", frames=3)
    assert check.video_frames == 6 and check.frames == 3
    assert check.confirmed >= 2 and check.found >= check.confirmed
    assert "confirmed the start from it on **" in check.text() and check.confirmed_at[0] in (0, 2, 3, 5)


def test_nothing_is_confirmed_on_frames_without_the_part(tmp_path):
    from hybridpose.objects import load_object

    for k in range(3):
        write_image(tmp_path / f"{k:03d}.png", np.full((480, 640, 3), 30, np.uint8))
    check = check_on_footage(tmp_path, load_object("truss"), Camera.default(), "default", tracker="edges")
    assert check.frames == 3 and check.confirmed == 0 and check.confirmed_at == ()
    assert "**0 (0 %)**" in check.text() and "will not start" in check.text()


def test_fit_refuses_a_video_that_is_not_there_before_fitting(tmp_path, capsys):
    from hybridpose.cli import main

    assert main(["fit", "truss", "--out", str(tmp_path / "f"), "--video", str(tmp_path / "none.mp4")]) == 2
    assert "--video:" in capsys.readouterr().err and not (tmp_path / "f").exists()
    assert main(["fit", "truss", "--out", str(tmp_path / "f"), "--video", str(tmp_path), "--video-tracker", "nope"]) == 2
    assert "unknown tracker 'nope'" in capsys.readouterr().err
