"""A real camera's effects on training views (hybridpose.render.camera_effects): seeded, shape-keeping,
each effect what it says, and only where the look is a bench's, not space's."""
import numpy as np
import pytest

from hybridpose.render import AppearanceSpec
from hybridpose.render.camera_effects import camera_effects, jpeg, motion_blur


def _scene(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.full((60, 80, 3), 90, np.uint8)
    img[20:40, 25:55] = rng.integers(120, 255, 3)
    return img


def test_seeded_and_shape_keeping():
    img = _scene()
    a, b = camera_effects(img, 7), camera_effects(img, 7)
    assert a.shape == img.shape and a.dtype == np.uint8 and np.array_equal(a, b)
    assert any(not np.array_equal(camera_effects(img, s), a) for s in range(8, 12))


def test_motion_blur_smears_a_point_along_its_direction_only():
    img = np.zeros((41, 41, 3), np.uint8)
    img[20, 20] = 255
    out = motion_blur(img, (1.0, 0.0), 9.0)[..., 0]
    rows, cols = np.nonzero(out)
    assert set(rows) == {20} and cols.min() >= 15 and cols.max() <= 25 and len(cols) >= 9
    assert np.array_equal(motion_blur(img, (1.0, 0.0), 0.5), img)  # under a pixel: nothing


def test_jpeg_round_trip_is_close_and_lossy():
    img = _scene(1)
    out = jpeg(img, 40)
    assert out.shape == img.shape and np.abs(out.astype(int) - img).mean() < 6
    assert not np.array_equal(out, img)


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="image: expected"):
        camera_effects(np.zeros((10, 10), np.uint8))


def test_only_a_bench_look_draws_them_and_old_configs_still_match():
    with pytest.raises(ValueError, match="camera_effects"):
        AppearanceSpec("space", camera_effects=True)
    assert "camera_effects" not in AppearanceSpec("random").record()
    assert AppearanceSpec("random", camera_effects=True).record()["camera_effects"] is True


def test_training_views_get_them(tmp_path, truss):
    """Two renders of the same views, with and without: the same poses, different pixels; the fit's
    bench look asks for them, its space look not."""
    from hybridpose.datasets import BopScene, render_random_dataset
    from hybridpose.fit import training_render_settings
    from hybridpose.geometry import Camera

    cam = Camera.default().scaled((160, 120))
    kw = dict(in_view=True, seed=3)
    plain = BopScene(render_random_dataset(tmp_path / "plain", truss, cam, 2, appearance=AppearanceSpec("random"), **kw))
    real = BopScene(render_random_dataset(tmp_path / "camera", truss, cam, 2,
                                          appearance=AppearanceSpec("random", camera_effects=True), **kw))
    for i in plain.image_ids:
        assert np.allclose(plain.image(i).pose.matrix, real.image(i).pose.matrix)
        assert not np.array_equal(plain.rgb(i), real.rgb(i))
    assert training_render_settings(None, (1.0, 2.0))["appearance"].camera_effects
    assert not training_render_settings(None, (1.0, 2.0), look="space")["appearance"].camera_effects
