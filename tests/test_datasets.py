"""BOP round trip (mm in files, metres in memory), labels.csv, resume, errors, torch Dataset."""
import json
import pickle
import shutil

import cv2
import numpy as np
import pytest
import torch

from hybridpose.datasets import BopScene, find_scenes, read_labels, render_random_dataset, render_sequence_dataset
from hybridpose.datasets.torch_dataset import PoseDataset, split_indices
from hybridpose.geometry import Camera
from hybridpose.render import Renderer, random_poses
from hybridpose.render.sequences import SequenceSpec

CAM = Camera.default().scaled("96x72")


@pytest.fixture(scope="module")
def random_ds(truss, tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "rand"
    render_random_dataset(out, truss, CAM, count=10, seed=4)
    return out


def test_bop_files_are_in_mm_and_read_back_in_metres(random_ds, truss):
    scene_dir = find_scenes(random_ds)[0]
    assert scene_dir == random_ds / "train" / "000000"
    raw = json.loads((scene_dir / "scene_gt.json").read_text())
    poses = random_poses(10, CAM, rng=4)
    np.testing.assert_allclose(raw["3"][0]["cam_t_m2c"], poses[3].t * 1000, atol=1e-9)
    np.testing.assert_allclose(raw["3"][0]["cam_R_m2c"], poses[3].R.ravel(), atol=1e-12)
    scene = BopScene(scene_dir)
    assert scene.image_ids == list(range(10))
    gt = scene.image(3)
    assert gt.pose.allclose(poses[3], atol=1e-9)
    assert gt.camera == CAM
    assert scene.rgb(3).shape == (72, 96, 3)
    assert scene.mask(3).dtype == bool
    with Renderer(truss, CAM) as r:
        direct = r.render(poses[3])
    np.testing.assert_allclose(scene.depth_m(3), direct.depth, atol=0.5e-4)  # 0.1 mm units in the PNG
    assert np.array_equal(scene.mask(3), direct.mask_visib)
    info = json.loads((scene_dir / "scene_gt_info.json").read_text())["3"][0]
    assert 0 <= info["visib_fract"] <= 1 and len(info["bbox_obj"]) == 4
    models_info = json.loads((random_ds / "models" / "models_info.json").read_text())
    assert 420 < models_info["1"]["diameter"] < 440  # mm


def test_labels_csv(random_ds):
    labels = read_labels(random_ds / "labels.csv")
    scene = BopScene(find_scenes(random_ds)[0])
    assert len(labels) == 10
    assert labels[2].image == "train/000000/rgb/000002.png" and (random_ds / labels[2].image).is_file()
    assert labels[2].pose.allclose(scene.image(2).pose, atol=1e-8)


def test_interrupted_render_resumes_to_identical_files(truss, tmp_path):
    full = tmp_path / "full"
    render_random_dataset(full, truss, CAM, count=6, seed=9)

    part = tmp_path / "part"

    class Stop(Exception):
        pass

    def interrupt(done, total):
        if done == 3:
            raise Stop

    with pytest.raises(Stop):
        render_random_dataset(part, truss, CAM, count=6, seed=9, progress=interrupt)
    calls = []
    render_random_dataset(part, truss, CAM, count=6, seed=9, progress=lambda d, t: calls.append(d))
    for sub in ("rgb", "mask_visib", "depth"):
        for f in sorted((full / "train" / "000000" / sub).iterdir()):
            assert f.read_bytes() == (part / "train" / "000000" / sub / f.name).read_bytes(), f
    for name in ("scene_gt.json", "scene_gt_info.json", "scene_camera.json", "scene_meta.json"):
        assert (full / "train/000000" / name).read_text() == (part / "train/000000" / name).read_text()
    assert not list(part.rglob("*.tmp"))
    # a finished job re-run renders nothing
    calls.clear()
    render_random_dataset(part, truss, CAM, count=6, seed=9, progress=lambda d, t: calls.append(d))
    assert calls == []
    with pytest.raises(ValueError, match="differs in: seed"):
        render_random_dataset(part, truss, CAM, count=6, seed=10)


def test_render_workers_write_the_same_dataset_and_resume(truss, tmp_path):
    one, par = tmp_path / "one", tmp_path / "par"
    render_random_dataset(one, truss, CAM, count=60, seed=3)
    # half of it first (a resumed job), then the rest with 2 worker processes
    shutil.copytree(one, par)
    scene = par / "train" / "000000"
    for f in scene.rglob("*.png"):
        if int(f.name[:6]) >= 30:
            f.unlink()
    calls = []
    render_random_dataset(par, truss, CAM, count=60, seed=3, workers=2, progress=lambda d, t: calls.append(d))
    assert calls and calls[0] > 30 and calls[-1] == 60
    for sub in ("rgb", "mask_visib", "depth", "mask"):
        names = sorted(f.name for f in (one / "train/000000" / sub).iterdir())
        assert names == sorted(f.name for f in (scene / sub).iterdir())
        for name in names:
            assert (one / "train/000000" / sub / name).read_bytes() == (scene / sub / name).read_bytes(), name
    for name in ("scene_gt.json", "scene_gt_info.json", "scene_camera.json"):
        assert (one / "train/000000" / name).read_text() == (scene / name).read_text()
    with pytest.raises(ValueError, match="workers"):
        render_random_dataset(tmp_path / "bad", truss, CAM, count=2, workers=0)


def test_random_dataset_records_each_images_sun(truss, tmp_path):
    from hybridpose.datasets.generate import sun_directions_in_cone
    from hybridpose.render import SpaceLighting

    light = SpaceLighting(sun_direction_cam=(0.0, 0.0, 1.0))
    out = render_random_dataset(tmp_path / "sun", truss, CAM, count=5, seed=2, lighting=light, sun_cone_deg=60.0,
                                sun_scale_range=(0.5, 1.5))
    scene = BopScene(out)
    meta = json.loads((out / "scene_meta.json").read_text())["frames"]
    # the same draws the renderer used: the lighting stream of the seed, then the intensities
    rng = np.random.default_rng([2, 7])
    expected = sun_directions_in_cone((0.0, 0.0, 1.0), 60.0, 5, rng)
    scales = rng.uniform(0.5, 1.5, 5)
    for i in range(5):
        np.testing.assert_allclose(scene.sun_direction_cam(i), expected[i], atol=1e-12)
        assert meta[str(i)]["sun_scale"] == pytest.approx(scales[i])
    # one fixed sun: every image records it; BOP data from elsewhere has none
    fixed = BopScene(render_random_dataset(tmp_path / "fixed", truss, CAM, count=2, seed=2, lighting=light))
    np.testing.assert_allclose(fixed.sun_direction_cam(1), [0.0, 0.0, 1.0])
    (out / "scene_meta.json").unlink()
    assert BopScene(out).sun_direction_cam(0) is None
    with pytest.raises(ValueError, match="sun_cone_deg: expected 0..180 degrees"):
        render_random_dataset(tmp_path / "bad", truss, CAM, count=2, sun_cone_deg=200.0)


def test_random_views_with_the_arm_in_front_are_seeded_recorded_and_cover_part_of_the_object(truss, tmp_path):
    out = render_random_dataset(tmp_path / "occ", truss, CAM, count=8, seed=4, in_view=True, occluded_share=0.5)
    cfg = json.loads((tmp_path / "occ" / "hybridpose.json").read_text())
    assert cfg["occluded_share"] == 0.5
    visible = [e[0]["visib_fract"] for e in json.loads((out / "scene_gt_info.json").read_text()).values()]
    plain = [e[0]["visib_fract"] for e in json.loads(
        (render_random_dataset(tmp_path / "plain", truss, CAM, count=8, seed=4, in_view=True) / "scene_gt_info.json")
        .read_text()).values()]
    # the same poses (the occluders draw from a stream of their own); some views now partly covered
    assert BopScene(out).image(3).pose.t == pytest.approx(BopScene(tmp_path / "plain" / "train" / "000000").image(3).pose.t)
    covered = [v < p - 0.05 for v, p in zip(visible, plain)]
    assert 1 <= sum(covered) <= 7 and min(visible) > 0.0, visible
    assert "occluded_share" not in json.loads((tmp_path / "plain" / "hybridpose.json").read_text())
    with pytest.raises(ValueError, match="occluded_share"):
        render_random_dataset(tmp_path / "bad", truss, CAM, count=2, occluded_share=1.5)


def test_sequence_dataset_has_timestamps_and_occlusion(truss, tmp_path):
    spec = SequenceSpec("tumble", frames=12, fps=10, occlusion="arm-full", seed=2)
    scene_dir = render_sequence_dataset(tmp_path / "seq", truss, CAM, spec)
    meta = json.loads((scene_dir / "scene_meta.json").read_text())
    assert meta["fps"] == 10 and meta["frames"]["5"]["timestamp_s"] == pytest.approx(0.5)
    np.testing.assert_allclose(BopScene(scene_dir).sun_direction_cam(5), np.array([0.6, 0.4, 0.7]) / np.linalg.norm([0.6, 0.4, 0.7]))
    info = json.loads((scene_dir / "scene_gt_info.json").read_text())
    assert info["6"][0]["visib_fract"] < 0.05 and info["0"][0]["visib_fract"] > 0.99


def test_corrupt_files_are_named(random_ds, tmp_path):
    bad = tmp_path / "bad"
    shutil.copytree(random_ds, bad)
    scene_dir = bad / "train" / "000000"
    (scene_dir / "rgb" / "000001.png").write_bytes((scene_dir / "rgb" / "000001.png").read_bytes()[:50])
    with pytest.raises(ValueError, match="000001.png: corrupt"):
        BopScene(scene_dir).rgb(1)
    (scene_dir / "scene_gt.json").write_text('{"0": [{"cam_R_m2c": [1, 0')
    with pytest.raises(ValueError, match="scene_gt.json: corrupt or truncated"):
        BopScene(scene_dir)
    with pytest.raises(FileNotFoundError, match="no BOP scene"):
        find_scenes(tmp_path / "bad" / "models")
    lab = tmp_path / "labels.csv"
    lab.write_text("image,tx,ty,tz,qw,qx,qy,qz\na.png,0,0,1,1,0.2,0,0\n")
    with pytest.raises(ValueError, match="line 2: quaternion .* norm 1.0198"):
        read_labels(lab)
    lab.write_text("image,tx,ty,tz,qw,qx,qy,qz\n")
    with pytest.raises(ValueError, match="empty dataset"):
        read_labels(lab)


def test_torch_dataset_full_and_crop(random_ds):
    ds = PoseDataset(random_ds, size=64)
    item = ds[0]
    assert item["image"].shape == (3, 64, 64) and item["image"].dtype == torch.float32
    assert 0 <= item["image"].min() and item["image"].max() <= 1
    assert torch.allclose(torch.linalg.norm(item["q"]), torch.tensor(1.0))
    crops = PoseDataset(random_ds, size=48, crop=True)
    scene = BopScene(find_scenes(random_ds)[0])
    for k in range(len(crops)):
        it = crops[k]
        pose = scene.image(k).pose
        # the object's projected centre (via the crop's K) lies inside the crop
        p = it["K"].double().numpy() @ pose.t
        u, v = p[:2] / p[2]
        assert -1 <= u <= 48 and -1 <= v <= 48
        # the crop's K is the full K mapped by the crop: check with a model vertex
        gt_K = scene.image(k).camera.K
        vert = pose @ np.array([0.19, 0.1, 0.025])
        uv_full = (gt_K @ vert)[:2] / vert[2]
        cx, cy, side = it["crop"].double().numpy()
        expect = (uv_full - [cx, cy]) * 48 / side + 23.5
        got = (it["K"].double().numpy() @ vert)[:2] / vert[2]
        np.testing.assert_allclose(got, expect, atol=1e-3)


def test_parallel_models_items_decode_each_image_once(random_ds, monkeypatch):
    """The parallel model's item (full image + crop of one view) decodes its image once and equals the two
    datasets' own items."""
    from hybridpose.datasets import bop
    from hybridpose.training.train import TrainConfig
    from hybridpose.training.train_data import make_datasets

    train, _ = make_datasets(TrainConfig(model="parallel-vgg19", data=str(random_ds), out="unused", image_size=64))
    paired = train.dataset
    decoded = []
    real = bop.BopScene.rgb
    monkeypatch.setattr(bop.BopScene, "rgb", lambda self, im_id: decoded.append(im_id) or real(self, im_id))
    item = paired[1]
    assert decoded == [paired.full.samples[1][1]]
    assert torch.equal(item["image"], paired.full[1]["image"]) and torch.equal(item["t"], paired.full[1]["t"])
    assert torch.equal(item["crop_image"], paired.crop[1]["image"])
    # with the image cache (--cache-images) both come from it: nothing decoded, the same tensors
    cached, _ = make_datasets(TrainConfig(model="parallel-vgg19", data=str(random_ds), out="unused", image_size=64,
                                          cache_images=str(random_ds.parent / "cache_paired")))
    decoded.clear()
    again = cached.dataset[1]
    assert not decoded and all(torch.equal(again[k], item[k]) for k in ("image", "crop_image", "t", "K"))


def test_image_cache_gives_the_same_items_and_is_rebuilt_when_the_views_change(random_ds, tmp_path, monkeypatch):
    """cache_images: the items read back equal the decoded ones (full frames and fixed crops), the file is
    reused by a new dataset on the same views, rebuilt after a view's image changed, and random crops
    (jitter) never read it."""
    import cv2

    from hybridpose.datasets import bop

    data = tmp_path / "ds"
    shutil.copytree(random_ds, data)
    keys = ("image", "t", "q", "K", "crop")
    for crop in (False, True):
        ds = PoseDataset(data, size=(48, 40), crop=crop)
        before = [ds[k] for k in range(len(ds))]
        path = ds.cache_images(tmp_path / "cache", workers=2)
        assert ds.cached and path.exists() and not list(path.parent.glob(".*.tmp"))
        decoded = []
        real = bop.BopScene.rgb
        monkeypatch.setattr(bop.BopScene, "rgb", lambda self, im_id: decoded.append(im_id) or real(self, im_id))
        after = [ds[k] for k in range(len(ds))]
        assert not decoded, "cached items are not decoded"
        assert all(torch.equal(a[key], b[key]) for a, b in zip(before, after) for key in keys)
        if crop:  # random crops are drawn per item: never from the cache
            jittered = ds.subset(range(3), jitter=True)
            assert not jittered.cached
            jittered[0]
            assert decoded
        monkeypatch.setattr(bop.BopScene, "rgb", real)
    # reused as long as the views are the same files, rebuilt once one changed
    mtime = path.stat().st_mtime_ns
    PoseDataset(data, size=(48, 40), crop=True).cache_images(tmp_path / "cache")
    assert path.stat().st_mtime_ns == mtime
    rgb = sorted((find_scenes(data)[0] / "rgb").iterdir())[0]
    img = cv2.imread(str(rgb))
    cv2.imwrite(str(rgb), 255 - img)
    ds = PoseDataset(data, size=(48, 40), crop=True)
    ds.cache_images(tmp_path / "cache")
    assert path.stat().st_mtime_ns != mtime
    k = ds.samples.index(next(s for s in ds.samples if s[1] == int(rgb.stem)))
    fresh = PoseDataset(data, size=(48, 40), crop=True)[k]["image"]
    assert torch.equal(ds[k]["image"], fresh)


def test_split_is_seeded_80_20():
    tr, va = split_indices(100, 0.2, seed=1)
    assert len(tr) == 80 and len(va) == 20 and not set(tr) & set(va)
    tr2, va2 = split_indices(100, 0.2, seed=1)
    assert np.array_equal(va, va2)
    assert not np.array_equal(va, split_indices(100, 0.2, seed=2)[1])
    with pytest.raises(ValueError, match="n: need at least 2"):
        split_indices(1)


def test_atomic_write_keeps_the_old_file_when_the_writer_fails(tmp_path):
    from hybridpose.io import atomic_write_bytes, atomic_write_with

    target = tmp_path / "sub" / "ck.pt"
    atomic_write_bytes(target, b"old")

    def half_then_fail(f):
        f.write(b"new, partly")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write_with(target, half_then_fail)
    assert target.read_bytes() == b"old" and sorted(p.name for p in target.parent.iterdir()) == ["ck.pt"]
    atomic_write_with(target, lambda f: f.write(b"new"))
    assert target.read_bytes() == b"new" and oct(target.stat().st_mode & 0o777) == "0o644"


def test_find_scenes_reads_a_folder_of_rendered_datasets(random_ds, tmp_path):
    """Several ``hybridpose render`` outputs side by side (dataset/split/scene): every scene, sorted."""
    import shutil

    for name in ("b_seq", "a_seq"):
        shutil.copytree(random_ds, tmp_path / "many" / name)
    found = find_scenes(tmp_path / "many")
    assert [p.relative_to(tmp_path / "many").parts[0] for p in found] == ["a_seq", "b_seq"]
    assert find_scenes(tmp_path / "many" / "a_seq") == [found[0]]


def test_a_dataset_of_a_mesh_named_like_a_built_in_keeps_its_own_mesh_and_symmetries(tmp_path):
    """A user's printed ``cube.obj`` shares the built-in cube's name, not its mesh, size or (printed:
    none) symmetries; the training reads back the dataset's own model."""
    import trimesh

    from hybridpose.datasets.bop import dataset_object, write_models
    from hybridpose.objects import ObjectModel, load_builtin

    mine = ObjectModel("cube", trimesh.creation.box((0.0845,) * 3).subdivide(), symmetries=())
    write_models(tmp_path, mine)
    (tmp_path / "hybridpose.json").write_text(json.dumps({"object": "cube"}))
    back = dataset_object(tmp_path)
    assert back.name != "cube" and len(back.faces) == len(mine.faces) and back.symmetries == ()
    assert np.allclose(back.extents, mine.extents)
    builtin = load_builtin("cube")  # the built-in's own dataset still gets the built-in back
    write_models(tmp_path, builtin)
    back = dataset_object(tmp_path)
    assert back.name == "cube" and len(back.symmetries) == 23 and np.allclose(back.keypoints, builtin.keypoints)


def test_source_cache_gives_the_same_random_crops_without_decoding(random_ds, tmp_path, monkeypatch):
    """cache_sources: random crops (jitter, whole-frame views included) cut from the cached views equal
    those cut from the decoded PNGs under the same torch seed; nothing is decoded once it is built; a
    DataLoader worker maps the file itself; views of two sizes are refused."""
    from hybridpose.datasets import bop

    ds = PoseDataset(random_ds, size=40, crop=True, full_view=0.5).subset(range(4), jitter=True)
    keys = ("image", "t", "q", "K", "crop")
    torch.manual_seed(3)
    before = [ds[k] for k in range(len(ds))]
    path = ds.cache_sources(tmp_path / "cache", workers=2)
    assert path.name.startswith("source_") and path.exists() and not list(path.parent.glob(".*.tmp"))
    decoded = []
    real = bop.BopScene.rgb
    monkeypatch.setattr(bop.BopScene, "rgb", lambda self, im_id: decoded.append(im_id) or real(self, im_id))
    torch.manual_seed(3)
    after = [ds[k] for k in range(len(ds))]
    assert not decoded, "items come from the source cache"
    assert all(torch.equal(a[key], b[key]) for a, b in zip(before, after) for key in keys)
    assert pickle.loads(pickle.dumps(ds))._sources is None  # a worker maps the file, it is not sent the pixels
    monkeypatch.setattr(bop.BopScene, "rgb", real)
    # a view of another size: the cache cannot hold it
    rgb = sorted((find_scenes(random_ds)[0] / "rgb").iterdir())
    data = tmp_path / "mixed"
    shutil.copytree(random_ds, data)
    odd = data / rgb[-1].relative_to(random_ds)
    cv2.imwrite(str(odd), cv2.resize(cv2.imread(str(odd)), (20, 16)))
    with pytest.raises(ValueError, match="one size"):
        PoseDataset(data, size=40, crop=True).cache_sources(tmp_path / "cache2")
