"""Your own object, end to end: a CNN fitted to a part nobody trained for, then tracker-only vs CNN-only
vs hybrid on sequences of it in front of a real photo the fit never saw.

    python benchmarks/own_object.py --out runs/own_object [--budget 60m] [--workers N]
    python benchmarks/own_object.py --out runs/own_object --split tuning --tuning-photos DIR

1. writes a plain box mesh (180 × 110 × 70 mm, in millimetres as CAD exports are);
2. ``hybridpose fit`` for it within ``--budget`` (random lights and colours; backgrounds half
   procedural clutter, half cut from the photos that ship with scikit-image — astronaut, coffee, cat,
   motorcycles, rocket, textures: ``pip install hybridpose[bench]``; ``--train-photos none`` for
   procedural backgrounds only);
3. renders thirty 60-frame sequences — tumble, approach, fly-around, with and without the arm passing in
   front, five seeds each — over crops of ``grace_hopper.jpg`` — a photograph that ships with matplotlib
   and that no training view used — one look per sequence;
4. ``hybridpose bench --data`` on them with the fitted checkpoint (trackers ``edges`` and ``combined``,
   the one ``hybridpose track`` picks on a lit scene), and rewrites the ``own-object`` block of
   ``benchmarks/RESULTS.md``.

Every step resumes. Seeds: the fit's 0 (training views) and 1 (held-out views); the sequences' 1–30.
Nothing here was tuned on these sequences. ``--split tuning`` renders the box's tuning sequences instead —
the same six kinds, seeds 101–130, over the photos in ``--tuning-photos`` (those used so far: two photos
of circuit boards, ``f3.jpg`` and ``verify.jpeg`` of the Rust embedded book, installed with the Rust
documentation) — and benches them without touching the results page: what to tune on.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import matplotlib

from hybridpose.hybrid_config import DEFAULT_FUSION
from hybridpose.workers import usable_cores

KINDS = (("tumble", "none"), ("tumble", "arm-full"), ("approach", "none"), ("approach", "arm-partial"),
         ("fly-around", "none"), ("fly-around", "arm-full"))
SEEDS_PER_KIND = 5  # the spread over seeds (median, p90, worst of each kind), not one sequence a kind
# the library's default fusion first (its row carries the targets), the other one beside it: on the box's
# tuning sequences ukf led where on the truss's isam2 did (docs/decisions.md)
FUSIONS = ",".join(dict.fromkeys((DEFAULT_FUSION, "isam2", "ukf")))
# combined first (what `hybridpose track` picks on a lit scene such as a box over a photo: edges, region
# and texture; its rows carry the targets), then edges (the space tracker) beside it
TRACKERS = "combined,edges"
# round r renders every kind once, kind k with seed 6·r + k + the split's first: report 1–30, tuning 101–130
FIRST_SEED = {"report": 1, "tuning": 101}


def sequences(split: str) -> tuple[tuple[str, str, int], ...]:
    """(trajectory, occlusion, seed) of the split's thirty sequences."""
    first = FIRST_SEED[split]
    return tuple((trajectory, occlusion, len(KINDS) * r + k + first)
                 for r in range(SEEDS_PER_KIND) for k, (trajectory, occlusion) in enumerate(KINDS))


BOX_MM = (180.0, 110.0, 70.0)


# scikit-image's sample photos of scenes and textures (not its microscopy, text or synthetic images)
TRAIN_PHOTOS = ("astronaut.png", "coffee.png", "chelsea.png", "motorcycle_left.png", "motorcycle_right.png",
                "rocket.jpg", "camera.png", "coins.png", "grass.png", "gravel.png", "brick.png", "hubble_deep_field.jpg")


def training_photos(folder: Path) -> Path:
    """``folder`` filled with :data:`TRAIN_PHOTOS` from the installed scikit-image; a clear error without it."""
    try:
        import skimage
    except ImportError:
        raise SystemExit("--train-photos skimage: scikit-image is not installed (pip install hybridpose[bench]); "
                         "or pass --train-photos none") from None
    source = Path(skimage.__file__).parent / "data"
    folder.mkdir(parents=True, exist_ok=True)
    for name in TRAIN_PHOTOS:
        if (source / name).is_file():
            shutil.copy(source / name, folder / name)
    if not any(folder.iterdir()):
        raise SystemExit(f"--train-photos skimage: none of its sample photos under {source}")
    return folder


def hp(*args) -> None:
    subprocess.run([sys.executable, "-m", "hybridpose", *map(str, args)], check=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/own_object")
    ap.add_argument("--budget", default="60m")
    ap.add_argument("--workers", type=int, default=None,
                    help="processes for the fit's renders and the benchmark's sequences (default: one per core)")
    ap.add_argument("--results-md", default=str(Path(__file__).parent / "RESULTS.md"))
    ap.add_argument("--train-photos", choices=("skimage", "none"), default="skimage",
                    help="backgrounds of the training views: half from scikit-image's sample photos (default), "
                         "or procedural clutter only")
    ap.add_argument("--textured-share", type=float, default=None,
                    help="share of the training views with a random print on the box (hybridpose fit "
                         "--textured-share; default: fit's)")
    ap.add_argument("--split", choices=tuple(FIRST_SEED), default="report",
                    help="report: the sequences over grace_hopper.jpg that RESULTS shows (seeds 1–30); tuning: "
                         "the tuning sequences over --tuning-photos (seeds 101–130), results in OUT/bench_tuning only")
    ap.add_argument("--tuning-photos", default=None, help="folder of the photos behind the tuning sequences")
    args = ap.parse_args()
    if args.split == "tuning" and not (args.tuning_photos and Path(args.tuning_photos).is_dir()):
        raise SystemExit("--split tuning: give --tuning-photos DIR, a folder of photos none of the fit's training "
                         "views and none of the report sequences use")
    import trimesh

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    mesh = out / "box_mm.obj"
    if not mesh.is_file():
        trimesh.creation.box(extents=BOX_MM).export(mesh)
    fit = out / "fit"
    extra = [] if args.textured_share is None else ["--textured-share", args.textured_share]
    # its own photos, or none at all (procedural clutter alone), never the fit's default ones
    extra += ["--backgrounds", training_photos(out / "train_photos") if args.train_photos == "skimage" else "none"]
    hp("fit", mesh, "--scale", 0.001, "--out", fit, "--budget", args.budget, *extra,
       *([] if args.workers is None else ["--workers", args.workers]))
    if args.split == "tuning":
        photos, seqs, results = Path(args.tuning_photos), out / "tuning_seqs", []
    else:
        photos, seqs = out / "photos", out / "seqs"
        photos.mkdir(exist_ok=True)
        shutil.copy(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg", photos)
        results = ["--results-md", args.results_md, "--results-block", "own-object"]
    for trajectory, occlusion, seed in sequences(args.split):
        hp("render", "--object", mesh, "--scale", 0.001, "--kind", "sequence", "--trajectory", trajectory,
           "--occlusion", occlusion, "--frames", 60, "--size", "640x480", "--seed", seed, "--appearance", "random",
           "--backgrounds", photos, "--photo-share", 1, "--out", seqs / f"{trajectory}_{occlusion}_s{seed}")
    hp("bench", "--data", seqs, "--object", mesh, "--scale", 0.001, "--regressor", fit / "best.pt",
       "--trackers", TRACKERS, "--fusions", FUSIONS, "--workers", args.workers or usable_cores(),
       "--out", out / ("bench" if args.split == "report" else "bench_tuning"), *results)


if __name__ == "__main__":
    main()
