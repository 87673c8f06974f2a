"""Randomised looks for the world outside space: backgrounds, ambient and fill lights, part colour."""
import json

import cv2
import numpy as np
import pytest

from hybridpose.cli import main
from hybridpose.datasets import BopScene, render_random_dataset
from hybridpose.geometry import Camera, Pose
from hybridpose.metrics import rotation_error_deg
from hybridpose.render import Appearance, AppearanceSpec, Renderer, clutter_background, random_appearance
from hybridpose.render.appearance import PhotoBackgrounds

CAM = Camera.default().scaled((160, 120))
# the sun travels towards the camera: the faces the camera sees are unlit
BACKLIT = (0.0, 0.0, -1.0)


@pytest.fixture(scope="module")
def renderer(truss):
    with Renderer(truss, CAM) as r:
        yield r


def pose():
    return Pose.from_rotvec_t([0.4, -0.3, 0.2], [0.0, 0.0, 0.8])


def test_space_is_what_it_was_without_an_appearance(renderer):
    plain = renderer.render(pose(), rng=0)
    space = renderer.render(pose(), rng=0, appearance=Appearance())
    assert np.array_equal(plain.rgb, space.rgb)
    # and a random look leaves nothing behind for the next space render
    renderer.render(pose(), rng=0, appearance=random_appearance(CAM.width, CAM.height, 3))
    assert np.array_equal(renderer.render(pose(), rng=0).rgb, plain.rgb)


def test_background_colour_ambient_and_fill_lights_change_what_they_should(renderer):
    base = renderer.render(pose(), rng=0, sun_direction_cam=BACKLIT)
    obj = base.mask_visib
    # background: away from the silhouette, whose anti-aliased rim belongs to neither
    bg_px = cv2.dilate(obj.astype(np.uint8), np.ones((5, 5), np.uint8)) == 0
    assert base.rgb[obj].mean() < 5 and base.rgb[bg_px].max() == 0  # back-lit in space: nothing to see

    bg = clutter_background(CAM.width, CAM.height, 1)
    with_bg = renderer.render(pose(), rng=0, sun_direction_cam=BACKLIT, appearance=Appearance(background=bg))
    assert np.array_equal(with_bg.rgb[bg_px], bg[bg_px]) and np.array_equal(with_bg.rgb[obj], base.rgb[obj])

    lit = renderer.render(pose(), rng=0, sun_direction_cam=BACKLIT, appearance=Appearance(ambient=0.4))
    assert lit.rgb[obj].mean() > 40  # the ambient light shows the unlit faces

    red = renderer.render(pose(), rng=0, sun_direction_cam=BACKLIT,
                          appearance=Appearance(ambient=0.4, object_rgb=(1.0, 0.1, 0.1)))
    r, g = red.rgb[obj][:, 0].mean(), red.rgb[obj][:, 1].mean()
    assert r > 3 * g

    fill = renderer.render(pose(), rng=0, sun_direction_cam=BACKLIT,
                           appearance=Appearance(fill_lights=(((0.0, 0.0, 1.0), 1.0),)))
    assert fill.rgb[obj].mean() > 40  # a light from behind the camera


def test_appearance_draws_are_seeded_by_image_index():
    spec = AppearanceSpec("random")
    a, b, c = spec.draw(64, 48, seed=3, index=5), spec.draw(64, 48, seed=3, index=5), spec.draw(64, 48, seed=3, index=6)
    assert np.array_equal(a.background, b.background) and a.ambient == b.ambient and a.object_rgb == b.object_rgb
    assert not np.array_equal(a.background, c.background)
    assert AppearanceSpec().draw(64, 48, 3, 5) is None


def test_photo_backgrounds_cover_the_frame(tmp_path):
    rng = np.random.default_rng(0)
    for i, (h, w) in enumerate([(30, 40), (200, 90)]):
        cv2.imwrite(str(tmp_path / f"p{i}.jpg"), rng.integers(0, 255, (h, w, 3), dtype=np.uint8))
    (tmp_path / "notes.txt").write_text("not a photo")
    photos = PhotoBackgrounds(tmp_path)
    assert len(photos.files) == 2
    for k in range(4):
        img = photos.draw(64, 48, k)
        assert img.shape == (48, 64, 3) and img.dtype == np.uint8
    spec = AppearanceSpec("random", backgrounds=str(tmp_path))
    assert spec.draw(64, 48, 0, 0).background.shape == (48, 64, 3)


