"""File I/O at the edge: atomic writes (temp file + rename; videos too) and reads whose errors name the file."""
from __future__ import annotations

import json
import logging
import os
import queue
import tempfile
import threading
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)

# browsers play H.264 .mp4 and VP8/VP9 .webm; MPEG-4 Part 2 ('mp4v') only as a last resort. VP8 before
# VP9: on a 640×480 video OpenCV's VP9 took 99 ms a frame (and 3 s to finish), three quarters of `track`'s
# time, where VP8 takes 23 ms
VIDEO_CODECS = (("avc1", ".mp4"), ("VP80", ".webm"), ("VP90", ".webm"), ("mp4v", ".mp4"))
VIDEO_QUEUE_FRAMES = 8  # frames waiting for the encoder at most (≈ 7 MB at 640×480): the tracking waits beyond


def atomic_write_with(path, write) -> None:
    """Call ``write(f)`` on a binary file so that a reader of ``path`` never sees a partial file:
    a temp file beside it, then ``os.replace``; if ``write`` raises, ``path`` is left as it was.
    Streams: a multi-GB checkpoint is never held in memory as one bytes object."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; results are meant to be shared
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that a reader never sees a partial file (temp + ``os.replace``)."""
    atomic_write_with(path, lambda f: f.write(data))


def atomic_write_json(path, obj, indent: int | None = 2) -> None:
    atomic_write_bytes(path, json.dumps(obj, indent=indent).encode())


def atomic_write_text(path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def read_json(path):
    """Parse a JSON file; FileNotFoundError / ValueError name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: corrupt or truncated JSON ({exc})") from exc


def write_image(path, image: np.ndarray) -> None:
    """Atomically write an image; (H, W, 3) uint8 RGB is stored as a standard (BGR-ordered) PNG/JPEG,
    (H, W) uint8/uint16 as single-channel."""
    path = Path(path)
    img = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image
    ok, buf = cv2.imencode(path.suffix or ".png", img)
    if not ok:
        raise ValueError(f"{path}: could not encode image of shape {image.shape} dtype {image.dtype}")
    atomic_write_bytes(path, buf.tobytes())


def read_image(path, mode: str = "rgb") -> np.ndarray:
    """Read an image file. ``mode``: ``"rgb"`` → (H, W, 3) uint8 RGB; ``"gray"`` → (H, W) uint8;
    ``"unchanged"`` → as stored (e.g. uint16 depth)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: image not found")
    flags = {"rgb": cv2.IMREAD_COLOR, "gray": cv2.IMREAD_GRAYSCALE, "unchanged": cv2.IMREAD_UNCHANGED}[mode]
    img = cv2.imread(str(path), flags)
    if img is None:
        raise ValueError(f"{path}: corrupt, truncated or unsupported image file")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if mode == "rgb" else img


def _quiet_video_writer(path: str, fourcc: str, fps: float, size) -> cv2.VideoWriter:
    """``cv2.VideoWriter``, with FFmpeg's complaints about codecs it lacks (printed straight to the
    process's stderr while probing) kept off the user's terminal."""
    try:
        saved = os.dup(2)
    except OSError:
        return cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*fourcc), fps, size)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            return cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*fourcc), fps, size)
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class VideoFile:
    """An RGB video written to a temporary file and renamed to ``<stem><ext>`` on :meth:`close`, in
    the first codec of :data:`VIDEO_CODECS` this OpenCV build can write. The frames are encoded on a
    thread of their own (OpenCV lets go of the GIL while it encodes), beside the tracking."""

    def __init__(self, stem, fps: float, size: tuple[int, int]) -> None:
        self.stem = Path(stem)
        self.stem.parent.mkdir(parents=True, exist_ok=True)
        for fourcc, ext in VIDEO_CODECS:
            fd, tmp = tempfile.mkstemp(dir=self.stem.parent, prefix=f".{self.stem.name}.", suffix=ext)
            os.close(fd)
            writer = _quiet_video_writer(tmp, fourcc, float(fps), tuple(size))
            if writer.isOpened():
                self.writer, self.tmp, self.path, self.codec = writer, Path(tmp), self.stem.with_suffix(ext), fourcc
                self._frames: queue.Queue = queue.Queue(maxsize=VIDEO_QUEUE_FRAMES)
                self._failed: BaseException | None = None
                self._encoder = threading.Thread(target=self._encode, name=f"encode {self.path.name}", daemon=True)
                self._encoder.start()
                if fourcc == "mp4v":
                    log.warning("this OpenCV writes neither H.264 nor VP9/VP8: %s is MPEG-4 Part 2, which "
                                "browsers do not play (VLC and ffplay do)", self.path)
                return
            writer.release()
            Path(tmp).unlink(missing_ok=True)
        raise RuntimeError(f"{self.stem}: OpenCV cannot write any of {[c for c, _ in VIDEO_CODECS]}")

    def _encode(self) -> None:
        while (bgr := self._frames.get()) is not None:
            if self._failed is None:
                try:
                    self.writer.write(bgr)
                except BaseException as exc:  # said on the next write or at close, in the caller's thread
                    self._failed = exc

    def write(self, rgb: np.ndarray) -> None:
        """Queue one (H, W, 3) uint8 RGB frame (converted here: the caller may reuse ``rgb``)."""
        if self._failed is not None:
            raise self._failed
        self._frames.put(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def close(self, keep: bool = True) -> Path:
        self._frames.put(None)
        self._encoder.join()
        self.writer.release()
        if keep and self._failed is not None:
            self.tmp.unlink(missing_ok=True)
            raise self._failed
        if keep:
            os.chmod(self.tmp, 0o644)
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
        return self.path
