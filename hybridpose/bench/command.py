"""``hybridpose bench``: the suite (or the user's BOP sequences), the runs, the outputs.

Every input is checked before any long work starts; the rows of an interrupted run are reused.
"""
from __future__ import annotations

import fnmatch
import time
from dataclasses import asdict, dataclass, replace
from dataclasses import fields as dataclass_fields
from pathlib import Path
from typing import Callable

from ..estimator import HybridConfig
from ..hybrid_config import DEFAULT_FUSION, recommended_config
from ..io import atomic_write_json, atomic_write_text
from ..machine import git_commit, package_versions
from .report import report_markdown, write_plots
from .runner import MODES, RunSpec, ray_connection, run_all
from .suite import render_suite, split_seeds, suite

SUN_CHOICES = ("known", "unknown")
RESULTS_BLOCK = "bench"  # <!-- bench:begin --> … <!-- bench:end --> in the results page
PAPER_TABLE = """The paper's single-image table (rendered truss, 224×224, after 100 epochs; random whole-object views, not
sequences): VGG-16 13.56° mean / 12.33° median rotation, 0.18 m; VGG-19 12.21° / 11.34°, 0.15 m; Branched
VGG-19 8.34° / 7.34°, 0.06 m; Parallel VGG-19 4.61° / 4.41°, 0.03 m. Our CNN on such views: the CNN
sections below."""


@dataclass(frozen=True)
class BenchRequest:
    """What ``hybridpose bench`` was asked (the CLI's options, checked by :func:`plan`)."""

    out: str
    suite: str | None = "standard"
    split: str = "report"
    data: str | None = None
    object: str = "truss"
    scale: float = 1.0
    modes: tuple[str, ...] = MODES
    trackers: tuple[str, ...] = ()  # none: the suite's default (trackers_of)
    fusions: tuple[str, ...] = (DEFAULT_FUSION,)
    regressor: str = "default"  # or one per part: "cube=fit_cube/best.pt,box=fit_box/best.pt"
    check_periods: tuple[int, ...] = ()
    configs: tuple[str, ...] = ()  # "name=value,name=value": one more hybrid run per entry
    tracker_options: tuple[str, ...] = ()  # "name=value": keyword arguments of every tracker run
    sun: tuple[str, ...] = ("known",)  # "known" and/or "unknown": every run once per entry
    workers: int = 1
    ray: str | None = None
    video: str | None = None
    limit: int | None = None
    cache: str = "runs/bench_cache"
    seeds: tuple[int, ...] | None = None  # the split's seeds instead of its default twenty
    sequences: tuple[str, ...] = ()  # shell-style patterns of sequence names to run (none: all)


def plan(req: BenchRequest) -> tuple[list[RunSpec], dict[str, Path] | None, list]:
    """The run specs, and the user's scenes (``--data``) or the suite entries; ValueError naming the
    option for anything unknown, before any rendering or CNN loading.

    The realistic suite shows two parts (``cube``, ``box``): its specs come once per part, each with
    the regressor :func:`regressor_for` gives that part (none: tracker runs only)."""
    from ..registry import available

    for mode in req.modes:
        if mode not in MODES:
            raise ValueError(f"--modes: unknown mode {mode!r}; expected some of {', '.join(MODES)}")
    for role, names, option in (("tracker", trackers_of(req), "--trackers"), ("fusion", req.fusions, "--fusions")):
        known = available(role, baselines=True)
        for n in names:
            if n not in known:
                raise ValueError(f"{option}: unknown {role} {n!r}; available: {', '.join(known)}")
    for regressor in set(regressor_map(req.regressor).values()):
        if regressor not in available("regressor") and not Path(regressor).is_file():
            raise ValueError(f"--regressor: {regressor!r} is neither a registered regressor "
                             f"({', '.join(available('regressor'))}) nor a checkpoint file")
    if req.workers < 1:
        raise ValueError(f"--workers: expected ≥ 1, got {req.workers}")
    if any(p < 0 for p in req.check_periods):
        raise ValueError(f"--check-periods: expected frame counts ≥ 0, got {req.check_periods}")
    for value in req.sun:
        if value not in SUN_CHOICES:
            raise ValueError(f"--sun: expected known and/or unknown, got {value!r}")
    if not req.sun:
        raise ValueError("--sun: expected known and/or unknown")
    if req.data is not None:
        if req.seeds is not None:
            raise ValueError("--seeds: only with --suite (your --data sequences are what they are)")
        scenes = user_scenes(req.data)
        scenes = {name: scenes[name] for name in chosen(list(scenes), req.sequences)}
        _check_video(req.video, list(scenes))
        return _specs(req, req.object, req.scale, regressor_for(req, req.object)), scenes, []
    if req.suite is None:
        raise ValueError("--suite or --data: say which sequences to run")
    entries = suite(req.suite, req.split, req.seeds)
    keep = set(chosen([e.name for e in entries], req.sequences))
    entries = [e for e in entries if e.name in keep][: req.limit]
    _check_video(req.video, [e.name for e in entries])
    if req.suite != "realistic":
        return _specs(req, req.object, req.scale, regressor_for(req, req.object)), None, entries
    parts = list(dict.fromkeys(e.object for e in entries))
    return [s for part in parts for s in _specs(req, part, 1.0, regressor_for(req, part))], None, entries