def test_bad_appearance_input_is_refused(tmp_path):
    with pytest.raises(ValueError, match="no photos"):
        PhotoBackgrounds(tmp_path)
    with pytest.raises(ValueError, match="not a folder"):
        AppearanceSpec("random", backgrounds=str(tmp_path / "missing"))
    with pytest.raises(ValueError, match="only with appearance 'random'"):
        AppearanceSpec("space", backgrounds=str(tmp_path))
    with pytest.raises(ValueError, match="appearance: expected one of"):
        AppearanceSpec("studio")
    with pytest.raises(ValueError, match="ambient"):
        Appearance(ambient=2.0)
    with pytest.raises(ValueError, match="object_rgb"):
        Appearance(object_rgb=(1.0, 2.0, 0.0))
    with pytest.raises(ValueError, match="background"):
        Appearance(background=np.zeros((4, 4), np.uint8))


def test_random_look_dataset_keeps_the_poses_and_resumes(truss, tmp_path):
    space = render_random_dataset(tmp_path / "space", truss, CAM, 4, seed=2, in_view=True)
    looks = AppearanceSpec("random")
    scene = render_random_dataset(tmp_path / "rand", truss, CAM, 4, seed=2, in_view=True, appearance=looks)
    a, b = BopScene(space), BopScene(scene)
    for i in a.image_ids:
        assert np.allclose(a.image(i).pose.matrix, b.image(i).pose.matrix)  # same poses for the seed
        assert b.rgb(i).mean() > a.rgb(i).mean() + 10  # a background instead of black space
    config = json.loads((tmp_path / "rand" / "hybridpose.json").read_text())
    assert config["appearance"] == {"kind": "random", "backgrounds": None, "photo_share": 0.5, "fixed": False}
    before = {p.name: p.read_bytes() for p in (scene / "rgb").iterdir()}
    (scene / "rgb" / sorted(before)[-1]).unlink()
    render_random_dataset(tmp_path / "rand", truss, CAM, 4, seed=2, in_view=True, appearance=looks)
    assert {p.name: p.read_bytes() for p in (scene / "rgb").iterdir()} == before  # resumed, byte-identical


def test_render_command_takes_the_appearance_options(tmp_path, capsys):
    assert main(["render", "--kind", "random", "--count", "2", "--size", "96x72", "--appearance", "random",
                 "--out", str(tmp_path / "r")]) == 0
    assert main(["render", "--kind", "sequence", "--frames", "3", "--size", "96x72", "--appearance", "random",
                 "--out", str(tmp_path / "s")]) == 0
    scene = BopScene(tmp_path / "s" / "test" / "000000")
    masks = [np.asarray(cv2.imread(str(p), 0)) > 0 for p in sorted((scene.dir / "mask_visib").iterdir())]
    behind = ~(masks[0] | masks[1] | masks[2])
    assert behind.any() and np.array_equal(scene.rgb(0)[behind], scene.rgb(2)[behind])  # one background for the video
    assert scene.rgb(0)[behind].mean() > 5
    assert main(["render", "--kind", "random", "--count", "2", "--size", "96x72", "--backgrounds", str(tmp_path),
                 "--out", str(tmp_path / "b")]) == 2
    assert "only with appearance 'random'" in capsys.readouterr().err
    assert main(["render", "--kind", "random", "--count", "2", "--size", "96x72", "--appearance", "random",
                 "--texture-share", "0.5", "--out", str(tmp_path / "t")]) == 0
    assert json.loads((tmp_path / "t" / "hybridpose.json").read_text())["appearance"]["texture_share"] == 0.5
    assert main(["render", "--kind", "random", "--count", "2", "--size", "96x72", "--texture-share", "0.5",
                 "--out", str(tmp_path / "u")]) == 2
    assert "texture_share: a print on the part" in capsys.readouterr().err


