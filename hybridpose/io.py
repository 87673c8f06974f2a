"""File I/O at the edge: atomic writes (temp file + rename) and reads whose errors name the file."""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np


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