def trackers_of(req: BenchRequest) -> tuple[str, ...]:
    """The request's trackers, or the suite's default: ``combined`` off black space (the realistic
    suite), ``edges`` in space."""
    return req.trackers or (("combined",) if req.suite == "realistic" else ("edges",))


def regressor_map(text: str) -> dict[str | None, str]:
    """``--regressor``: one name or checkpoint for every part (``{None: it}``), or one per part,
    ``cube=fit_cube/best.pt,box=fit_box/best.pt`` (``{"cube": …, "box": …}``)."""
    if "=" not in text:
        return {None: text}
    out = {}
    for item in (t.strip() for t in text.split(",") if t.strip()):
        part, _, regressor = item.partition("=")
        if not part.strip() or not regressor.strip():
            raise ValueError(f"--regressor: expected NAME_OR_CHECKPOINT or PART=CHECKPOINT,PART=CHECKPOINT, got {text!r}")
        out[part.strip()] = regressor.strip()
    return out


def regressor_for(req: BenchRequest, part: str) -> str | None:
    """The regressor the CNN and hybrid runs on ``part`` use, or None where none fits it: on the
    realistic suite's parts the shipped network (fitted to the truss) has no say; a fitted one is
    given per part (:func:`regressor_map`)."""
    mapping = regressor_map(req.regressor)
    if None in mapping:
        regressor = mapping[None]
        return None if req.suite == "realistic" and regressor == "default" else regressor
    return mapping.get(part)


def _specs(req: BenchRequest, part: str, scale: float, regressor: str | None) -> list[RunSpec]:
    """The runs on one part's sequences (no CNN or hybrid run without a ``regressor``)."""
    options = {t: tracker_options(t, req.tracker_options) for t in trackers_of(req)}
    specs = []
    if "tracker" in req.modes:
        specs += [RunSpec("tracker", tracker=t, object=part, scale=scale, tracker_options=options[t])
                  for t in trackers_of(req)]
    if regressor is not None and "cnn" in req.modes:
        specs.append(RunSpec("cnn", regressor=regressor, object=part, scale=scale))
    if regressor is not None and "hybrid" in req.modes:
        base = default_policy(regressor)
        variants = [parse_config(text, base) for text in req.configs]
        configs = [base] + [replace(base, check_period=p) for p in req.check_periods if p != base.check_period] + variants
        specs += [RunSpec("hybrid", tracker=t, regressor=regressor, fusion=f, object=part, scale=scale, config=c,
                          tracker_options=options[t])
                  for t in trackers_of(req) for f in req.fusions for c in configs]
    # the CNN alone does not use the sun: one run of it, whatever --sun says
    suns = list(dict.fromkeys(req.sun))
    return [s if s.mode == "cnn" else replace(s, sun=value == "known") for value in suns for s in specs
            if s.mode != "cnn" or value == suns[0]]


def chosen(names: list[str], patterns: tuple[str, ...]) -> list[str]:
    """The sequence ``names`` that match any of ``patterns`` (shell-style, ``tumble_*``; none: all);
    ValueError naming ``--sequences`` for a pattern that matches nothing (before anything is rendered)."""
    keep = [n for n in names if not patterns or any(fnmatch.fnmatchcase(n, p) for p in patterns)]
    for pattern in patterns:
        if not any(fnmatch.fnmatchcase(n, pattern) for n in names):
            kinds = sorted({n.rsplit("_s", 1)[0] for n in names})
            raise ValueError(f"--sequences: {pattern!r} matches none of this run's sequences (NAME_sSEED; kinds: "
                             f"{', '.join(kinds[:14])}{' …' if len(kinds) > 14 else ''}), e.g. {names[0]!r}")
    return keep


def _check_video(video: str | None, names: list[str]) -> None:
    if video is not None and video not in names:
        raise ValueError(f"--video: no sequence {video!r} in this run; e.g. {', '.join(sorted(names)[:3])}")