def test_the_edge_tracker_keeps_a_part_in_front_of_clutter(tmp_path):
    """In front of a cluttered background the honest quality counts only the edges on and inside the
    part's outline: at the true pose the tracker is not lost (on black space nothing changes)."""
    import trimesh

    from hybridpose.core import Frame
    from hybridpose.edges.fit import background_edge_density, to_gray
    from hybridpose.objects import load_object
    from hybridpose.registry import create

    path = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.2, 0.12, 0.08)).export(path)
    box = load_object(str(path))
    cam = Camera.default().scaled((320, 240))
    poses = [Pose.from_rotvec_t([0.5, 0.3 + 0.02 * k, 0.1], [0.0, 0.0, 0.7]) for k in range(2)]
    # a busy background, as a photo of a bench is: random 6-px tiles
    tiles = np.random.default_rng(5).integers(0, 256, (cam.height // 6 + 1, cam.width // 6 + 1, 3), dtype=np.uint8)
    busy = np.ascontiguousarray(np.repeat(np.repeat(tiles, 6, 0), 6, 1)[:cam.height, :cam.width])
    look = Appearance(ambient=0.3, background=busy)
    with Renderer(box, cam) as r:
        images = [r.render(p, rng=k, appearance=look).rgb for k, p in enumerate(poses)]
        dark = r.render(poses[0], rng=0).rgb
    uv = cam.project(box.bbox_corners, poses[0])
    region = (*uv.min(0).astype(int), *uv.max(0).astype(int))
    assert background_edge_density(to_gray(images[0]), region) > 0.05 > background_edge_density(to_gray(dark), region)
    trk = create("tracker", "edges", object=box)
    trk.init(Frame(images[0], cam, 0.0, 0), poses[0])
    m = trk.track(Frame(images[1], cam, 1 / 30, 1), prior=poses[0])
    assert not m.lost and m.quality > 0.6 and rotation_error_deg(m.pose, poses[1]) < 1.0


def test_a_print_on_the_part_changes_only_the_part_and_no_other_draw(renderer):
    """``texture_share``: a share of the images get a print on the part, drawn from a stream of its own
    (the background, lights and colour of each image stay what they were), multiplied into the shaded
    part where it is seen; the config records it only where set."""
    plain, printed = AppearanceSpec("random"), AppearanceSpec("random", texture_share=0.5)
    looks = [(plain.draw(CAM.width, CAM.height, 3, i), printed.draw(CAM.width, CAM.height, 3, i)) for i in range(40)]
    for a, b in looks:
        assert np.array_equal(a.background, b.background) and a.ambient == b.ambient and a.object_rgb == b.object_rgb
        assert a.object_texture is None
    assert 10 <= sum(b.object_texture is not None for _, b in looks) <= 30
    assert "texture_share" not in plain.record() and printed.record()["texture_share"] == 0.5

    a, b = next((a, b) for a, b in looks if b.object_texture is not None)
    bare = renderer.render(pose(), rng=0, appearance=a)
    seen = renderer.render(pose(), rng=0, appearance=b)
    away = ~cv2.dilate(bare.mask_visib.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.array_equal(bare.rgb[away], seen.rgb[away])                  # the background untouched
    on = bare.mask_visib
    assert (seen.rgb[on].astype(int) <= bare.rgb[on].astype(int) + 2).all()  # a print only darkens (sensor noise aside)
    assert np.std(seen.rgb[on].astype(float) - bare.rgb[on]) > 3            # and varies over the part
    with pytest.raises(ValueError, match="texture_share: a print on the part is drawn only with appearance 'random'"):
        AppearanceSpec("space", texture_share=0.5)
    with pytest.raises(ValueError, match=r"texture_share: expected a share of the images in \[0, 1\]"):
        AppearanceSpec("random", texture_share=1.5)
    with pytest.raises(ValueError, match="object_texture: expected an"):
        Appearance(object_texture=np.zeros((4, 4), np.uint8))
