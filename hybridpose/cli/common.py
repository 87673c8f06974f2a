"""Helpers shared by the ``hybridpose`` subcommands: progress bars and argument types."""
from __future__ import annotations

import argparse

from ..geometry import Camera, load_camera


def progress(desc: str):
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit="img", dynamic_ncols=True)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)
        if done >= total:
            bar.close()

    return update


def counter(desc: str, unit: str = "frame"):
    """Progress bar for a stream of unknown length (video frames)."""
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit=unit, dynamic_ncols=True)

    def update(done: int) -> None:
        bar.update(done - bar.n)

    return update


def close_bars() -> None:
    """Close every open progress bar, ending its line, so that what is printed next starts a line of
    its own (an error glued onto a bar's last line is easy to miss)."""
    from tqdm import tqdm

    for bar in list(getattr(tqdm, "_instances", ())):
        bar.close()


def base_camera(args) -> Camera:
    # a camera file without an image size (a ViSP tracker configuration) calibrates frames of --size
    cam = load_camera(args.camera, image_size=args.size) if getattr(args, "camera", None) else Camera.default()
    return cam.scaled(args.size) if args.size else cam


def float_pair(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH (two numbers), got {text!r}") from None
    return lo, hi


def sun_dir(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}") from None
    if len(vals) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers x,y,z, got {text!r}")
    return vals