def tracker_options(tracker: str, items) -> tuple:
    """``["max_samples=800"]`` → the sorted ``((name, value), ...)`` keyword arguments of the tracker
    registered as ``tracker``; ValueError naming ``--tracker-option`` and what it takes otherwise (the
    values themselves are checked by :func:`bench` building each tracker once before any long work)."""
    from ..registry import backend_options, get

    factory = get("tracker", tracker)
    try:
        kw = backend_options(items, factory, "--tracker-option")
    except ValueError as exc:
        raise ValueError(f"{exc} (tracker {tracker!r})") from None
    return tuple(sorted(kw.items()))


def default_policy(regressor: str) -> HybridConfig:
    """The hybrid's policy in the default row for ``--regressor`` (a registered name or a checkpoint
    file): the defaults with the fields the regressor recommends (a part's fitted checkpoint:
    ``reacquire_deg=20``), as the estimator applies them when given no config; the row's label names
    every field that differs from the defaults."""
    from ..registry import available, get

    if regressor in available("regressor"):
        recommended = getattr(get("regressor", regressor), "hybrid_config", None)
    else:
        from ..regressors.checkpoints import load_checkpoint

        recommended = load_checkpoint(regressor).get("hybrid_config")
    try:
        return recommended_config(recommended, source=f"--regressor {regressor}")
    except TypeError as exc:
        raise ValueError(str(exc)) from None


def parse_config(text: str, base: HybridConfig | None = None) -> HybridConfig:
    """``"probation_frames=2,check_below_quality=0.7"`` → ``base`` (None: the defaults) with those
    fields (``none`` or ``off`` for a field that may be None, such as ``keep_quality``); ValueError
    naming ``--config`` and the known fields otherwise."""
    fields = HybridConfig().__dict__
    optional = {f.name for f in dataclass_fields(HybridConfig) if "None" in str(f.type)}
    changes = {}
    for item in (t.strip() for t in text.split(",") if t.strip()):
        key, _, value = item.partition("=")
        key = key.strip()
        if key not in fields or not value:
            raise ValueError(f"--config: expected name=value with a name among {', '.join(fields)}, got {item!r}")
        if isinstance(fields[key], bool):
            if value.strip().lower() not in ("true", "false", "1", "0"):
                raise ValueError(f"--config: {key}: expected true or false, got {value!r}")
            changes[key] = value.strip().lower() in ("true", "1")
            continue
        if key in optional and value.strip().lower() in ("none", "off"):
            changes[key] = None
            continue
        try:
            changes[key] = type(fields[key])(float(value)) if isinstance(fields[key], int) else float(value)
        except ValueError:
            raise ValueError(f"--config: {key}: expected a number, got {value!r}") from None
    return replace(base or HybridConfig(), **changes)


def user_scenes(root) -> dict[str, Path]:
    """``{name: scene_dir}`` of every BOP scene under ``root`` (names: the path below it, '/' → '-')."""
    from ..datasets.bop import BopScene, find_scenes

    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"--data: {root} is not a folder")
    try:
        scenes = find_scenes(root)
    except (FileNotFoundError, ValueError) as exc:
        raise ValueError(f"--data: {exc}") from exc
    if not scenes:
        raise ValueError(f"--data: no BOP scene (a folder with scene_gt.json, scene_camera.json and rgb/) under {root}")
    out = {}
    for d in scenes:
        try:
            BopScene(d)
        except (FileNotFoundError, ValueError) as exc:
            raise ValueError(f"--data: {exc}") from exc
        name = str(d.relative_to(root)).replace("/", "-") if d != root else d.name
        out[name] = d
    return out


def _check_regressor(specs: list[RunSpec]) -> None:
    """Load each regressor once here: one trained for another object is refused now, not in a worker."""
    from .runner import spec_backends

    for spec in {RunSpec("cnn", regressor=s.regressor, object=s.object, scale=s.scale) for s in specs if s.mode != "tracker"}:
        spec_backends(spec)


def _check_trackers(specs: list[RunSpec]) -> None:
    """Build each tracker with its options once here: a value it refuses is an error now, not in a worker."""
    from .runner import spec_backends

    for spec in {RunSpec("tracker", tracker=s.tracker, object=s.object, scale=s.scale, tracker_options=s.tracker_options)
                 for s in specs if s.mode != "cnn" and s.tracker_options}:
        try:
            spec_backends(spec)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"--tracker-option: {spec.tracker}: {exc}") from exc


def bench(req: BenchRequest, log: Callable[[str], None] = print, progress: Callable[[str], None] | None = None) -> dict:
    """Run the request; write ``OUT/results.json``, ``OUT/report.md``, plots (and ``OUT/video/`` with
    ``--video``). Returns the result dict (``config``, ``versions``, ``commit``, ``seconds``, ``rows``)."""
    specs, scenes, entries = plan(req)
    _check_trackers(specs)
    _check_regressor(specs)
    with ray_connection(req.ray):  # a cluster that does not answer is an error before the rendering
        return _run(req, specs, scenes, entries, log, progress)


