"""Helpers shared by the ``hybridpose`` subcommands: progress bars and argument types."""
from __future__ import annotations

import argparse
import inspect

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


def names(text: str) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(",") if n.strip())


def backend_options(items, factory, flag: str) -> dict:
    """``["explain=false", "lost_quality=0.4"]`` → keyword arguments of the backend ``factory`` (a
    callable or a dataclass of options), each value read as the type of that parameter's default
    (true/false, a number, a word, a comma list where the default is a tuple, ``none`` where the
    default is None); ValueError naming ``flag`` and
    the parameters it takes otherwise (the backend checks the values it is given)."""
    params = {k: p for k, p in inspect.signature(factory).parameters.items()
              if k not in ("self", "object") and p.default is not inspect.Parameter.empty}
    options = {}
    for item in items or ():
        key, _, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if key not in params or not value:
            raise ValueError(f"{flag}: expected NAME=VALUE with a name among {', '.join(params) or 'none'}, got {item!r}")
        default = params[key].default
        if value.lower() == "none" and (default is None or "None" in str(params[key].annotation)):
            options[key] = None
        elif isinstance(default, str):
            options[key] = value
        elif isinstance(default, tuple):
            options[key] = names(value)  # a comma list: modalities=texture,region
        elif isinstance(default, bool):
            if value.lower() not in ("true", "false", "1", "0"):
                raise ValueError(f"{flag}: {key}: expected true or false, got {value!r}")
            options[key] = value.lower() in ("true", "1")
        else:
            try:
                number = float(value)
            except ValueError:
                raise ValueError(f"{flag}: {key}: expected a number, got {value!r}") from None
            options[key] = int(number) if isinstance(default, int) and number.is_integer() else number
    return options
