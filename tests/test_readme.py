"""The README's code blocks as a user meets them: every Python block runs as written (over a short
rendering of the demo's sequence where it reads the demo's frames), and every ``hybridpose`` command
of the shell blocks, there and in ``docs/``, is one the CLI accepts (its options and values parsed;
the long jobs not run)."""
import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]


def _blocks(language: str, page: Path = README) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", page.read_text(), flags=re.S)


def _commands(block: str) -> list[list[str]]:
    """The ``hybridpose`` command lines of a shell block (continuations joined, comments and
    ``&&`` chains split)."""
    text = re.sub(r"\\\n\s*", " ", block)
    out = []
    for line in text.splitlines():
        for part in line.split("#", 1)[0].split("&&"):
            argv = shlex.split(part)
            if argv and argv[0] == "hybridpose":
                out.append(argv[1:])
    return out


@pytest.fixture(scope="module")
def demo_folder(tmp_path_factory):
    """A folder holding ``hybridpose_demo/seq_tumble_arm`` as the demo renders it, 4 frames long."""
    from hybridpose.datasets import render_sequence_dataset
    from hybridpose.geometry import Camera
    from hybridpose.objects import load_object
    from hybridpose.render.sequences import SequenceSpec

    root = tmp_path_factory.mktemp("readme")
    render_sequence_dataset(root / "hybridpose_demo" / "seq_tumble_arm", load_object("truss"), Camera.default(),
                            SequenceSpec(trajectory="tumble", frames=4, fps=30.0, occlusion="arm", seed=1))
    return root


def test_the_readme_has_code_to_test():
    assert len(_blocks("python")) >= 2 and sum(len(_commands(b)) for b in _blocks("bash")) >= 10


@pytest.mark.parametrize("index", range(len(_blocks("python"))))
def test_python_blocks_run_as_written(index, demo_folder, monkeypatch):
    monkeypatch.chdir(demo_folder)
    exec(compile(_blocks("python")[index], f"README.md python block {index}", "exec"), {})


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_shell_commands_are_ones_the_cli_accepts(page, capsys):
    import argparse

    from hybridpose.cli import build_parser
    from hybridpose.training.train import add_train_arguments

    parser = build_parser()
    train = argparse.ArgumentParser(prog="hybridpose train")
    add_train_arguments(train)
    for block in _blocks("bash", page):
        for argv in _commands(block):
            try:
                if argv[0] == "train":  # its options are parsed by the training's own parser (hybridpose.cli.main)
                    train.parse_args(argv[1:])
                else:
                    parser.parse_args(argv)
            except SystemExit:
                pytest.fail(f"{page.name}: `hybridpose {' '.join(argv)}` is refused: {capsys.readouterr().err}")