def _run(req: BenchRequest, specs: list[RunSpec], scenes: dict[str, Path] | None, entries: list,
         log: Callable[[str], None], progress: Callable[[str], None] | None) -> dict:
    out = Path(req.out)
    out.mkdir(parents=True, exist_ok=True)
    if scenes is None:
        log(f"bench: {len(entries)} sequences of suite {req.suite!r} ({req.split}) — rendering what is not cached "
            f"in {req.cache}")
        scenes = render_suite(entries, req.cache)
    parts = {e.name: e.object for e in entries} if req.suite == "realistic" else {}
    groups = {part: {n: d for n, d in scenes.items() if parts.get(n, req.object) == part}
              for part in dict.fromkeys(parts.get(n, req.object) for n in scenes)}
    for part, mine in groups.items():
        runs = [s for s in specs if s.object == part]
        log(f"bench: {len(runs)} runs × {len(mine)} sequences" + (f" of the {part}" if parts else "")
            + f", {req.workers} worker(s)" + (f" on Ray ({req.ray})" if req.ray else ""))
        if parts and not any(s.mode != "tracker" for s in runs) and set(req.modes) - {"tracker"}:
            log(f"bench: no CNN or hybrid run on the {part}: the shipped network knows the truss only; fit one "
                f"(hybridpose fit {part} --out FIT) and pass --regressor {part}=FIT/best.pt")
    t0 = time.time()
    stats: dict = {}
    rows = []
    for part, mine in groups.items():
        part_stats: dict = {}
        rows += run_all(mine, [s for s in specs if s.object == part], out=out, workers=req.workers,
                        ray_address=req.ray, progress=progress, stats=part_stats)
        stats["reused"] = stats.get("reused", 0) + part_stats.get("reused", 0)
    seeds = None if req.data else list(req.seeds or split_seeds(req.suite, req.split))
    hybrid = next((s for s in specs if s.mode == "hybrid"), None)
    split = "smoke" if req.data is None and req.suite == "smoke" else req.split
    result = {"config": {"suite": req.suite if req.data is None else None, "data": req.data, "split": split,
                         "seeds": seeds, "sequences": sorted(scenes), "workers": req.workers, "ray": req.ray,
                         "runs": list(dict.fromkeys(s.label for s in specs)),
                         "object": ",".join(groups) if parts else req.object, "scale": req.scale,
                         "hybrid_config": asdict(hybrid.config if hybrid else HybridConfig())},
              "versions": package_versions(), "commit": git_commit(), "seconds": time.time() - t0,
              "rows_reused": stats.get("reused", 0), "rows": rows}
    atomic_write_json(out / "results.json", result)
    plots = write_plots(out, result)
    atomic_write_text(out / "report.md", report_markdown(result, plots))
    result["plots"] = plots
    if req.video is not None:
        write_video(out / "video", scenes[req.video], next(s for s in specs if s.mode == "hybrid"))
    return result


def rewrite_report(out) -> dict:
    """Plots and ``report.md`` again from ``OUT/results.json`` (nothing re-run)."""
    from ..io import read_json

    out = Path(out)
    result = read_json(out / "results.json")
    plots = write_plots(out, result)
    atomic_write_text(out / "report.md", report_markdown(result, plots))
    result["plots"] = plots
    return result


def write_video(out: Path, scene_dir: Path, spec: RunSpec) -> Path:
    """The hybrid's overlay of one sequence (``tracking.run_hybrid_on_frames``)."""
    from ..tracking import run_hybrid_on_frames
    from .modes import load_sequence
    from .runner import spec_backends

    _, estimator = spec_backends(spec)
    res = run_hybrid_on_frames((s.frame for s in load_sequence(scene_dir, sun=spec.sun)), estimator, out)
    return res.video


def write_results_page(path, result: dict, plots: list[str] = (), block: str = RESULTS_BLOCK) -> None:
    """Replace the block between ``<!-- {block}:begin -->`` and ``<!-- {block}:end -->`` of the
    results page with this run's report (the main block also with the paper's table); a page without
    the block gets it at its end, a missing page is made with only the block."""
    path = Path(path)
    begin, end = f"<!-- {block}:begin -->", f"<!-- {block}:end -->"
    page = path.read_text() if path.is_file() else ""
    if begin not in page or end not in page:
        page = page + ("\n" if page and not page.endswith("\n") else "") + f"{begin}\n{end}\n"
    head, rest = page.split(begin, 1)
    _, tail = rest.split(end, 1)
    text = report_markdown(result, plots) + ("\n" + PAPER_TABLE + "\n" if block == RESULTS_BLOCK else "")
    atomic_write_text(path, head + begin + "\n" + text + end + tail)
