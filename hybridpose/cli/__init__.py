"""The ``hybridpose`` command. Each group of subcommands lives in its own module and adds itself to
the parser: :mod:`.data` (render, verify), :mod:`.cnn` (train, train-verifier, calibrate, quantize,
eval, compare, export), :mod:`.tracking` (track, bench, fit, demo). Heavy imports (torch, MuJoCo)
happen inside the commands, so ``hybridpose --help`` starts at once."""
from __future__ import annotations

import argparse
import logging
import sys

from . import cnn, data, tracking

log = logging.getLogger("hybridpose")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hybridpose", description="6-DoF pose tracking of a known rigid object.")
    p.add_argument("-v", "--verbose", action="store_true")
    sub = p.add_subparsers(dest="command", required=True)
    for group in (data, cnn, tracking):
        group.add_commands(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if args.command == "train":  # its options are parsed by cnn.cmd_train (see there)
        args.train_args = list(args.train_args or []) + extra
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError, TypeError) as exc:
        from .common import close_bars

        close_bars()
        print(f"hybridpose {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
