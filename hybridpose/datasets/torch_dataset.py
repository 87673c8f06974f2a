"""A torch ``Dataset`` over BOP scenes: resized full images or object-centred crops, with K.

The crop is the paper's "bounded image": a square around the object's projected bounding box,
enlarged by ``crop_margin``, resampled to ``size``; pixels outside the frame are black (space).
"""
from __future__ import annotations

import copy
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from ..geometry import parse_size
from ..geometry.crops import MIN_CROP_PX, crop_affine, crop_box, crop_image
from ..io import atomic_write_json, read_json
from .bop import BopScene, find_scenes

JITTER_MARGIN = (1.1, 1.8)  # crop side / object box side, drawn per sample: a detector's loose or tight box
JITTER_SHIFT = 0.12  # crop centre shifted by up to this share of its side (a detector's error)
FULL_VIEW_PROB = 0.0  # share of whole-frame samples (a fit's option: the network then detects too)


def split_indices(n: int, val_fraction: float = 0.2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Seeded random split of ``range(n)`` into (train, val) index arrays (the paper's 80/20)."""
    if n < 2:
        raise ValueError(f"n: need at least 2 samples to split, got {n}")
    if not 0 < val_fraction < 1:
        raise ValueError(f"val_fraction: expected a value in (0, 1), got {val_fraction}")
    perm = np.random.default_rng(seed).permutation(n)
    n_val = max(1, int(round(n * val_fraction)))
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def single_threaded_worker(_worker_id: int) -> None:
    """DataLoader ``worker_init_fn`` for workers that decode and crop one image at a time: OpenCV's own
    thread pool in every worker oversubscribed a 16-core GPU machine (load average 168 with three
    trainings at once)."""
    cv2.setNumThreads(1)


def _cache_record(path: Path) -> dict | None:
    """The record beside an image cache (:meth:`PoseDataset.cache_images`), None where it is missing or
    unreadable (the cache is then rebuilt)."""
    try:
        return read_json(path)
    except (OSError, ValueError):
        return None


def _cache_is_current(path: Path, record: dict) -> bool:
    """Whether the image cache ``path`` (with its source sizes beside it) was made as ``record`` says."""
    return (path.exists() and path.with_suffix(".shapes.npy").exists()
            and _cache_record(path.with_suffix(".json")) == record)


class PoseDataset(Dataset):
    """Images and labels of one or more BOP scenes for training a pose regressor.

    Args:
        root: dataset root, split or scene directory.
        size: output size N or (W, H).
        crop: False → whole image resized to ``size`` (K rescaled; aspect may change as in the
            paper); True → object-centred square crop from ``bbox_obj``.
        indices: subset of sample indices (e.g. from :func:`split_indices`); None = all.
        crop_margin: crop side / max(bbox w, h).
        jitter: crop mode only — random, label-consistent crops for training: margin drawn from
            ``JITTER_MARGIN``, centre shifted by up to ``JITTER_SHIFT`` × side, and with probability
            ``full_view`` the whole frame (a square around the image centre) instead. Draws use
            torch's RNG (seeded runs repeat).
        full_view: the share of jittered crops that show the whole frame: 0 (default) where the
            regressor finds the object by detection (sunlit pixels on black: whole-frame views slowed
            learning there); > 0 teaches the network to find the object itself in a cluttered
            frame (its ``detection="network"``).
        keypoints_m: (N, 3) model keypoints in metres; adds ``kp2d`` (N, 2), their projections in
            the returned image's pixels. A (T, N, 3) stack (e.g. the keypoints under an object's
            near-symmetries) gives ``kp2d`` (T, N, 2).

    Each item is a dict of tensors: ``image`` (3, H, W) float32 in [0, 1]; ``t`` (3,) metres;
    ``q`` (4,) (w, x, y, z), w ≥ 0; ``K`` (3, 3) intrinsics *of the returned image*;
    ``crop`` (3,) (cx, cy, side) in source pixels (the full image when ``crop`` is False);
    ``index`` the sample index.
    """

    def __init__(self, root, size=224, crop: bool = False, indices=None, crop_margin: float = 1.2,
                 jitter: bool = False, keypoints_m=None, full_view: float = FULL_VIEW_PROB) -> None:
        self.scenes = [BopScene(p) for p in find_scenes(root)]
        self.samples = [(s, i) for s, sc in enumerate(self.scenes) for i in sc.image_ids]
        if not self.samples:
            raise ValueError(f"root: {Path(root)} holds no images (empty dataset)")
        self.size = parse_size(size)
        self.crop, self.crop_margin, self.jitter = bool(crop), float(crop_margin), bool(jitter)
        if self.jitter and not self.crop:
            raise ValueError("jitter: random crops need crop=True")
        if not 0.0 <= full_view <= 1.0:
            raise ValueError(f"full_view: expected a share of the crops in [0, 1], got {full_view!r}")
        self.full_view = float(full_view)
        self.keypoints_m = None
        if keypoints_m is not None:
            self.keypoints_m = np.asarray(keypoints_m, dtype=np.float64)
            if self.keypoints_m.ndim not in (2, 3) or self.keypoints_m.shape[-1] != 3:
                raise ValueError(f"keypoints_m: expected (N, 3) or (T, N, 3) metres, got {self.keypoints_m.shape}")
        self.indices = self._checked(np.arange(len(self.samples)) if indices is None else indices)
        self._cache_path, self._cache = None, None  # cache_images
        self._source_path, self._sources = None, None  # cache_sources

    def _checked(self, indices) -> np.ndarray:
        idx = np.asarray(indices, dtype=np.int64)
        if len(idx) and (idx.min() < 0 or idx.max() >= len(self.samples)):
            raise ValueError(f"indices: expected values in [0, {len(self.samples)}), got {idx.min()}..{idx.max()}")
        return idx

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, k: int) -> dict:
        return self.item(k)

    def rgb(self, k: int) -> np.ndarray:
        """The (H, W, 3) uint8 RGB image of item ``k``, as stored (before any crop or resize)."""
        return self._source(int(self.indices[k]))

    def _source(self, idx: int) -> np.ndarray:
        """Sample ``idx``'s stored image, from :meth:`cache_sources`' file where there is one."""
        if self._source_path is not None:
            if self._sources is None:  # opened lazily: in each DataLoader worker, after the fork
                self._sources = np.load(self._source_path, mmap_mode="r")
            return np.array(self._sources[idx])  # a copy: the map is read-only
        scene_i, im_id = self.samples[idx]
        return self.scenes[scene_i].rgb(im_id)

    def item(self, k: int, image: np.ndarray | None = None) -> dict:
        """Item ``k`` (as ``self[k]``); ``image``: its :meth:`rgb` where the caller already decoded it
        (the parallel model's two inputs come from one image: decoding it once saves a third of the
        loader's time per view)."""
        return self._item_at(int(self.indices[k]), image)

    def _item_at(self, idx: int, image: np.ndarray | None = None, use_cache: bool = True) -> dict:
        scene_i, im_id = self.samples[idx]
        scene = self.scenes[scene_i]
        gt = scene.image(im_id)
        rows = self._cache_rows() if use_cache and image is None and self.cached else None
        if rows is None:
            img = self._source(idx) if image is None else image
            src_h, src_w = img.shape[:2]
        else:  # the transformed image, as the code below would make it (cache_images)
            out = np.array(rows[0][idx])  # a copy: torch wants a writable array, the map is read-only
            src_h, src_w = (int(v) for v in rows[1][idx])
        w, h = self.size
        if self.crop:
            if gt.bbox_obj[2] <= 0:
                raise ValueError(f"{scene.dir} image {im_id}: no bbox_obj in scene_gt_info.json; cannot crop")
            cx, cy, side = crop_box(gt.bbox_obj, self.crop_margin)
            if self.jitter:
                cx, cy, side = self._jittered(cx, cy, side / self.crop_margin, src_w, src_h)
            if rows is None:
                out, K = crop_image(img, gt.camera.K, cx, cy, side, (w, h))
            else:
                K = np.vstack([crop_affine(cx, cy, side, w, h), [0, 0, 1]]) @ gt.camera.K  # crop_image's K
            crop = (cx, cy, side)
        else:
            cam = gt.camera.scaled((w, h))
            if rows is None:
                out = img if (w, h) == (src_w, src_h) else cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            K = cam.K
            crop = ((src_w - 1) / 2, (src_h - 1) / 2, float(max(src_h, src_w)))
        item = {
            "image": torch.from_numpy(np.ascontiguousarray(out)).permute(2, 0, 1).float() / 255.0,
            "t": torch.tensor(gt.pose.t, dtype=torch.float32),
            "q": torch.tensor(gt.pose.quat_wxyz, dtype=torch.float32),
            "K": torch.tensor(K, dtype=torch.float32),
            "crop": torch.tensor(crop, dtype=torch.float32),
            "index": idx,
        }
        if self.keypoints_m is not None:
            pts = self.keypoints_m.reshape(-1, 3)
            p = (gt.pose @ pts) @ K.T
            uv = (p[:, :2] / p[:, 2:]).reshape(*self.keypoints_m.shape[:-1], 2)
            item["kp2d"] = torch.tensor(uv, dtype=torch.float32)
        return item

    # --- image cache --------------------------------------------------------------------------
    def cache_images(self, directory, workers: int = 1) -> Path:
        """Decode and resize (or crop) every view's image once into ``directory`` and read them from
        there from now on: ``<kind>_<W>x<H>.npy`` (N, H, W, 3) uint8, memory-mapped, beside a JSON
        record of what it holds. An existing cache is used when it was made from the same views,
        files and settings, else rebuilt; both files are written to temp files and renamed.

        For the direct (VGG) models on a GPU, whose items are fixed (the photometric augmentation
        runs on the GPU): decoding a 640×480 PNG and resizing it take ≈ 6.5 ms of a core per view
        (the parallel model's two inputs ≈ 9 ms), so a few workers per model cannot feed a GPU
        that trains thousands of views a second; a memory-mapped row takes microseconds. Random
        crops (``jitter``) differ every epoch and are never read from the cache. ``workers``:
        threads that build it.
        """
        directory = Path(directory)
        kind = f"{'crop' if self.crop else 'full'}_{self.size[0]}x{self.size[1]}"
        if self.crop:
            kind += f"_m{self.crop_margin:g}"
        path = directory / f"{kind}.npy"
        record = {"format": 1, "size": list(self.size), "crop": self.crop, "crop_margin": self.crop_margin,
                  "views": self._views_fingerprint()}
        meta = path.with_suffix(".json")
        if not _cache_is_current(path, record):
            self._build_cache(path, meta, record, workers, (*self.size[::-1], 3), self._cache_row)
        self._cache_path, self._cache = path, None
        return path

    def cache_sources(self, directory, workers: int = 1) -> Path:
        """Decode every view's stored image once into ``directory`` (``source_<W>x<H>.npy``, (N, H, W, 3)
        uint8, memory-mapped, beside a JSON record as in :meth:`cache_images`) and cut every item,
        random crops included, from there from now on.

        For the keypoint models' random crops, which :meth:`cache_images` cannot hold: decoding a
        640×480 PNG takes ≈ 10 ms of a core per view and cutting the 128-px crop < 1 ms, while a 2-core
        CPU trains the ``default`` network at ≈ 20 ms a view — the loader's decoding took a quarter
        of the machine. 0.9 MB a 640×480 view on disk (the page cache keeps what fits in memory).

        Raises:
            ValueError: the views' images are not all one size.
        """
        directory = Path(directory)
        h, w = self.scenes[self.samples[0][0]].rgb(self.samples[0][1]).shape[:2]
        path = directory / f"source_{w}x{h}.npy"
        record = {"format": 1, "source": [w, h], "views": self._views_fingerprint()}
        meta = path.with_suffix(".json")
        if not _cache_is_current(path, record):
            def row(idx: int) -> tuple[np.ndarray, tuple[int, int]]:
                scene_i, im_id = self.samples[idx]
                img = self.scenes[scene_i].rgb(im_id)
                if img.shape[:2] != (h, w):
                    raise ValueError(f"{self.scenes[scene_i].dir} image {im_id}: {img.shape[1]}x{img.shape[0]} px, "
                                     f"while the first view is {w}x{h}; a source cache needs one size")
                return img, img.shape[:2]
            self._build_cache(path, meta, record, workers, (h, w, 3), row)
        self._source_path, self._sources = path, None
        return path

    def _views_fingerprint(self) -> str:
        """SHA-1 of the views (scene folder, image id) and of each scene's label and image files'
        sizes and modification times: a cache made from other files is not reused."""
        import hashlib

        h = hashlib.sha1()
        for scene in self.scenes:
            for f in sorted([*scene.dir.glob("scene_*.json"), *(scene.dir / "rgb").iterdir()]):
                st = f.stat()
                h.update(f"{f.resolve()}|{st.st_size}|{st.st_mtime_ns}\n".encode())
        h.update(repr(self.samples).encode())
        return h.hexdigest()

    def _build_cache(self, path: Path, meta: Path, record: dict, workers: int, shape: tuple[int, int, int],
                     row) -> None:
        """``row(idx)`` → (uint8 image of ``shape`` (H, W, 3), source (height, width)) of every sample
        into the memory-mapped ``path``, its source sizes beside it, ``record`` into ``meta``."""
        import logging
        import os
        from concurrent.futures import ThreadPoolExecutor

        n = len(self.samples)
        logging.getLogger(__name__).info("caching %d images of %dx%d in %s", n, shape[1], shape[0], path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        try:
            images = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint8, shape=(n, *shape))
            shapes = np.zeros((n, 2), np.int32)
            # threads, not processes: decoding and resizing run in OpenCV, which lets go of the GIL, and
            # a process forked after OpenCV's or torch's thread pools ran can deadlock
            with ThreadPoolExecutor(max(1, int(workers))) as pool:
                for idx, (image, source) in enumerate(pool.map(row, range(n))):
                    images[idx], shapes[idx] = image, source
            images.flush()
            del images
            np.save(path.with_suffix(".shapes.npy"), shapes)
            os.replace(tmp, path)
            atomic_write_json(meta, record)
        finally:
            tmp.unlink(missing_ok=True)

    @property
    def cached(self) -> bool:
        """Whether items are read from :meth:`cache_images`' file (random crops never are)."""
        return self._cache_path is not None and not self.jitter

    def _cache_row(self, idx: int) -> tuple[np.ndarray, tuple[int, int]]:
        """(transformed uint8 image (H, W, 3), source image (height, width)) of sample ``idx``."""
        scene_i, im_id = self.samples[idx]
        img = self.scenes[scene_i].rgb(im_id)
        x = self._item_at(idx, image=img, use_cache=False)["image"]
        # the item's float image is the uint8 one / 255: ×255 and rounding gives it back exactly
        return (x.permute(1, 2, 0) * 255.0).round().to(torch.uint8).numpy(), img.shape[:2]

    def _cache_rows(self):
        """(images (N, H, W, 3) uint8, source sizes (N, 2)) memory-mapped, or None without a cache."""
        path = self._cache_path
        if path is None:
            return None
        if self._cache is None:  # opened lazily: in each DataLoader worker, after the fork
            self._cache = (np.load(path, mmap_mode="r"), np.load(path.with_suffix(".shapes.npy"), mmap_mode="r"))
        return self._cache

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_cache"] = state["_sources"] = None  # a worker maps the files itself, not their contents
        return state

    def subset(self, indices, jitter: bool = False) -> "PoseDataset":
        """The same data restricted to ``indices`` (e.g. a split), without re-reading the scenes."""
        if jitter and not self.crop:
            raise ValueError("jitter: random crops need crop=True")
        sub = copy.copy(self)
        sub.indices, sub.jitter = self._checked(indices), bool(jitter)
        return sub

    def _jittered(self, cx: float, cy: float, extent: float, width: int, height: int) -> tuple[float, float, float]:
        r = torch.rand(4).tolist()
        if r[0] < self.full_view:
            return (width - 1) / 2, (height - 1) / 2, float(max(width, height))
        lo, hi = JITTER_MARGIN
        side = max(MIN_CROP_PX, (lo + (hi - lo) * r[1]) * extent)
        return cx + (2 * r[2] - 1) * JITTER_SHIFT * side, cy + (2 * r[3] - 1) * JITTER_SHIFT * side, side
