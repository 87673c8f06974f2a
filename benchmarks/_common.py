"""Shared helpers of the benchmark scripts: environment record and RESULTS.md sections."""
from __future__ import annotations

import json
import platform
import re
import subprocess
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
RESULTS_MD = BENCH_DIR / "RESULTS.md"


def environment() -> dict:
    try:
        git = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=BENCH_DIR).stdout.strip()
    except OSError:
        git = ""
    from hybridpose.machine import describe_cpu

    # the CPU model and ISA: timings from different hosts differ ≈ 2× with the same code (hybridpose.machine)
    return {"git": git, "python": platform.python_version(), "machine": platform.machine(),
            "processor": platform.processor(), **describe_cpu()}


def weights_tag(*paths) -> str:
    """8 hex digits of the files' contents (sha1): names which weights a cache or a table was made with, so
    other weights under the same file name (a verifier shipped since, say) are told apart."""
    import hashlib

    h = hashlib.sha1()
    for path in paths:
        h.update(Path(path).read_bytes())
    return h.hexdigest()[:8]


def test_views(data: str, limit=None):
    """(frame, ground truth) of each view of the BOP folder ``data`` in order, the first ``limit`` only
    when given: ``Frame(rgb, camera, 0.0, image id)`` and its ``BopImage`` (pose T_cam_obj, camera)."""
    from hybridpose.core import Frame
    from hybridpose.datasets.bop import BopScene, find_scenes

    items = [(s, i) for s in map(BopScene, find_scenes(data)) for i in s.image_ids][:limit]
    for scene, im_id in items:
        gt = scene.image(im_id)
        yield Frame(scene.rgb(im_id), gt.camera, 0.0, im_id), gt


# a list of numbers only (JSON's NaN and ±Infinity included), as json.dumps(indent=2) lays it out
_NUMBER_LIST = re.compile(r"\[\s*((?:-?(?:[0-9.eE+-]+|NaN|Infinity)\s*,\s*)*-?(?:[0-9.eE+-]+|NaN|Infinity))\s*\]")


def write_json(name: str, payload: dict) -> Path:
    """``payload`` as ``results/name.json`` (indented, but each list of numbers on one line: the per-view
    lists would otherwise take a line a number), written to a temporary file and renamed."""
    path = BENCH_DIR / "results" / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    text = _NUMBER_LIST.sub(lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]",
                            json.dumps(payload, indent=2))
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(text)
    tmp.replace(path)
    return path


def publish(name: str, section: str, payload: dict, lines: list[str]) -> None:
    """Write ``payload`` to ``results/name.json`` and ``lines`` as the RESULTS.md ``section``, and print them."""
    write_json(name, payload)
    update_results_md(section, "\n".join(lines))
    print("\n".join(lines))


LIGHTING_GROUPS = (("cone", "sets lit from the 40° cone (as most training data)"),
                   ("wide", "sets lit from within 85° of the optical axis"),
                   ("side", "sets lit from within 120° (side- and back-light)"))


def set_names(dirs) -> str:
    """``test154, test155`` for ``data/truss_test154 data/truss_test155`` (table cells)."""
    return ", ".join(Path(d).name.split("_")[-1] for d in dirs)


def update_results_md(section: str, markdown: str) -> None:
    """Replace the block between ``<!-- BEGIN section -->`` and ``<!-- END section -->`` (append if absent)."""
    begin, end = f"<!-- BEGIN {section} -->", f"<!-- END {section} -->"
    text = RESULTS_MD.read_text() if RESULTS_MD.exists() else "# Benchmark results\n\nEach section is rewritten by the script named in it.\n"
    block = f"{begin}\n{markdown.strip()}\n{end}"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        _, tail = rest.split(end, 1)
        text = head + block + tail
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    tmp = RESULTS_MD.with_suffix(".md.tmp")  # a benchmark killed mid-write leaves the old file whole
    tmp.write_text(text)
    tmp.replace(RESULTS_MD)


PAIRED_HEADER = ("mean rot ° without → with | Δ mean ° (95 % CI) | > {gross:.0f}° without → with | "
                 "only without / only with | McNemar p")


def paired_cells(c: dict) -> str:
    """The Markdown cells of one :func:`hybridpose.training.compare.paired_comparison` (A without, B
    with), in the order of ``PAIRED_HEADER``."""
    d = c["rot_mean_diff_deg"]
    return (f"{c['a']['rot_mean_deg']:.2f} → {c['b']['rot_mean_deg']:.2f} | "
            f"{d['estimate']:+.2f} ({d['ci95'][0]:+.2f}, {d['ci95'][1]:+.2f}) | "
            f"{100 * c['a']['gross_share']:.2f} % → {100 * c['b']['gross_share']:.2f} % | "
            f"{c['gross_only_a']} / {c['gross_only_b']} | {c['mcnemar_p']:.3g}")
