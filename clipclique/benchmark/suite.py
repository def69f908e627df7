"""`make bench`: the paper's experiments on every available sequence, written up as a report.

    .venv/bin/python tools/bench.py                          # the demo scenes, real sequences with a map
    .venv/bin/python tools/bench.py --sequences demo --quick --out /tmp/bench

Each frame goes through the detector, the observation fit and the encoder ONCE; the observations
are cached (on disk, clipclique-bench's perception cache in outputs/cache/) and every configuration (Table I's four
methods, the ablations, the alpha sweep) localizes the cached observations. The algorithm costs milliseconds per frame,
the detector and the encoder far more, so this is what lets the suite finish in minutes.

Stochastic configurations (RANSAC, PROSAC, X-View's random walks) run with three seeds; tables
give the best seed, as the paper does, and the spread over the seeds. Scalability copies the first
sequence's map side by side (the paper's set-up) and reruns `bench_core.scalability` (a synthetic
room copied the same way). The GPU section times ViT-L-14 and YOLOv8x-seg with random weights
when CUDA is available, and says why not otherwise.
Output: `outputs/bench/<UTC timestamp>/` with report.md, PNG plots and results.json. `--docs` (what
`make docs` runs) writes them to docs/benchmark/ instead and regenerates the README's figures from them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from clipclique.backends import SPARSE
from clipclique.benchmark import calibration, literal_reference, perception, report
from clipclique.benchmark.core import growth_exponent, scalability
from clipclique.benchmark.engine import ensure_map, perceive_chunk
from clipclique.benchmark.report import PAPER_LANDMARKS_AT_1S
from clipclique.config import LITERAL, METHOD_TITLES, LocalizationConfig, make_config
from clipclique.datasets import resolve_data_root
from clipclique.exits import user_errors
from clipclique.io.outputs import BENCH_DIR, CACHE_DIR, map_file
from clipclique.localization.run import Run, RunSettings, prepare, selected_frames
from clipclique.metrics import evaluate_frame, summarize
from clipclique.outcomes import ALGORITHM_STAGES, QUERY_STAGES, Failure, FailureKind, Stage
from clipclique.pipeline import LocalizationResult, MapIndex, index_key, index_map, localize
from clipclique.sim import DEMO_SCENES
from clipclique.sim.synthetic import duplicate_rooms
from clipclique.types import Map, Observations, Pose

DOCS = Path(__file__).resolve().parents[2] / "docs" / "benchmark"
README = DOCS.parents[1] / "README.md"
OFFLINE_HUBS = {"HF_HUB_OFFLINE": "1", "YOLO_OFFLINE": "1", "YOLO_AUTOINSTALL": "false"}  # no weights downloaded
SEEDS = (0, 1, 2)  # stochastic configurations: best of three, as the paper
LITERAL_REFERENCE = report.LITERAL
BASELINES_SAMPLING = ("xview", "sh", "cliploc")  # the RANSAC / PROSAC baselines
ALPHAS = tuple(round(0.1 * i, 1) for i in range(11))
SCALABILITY_COUNTS = (50, 100, 200, 500, 1000, 2000, 5000)
QUICK_COUNTS = (50, 200, 1000)
SCENE_REPEAT = 3  # scene-copies scalability: each query's fastest of this many runs
QUICK_FRAMES = 6
Tick = Callable[[], None]


@dataclass(frozen=True)
class Variant:
    """One configuration of the experiments: a method preset plus dotted-key overrides."""

    group: str  # "methods" | "fixes" | "descriptors" | "inliers" | "weights" | "matching" | "alpha"
    label: str
    method: str = "clipclique"
    overrides: tuple[tuple[str, Any], ...] = ()
    # clipclique/benchmark/literal_reference.py instead of the pipeline (config: its alpha only)
    reference: bool = False

    def config(self, seed: int = 0) -> LocalizationConfig:
        return make_config(self.method, overrides={**dict(self.overrides), "inliers.seed": seed,
                                                   "graph.xview_seed": seed})

    @property
    def stochastic(self) -> bool:
        config = self.config()
        return config.inliers.method != "cliques" or config.similarity.descriptor == "xview"

    @property
    def needs_clip(self) -> bool:
        return self.config().similarity.descriptor == "clip" or self.group == "alpha"


def variants() -> list[Variant]:
    """Table I, then each ablation changing one part of CLIP-Clique, then the alpha sweep, then Table I's
    RANSAC/PROSAC baselines verified by 3D centre distances instead of projected overlap, and every method
    re-ranked by image verification."""
    def one(group: str, key: str, settings: tuple[tuple[Any, str], ...]) -> list[Variant]:
        return [Variant(group, label, overrides=((key, value),)) for value, label in settings]

    fixes = (("similarity.class_weight", 0.0, "without the class term"),
             ("similarity.lookalike_weight", 0.0, "without look-alike classes"),
             ("inliers.partial_slack", 0.0, "without partial-view slack"),
             ("inliers.rerank", "none", "without re-ranking"),
             ("pose.refine_radius", 0.0, "without pose refinement"),
             ("inliers.duplicate_iou", 0.0, "without the duplicate rule"))
    return [
        *(Variant("methods", METHOD_TITLES[m], m)
          for m in ("xview", "sh", "cliploc", "clipclique-paper", "clipclique")),
        Variant("methods", LITERAL_REFERENCE, "clipclique-paper", reference=True),
        Variant("fixes", "CLIP-Clique (all fixes)"),
        *(Variant("fixes", label, overrides=((key, value),)) for key, value, label in fixes),
        Variant("fixes", "CLIP-Clique (paper: none)", overrides=tuple(LITERAL.items())),
        *one("descriptors", "similarity.descriptor", (("sh", "SH"), ("clip", "CLIP"), ("fused", "SH + CLIP"))),
        *one("inliers", "inliers.method", (("ransac", "RANSAC"), ("prosac", "PROSAC"), ("cliques", "Maximal cliques"))),
        *one("weights", "pose.weights", (("none", "none"), ("sim", "w_sim"), ("com", "w_com"),
                                         ("both", "w_sim * w_com"))),
        *one("matching", "matching.strategy",
             (("one_to_one", "1-to-1"), ("knn", "kNN (k = 3)"), ("adaptive", "Adaptive"))),
        *one("alpha", "similarity.alpha", tuple((a, f"{a:.1f}") for a in ALPHAS)),
        *(Variant("verification", f"{METHOD_TITLES[m]}, centre distances", m, (("inliers.verification", "centers"),))
          for m in BASELINES_SAMPLING),
        *(Variant("rerank", f"{METHOD_TITLES[m]}, re-ranked", m, (("inliers.rerank", "verification"),))
          for m in ("xview", "sh", "cliploc", "clipclique")),
    ]


class Evaluated(NamedTuple):
    summary: dict[str, float]  # metrics.summarize, plus similarity statistics of true and of other pairs
    notes: list[str]  # the pipeline's notes (e.g. CLIP missing: alpha = 0)
    failures: dict[str, int]  # frames without a pose, by Failure.reason


@dataclass
class CachedFrame:
    index: int
    observations: Observations
    gt_pose: Pose | None


@dataclass
class CachedSequence:
    """A sequence's map and query observations, computed once and localized by every configuration."""

    name: str
    map: Map
    frames: list[CachedFrame]
    description: dict[str, Any]  # data, detector, encoder, simulated parts: the report's provenance lines
    query_ms: dict[str, float]  # median ms per frame of the detector, observation fit and encoder
    run: Run  # the sequence, detector and encoder the observations came from
    indexes: dict[str, MapIndex] = field(default_factory=dict)
    evaluated: dict[str, Evaluated] = field(default_factory=dict)

    @property
    def has_clip(self) -> bool:
        return self.map.text_embeddings is not None and all(
            f.observations.image_embeddings is not None for f in self.frames)


def available_sequences(data_root: Path) -> tuple[list[str], list[str]]:
    """The demos, plus every real ScanNet scene / TUM sequence under the data root whose map exists;
    and the real ones left out, with why."""
    names, skipped = list(DEMO_SCENES), []
    for folder in sorted([*(data_root / "scannet" / "scans").glob("scene*_*"),
                          *(data_root / "tum").glob("rgbd_dataset_*")]):
        if map_file(folder.name).is_file():
            names.append(folder.name)
        else:
            skipped.append(f"{folder.name}: no map (build it with `clipclique-map build {folder.name}`)")
    return names, skipped


def cache_sequence(name: str, data_root: Path | None, frames: int | None,
                   tick: Callable[[int], None]) -> CachedSequence:
    """The selected frames detected, fitted and embedded once, through clipclique-bench's perception
    cache (outputs/cache: a rerun reads them back); `frames` spreads that many over the sequence."""
    run = prepare(RunSettings(name, data_root=data_root, record=False))
    if frames is not None:
        run.settings = dataclasses.replace(run.settings, stride=max(1, len(run.sequence) // frames), max_frames=frames)
    selected = selected_frames(run)
    folder = perception.folder_of(CACHE_DIR, perception.key_of(run))
    cached, timings = [], []
    for i in selected:
        perceive_chunk(run.settings, (i,), folder)
        seen = perception.load(perception.frame_file(folder, i))
        tick(len(selected))
        if seen.observations is None:  # no annotations for the detector: left out, as clipclique-loc run does
            continue
        cached.append(CachedFrame(seen.index, seen.observations, seen.gt_pose))
        timings.append(seen.timings)
    description = {
        "sequence": run.sequence.name,
        "kind": run.sequence.kind,
        "synthetic": run.sequence.synthetic,
        "frames": len(cached),
        "sequence_frames": len(run.sequence),
        "stride": run.settings.stride,
        "landmarks": len(run.map),
        "frames_with_3_mapped": sum(int(mapped_pairs(f.observations, run.map).any(axis=1).sum()) >= 3 for f in cached),
        "classes": len(run.map.class_names),
        "detector": {"name": run.detector.name, "simulated": run.detector.simulated},
        "encoder": None if run.encoder is None else {"name": run.encoder.name, "simulated": run.encoder.simulated},
        "notes": run.notes,
    }
    query_ms = {stage: 1e3 * float(np.median([t[stage] for t in timings])) for stage in QUERY_STAGES}
    return CachedSequence(name, run.map, cached, description, query_ms, run)


def evaluate(sequence: CachedSequence, config: LocalizationConfig, reference: bool = False) -> Evaluated:
    """Every cached frame localized with `config` (or by the literal reference) and scored; memoized."""
    key = json.dumps([config.to_dict(), reference], sort_keys=True)
    if key not in sequence.evaluated:
        built_for = index_key(config)
        if not reference and built_for not in sequence.indexes:
            sequence.indexes[built_for] = index_map(sequence.map, config)
        localizer = (partial(literal_localize, map=sequence.map, alpha=config.similarity.alpha) if reference
                     else partial(localize, index=sequence.indexes[built_for], config=config))
        evaluations, true, other, notes, failures = [], [], [], {}, Counter()
        for frame in sequence.frames:
            result = localizer(frame.observations)
            evaluations.append(evaluate_frame(result, frame.observations, sequence.map, frame.gt_pose, config,
                                              frame.index))
            same = mapped_pairs(frame.observations, sequence.map)
            true.append(result.similarity[same])
            other.append(result.similarity[~same])
            notes.update(dict.fromkeys(result.notes))
            if result.failure:
                failures[result.failure.reason] += 1
        summary = summarize(evaluations)
        true, other = np.concatenate(true), np.concatenate(other)
        summary["similarity_true_mean"] = float(true.mean()) if true.size else math.nan
        summary["similarity_true_p90"] = float(np.percentile(true, 90)) if true.size else math.nan
        summary["similarity_other_mean"] = float(other.mean()) if other.size else math.nan
        sequence.evaluated[key] = Evaluated(summary, list(notes), dict(failures.most_common()))
    return sequence.evaluated[key]


def literal_localize(observations: Observations, map: Map, alpha: float) -> LocalizationResult:
    """clipclique/benchmark/literal_reference.py on one frame, wrapped as the pipeline's result so it is scored alike
    (its similarity matrix is not exposed: the similarity statistics of this row are NaN)."""
    start = time.perf_counter()
    hypotheses = literal_reference.localize(observations, map, alpha=alpha)
    elapsed = time.perf_counter() - start
    no_pairs = np.zeros((0, 2), dtype=np.int64)
    return LocalizationResult(hypotheses=hypotheses, candidates=no_pairs, candidate_scores=np.zeros(0),
                              similarity=np.full((len(observations), len(map)), np.nan), num_cliques=0, cap_hit=None,
                              failure=None if hypotheses else Failure(kind=FailureKind.NO_POSE),
                              timings={Stage.MATCHING: elapsed})


def mapped_pairs(observations: Observations, map: Map) -> np.ndarray:
    """(K, N) bool: observation k is landmark n's object (ground-truth instance ids)."""
    ids = observations.instance_ids[:, None]
    return (ids >= 0) & (ids == map.instance_ids[None])


# Issue 37's sparse view: a frame whose detections hit 3 to 5 distinct mapped objects (a desk corner; the real
# desk's failed frames hit 3-5), the upper bound the demo_sparse detector's own (backends.SPARSE: where it
# confuses 2 detections in 3). Fewer than 3: "few" (no pose can rest on right pairs alone); more: "busy".
SPARSE_VIEW_OBJECTS = (3, SPARSE["sparse_objects"])
VIEWS = ("all", "sparse", "busy", "few")


def view_of(observations: Observations, map: Map) -> str:
    """"sparse", "busy" or "few": the frame's view by the distinct mapped objects its observations are (ground
    truth; SPARSE_VIEW_OBJECTS)."""
    objects = int(mapped_pairs(observations, map).any(axis=0).sum())
    low, high = SPARSE_VIEW_OBJECTS
    return "few" if objects < low else "sparse" if objects <= high else "busy"


def in_view(sequence: CachedSequence, view: str) -> CachedSequence:
    """`sequence` with only its frames of `view` (VIEWS; "all": every frame, the sequence itself)."""
    if view == "all":
        return sequence
    return dataclasses.replace(sequence, frames=[f for f in sequence.frames if view_of(f.observations, sequence.map)
                                                 == view], evaluated={})


def run_variant(sequence: CachedSequence, variant: Variant, tick: Tick) -> dict[str, Any]:
    """The variant's summary on the sequence: best of SEEDS when stochastic, with the spread."""
    record: dict[str, Any] = {"group": variant.group, "label": variant.label, "method": variant.method,
                              "overrides": dict(variant.overrides), "stochastic": variant.stochastic}
    if variant.needs_clip and not sequence.has_clip:
        tick()
        return record | {"skipped": "no CLIP embeddings on this sequence (no encoder or a map without text embeddings)"}
    seeds = SEEDS if variant.stochastic else SEEDS[:1]
    runs = []
    for seed in seeds:
        runs.append(evaluate(sequence, variant.config(seed), variant.reference))
        tick()
    summaries = [run.summary for run in runs]
    best = max(range(len(runs)), key=lambda i: tuple(np.nan_to_num(summaries[i][f"success@{k}"], nan=-1.0)
                                                     for k in (1, 3, 5)))
    record |= {"seeds": list(seeds), "best_seed": seeds[best], "summary": summaries[best], "notes": runs[best].notes,
               "failures": runs[best].failures}
    if len(runs) > 1:
        record["spread"] = {column: spread([s[column] for s in summaries])
                            for column in ("success@1", "success@3", "success@5", "precision", "recall", "te_median_m")}
        record["per_seed"] = summaries
    return record


def held_out_calibration(sequences: list[CachedSequence]) -> dict[str, Any]:
    """The confidence model measured leaving one scene out at a time (clipclique/benchmark/calibration.py), or why
    not."""
    if len(sequences) < 2:
        return {"skipped": "a held-out measurement needs two sequences or more"}
    rows = calibration.collect(sequences)
    return calibration.measure(rows, calibration.held_out(rows)) | {"sequences": [s.name for s in sequences]}


def run_scalability(counts: tuple[int, ...], frames: int, scene: CachedSequence, tick: Tick) -> dict[str, Any]:
    """Latency against landmark count: bench_core's synthetic rooms, and `scene`'s own map copied
    side by side and queried with its cached frames (the paper's set-up), each with its fit."""
    rows = []
    for count in counts:
        rows.extend(scalability([count], "clipclique", room=50, frames=frames))
        tick()
    return {
        "scene": curve(scene_scalability(scene, counts, frames, tick)) | {
            "sequence": scene.name, "room_landmarks": len(scene.map),
            "frames_per_count": min(frames, len(scene.frames)),
            "fastest_of": SCENE_REPEAT},
        "synthetic": curve(rows) | {"room_landmarks": 50, "frames_per_count": frames},
    }


def scene_scalability(sequence: CachedSequence, counts: tuple[int, ...], frames: int, tick: Tick,
                      repeat: int = SCENE_REPEAT) -> list[dict]:
    """Per count: the sequence's map copied round(count / N) times side by side
    (`synthetic.duplicate_rooms`), `frames` cached queries localized with CLIP-Clique, each the
    fastest of `repeat` runs (which damps the noise of a shared machine)."""
    config = make_config("clipclique")
    queries = sequence.frames[:: max(1, len(sequence.frames) // frames)][:frames]
    rows = []
    for count in counts:
        map = duplicate_rooms(sequence.map, max(1, round(count / len(sequence.map))))
        index = index_map(map, config)
        results = [min((localize(frame.observations, index, config) for _ in range(repeat)),
                       key=lambda result: sum(result.timings.values())) for frame in queries]
        rows.append({
            "landmarks": len(map),
            "median_ms": 1e3 * float(np.median([sum(r.timings[s] for s in ALGORITHM_STAGES) for r in results])),
            "median_total_ms": 1e3 * float(np.median([sum(r.timings.values()) for r in results])),
            "candidates": float(np.median([len(r.candidates) for r in results])),
            "cliques": float(np.median([r.num_cliques for r in results])),
            "cap_hits": sum(r.cap_hit is not None for r in results),
        })
        tick()
    return rows


def curve(rows: list[dict]) -> dict[str, Any]:
    """Rows with their fitted growth exponents, the size that takes 1 s and the latency at the paper's size."""
    tail = rows[-3:]
    x = np.log([r["landmarks"] for r in rows])
    y = np.log([max(r["median_total_ms"], 1e-6) for r in rows])
    reached = y[-1] >= math.log(1000.0)
    return {
        "rows": rows,
        "exponent_algorithm": growth_exponent(rows),
        "exponent_algorithm_tail": growth_exponent(tail),
        "exponent_total": growth_exponent(rows, "median_total_ms"),
        "exponent_total_tail": growth_exponent(tail, "median_total_ms"),
        "landmarks_at_1s": float(np.exp(np.interp(math.log(1000.0), np.maximum.accumulate(y), x))) if reached else None,
        "ms_at_paper_size": float(np.exp(np.interp(math.log(PAPER_LANDMARKS_AT_1S), x, y))),
    }


def gpu_stages(run: Run, frames: int, device: str = "cuda", warmup: int = 3, clip_model: str = "ViT-L-14",
               yolo_config: str = "yolov8x-seg.yaml") -> dict[str, Any]:
    """Median ms per frame of YOLO-seg and CLIP (random weights: timing only) and the CPU fit.

    Random weights detect nothing useful, so the masks the observation fit and the encoder work on
    are the sequence's own detector's; YOLO's output is timed and discarded.
    """
    import open_clip
    import torch
    from ultralytics import YOLO

    from clipclique.perception.encoders import ClipEncoder
    from clipclique.perception.observations import extract_observations
    from clipclique.perception.yolo import YoloDetector

    torch.manual_seed(0)  # the random weights, so what YOLO detects (and NMS costs) repeats
    model, _, preprocess = open_clip.create_model_and_transforms(clip_model, pretrained=None, device=device)
    encoder = ClipEncoder(model, preprocess, open_clip.get_tokenizer(clip_model), f"open_clip:{clip_model}/random",
                          device)
    yolo = YoloDetector(YOLO(yolo_config), run.map.class_names, device=device)
    synchronize = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    times: dict[str, list[float]] = {"detector": [], "observations": [], "encoder": []}
    for count, i in enumerate(list(selected_frames(run))[: frames + warmup]):
        frame = run.sequence[i]
        clock = time.perf_counter()
        yolo.detect(frame)
        synchronize()
        detector_s = time.perf_counter() - clock
        detections = run.detector.detect(frame)
        clock = time.perf_counter()
        extraction = extract_observations(frame, detections)
        observations_s = time.perf_counter() - clock
        clock = time.perf_counter()
        encoder.encode_images(extraction.crops)
        synchronize()
        if count >= warmup:
            for stage, seconds in zip(times, (detector_s, observations_s, time.perf_counter() - clock)):
                times[stage].append(seconds)
    return {"device": torch.cuda.get_device_name() if device.startswith("cuda") else device,
            "models": [f"{clip_model} (random weights)", f"{yolo_config} (random weights)"],
            "frames": len(times["detector"]), "warmup": warmup,
            "stage_ms": {stage: 1e3 * float(np.median(values)) for stage, values in times.items()}}


def machine() -> dict[str, Any]:
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).parent).stdout.strip()
    return {"cpu": cpu_name(), "cores": os.cpu_count(), "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
            "python": platform.python_version(), "commit": commit or None}


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo (Linux), else what platform knows."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    models = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
    return models[0] if models else platform.processor() or platform.machine()


def gpu_unavailable() -> str | None:
    """Why the GPU section cannot run here, or None when it can."""
    try:
        import torch
    except ImportError:
        return "torch is not installed (the 'models' extra)"
    return None if torch.cuda.is_available() else "torch.cuda.is_available() is False on this machine (CPU only)"


def run_gpu(sequence: CachedSequence, record: dict[str, Any], frames: int = 50) -> dict[str, Any]:
    """gpu_stages on `sequence`, with CLIP-Clique's algorithm time from its Table I `record`."""
    timed = gpu_stages(sequence.run, frames)
    timed["stage_ms"]["algorithm"] = record["summary"]["time_ms_median"]
    return {"ran": True, "sequence": sequence.name, **timed}


def spread(values: list[float]) -> list[float]:
    """[min, max] of the values that exist (NaN where none does)."""
    finite = [v for v in values if not math.isnan(v)]
    return [min(finite), max(finite)] if finite else [math.nan, math.nan]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sequences", nargs="+",
                        help="default: the four demo scenes and every real sequence with a map")
    parser.add_argument("--quick", action="store_true",
                        help=f"{QUICK_FRAMES} frames per sequence, small scalability run, no GPU")
    parser.add_argument("--frames", type=int, help="frames per sequence, spread evenly [default: all]")
    parser.add_argument("--data-root", type=Path, help="datasets folder [default: $CLIPCLIQUE_DATA or ./data]")
    parser.add_argument("--out", type=Path, help="report folder [default: outputs/bench/<UTC timestamp>]")
    parser.add_argument("--docs", action="store_true",
                        help="the committed run: write to docs/benchmark/ and regenerate the README's figures")
    args = parser.parse_args(argv)
    if args.docs and (args.quick or args.frames or args.sequences or args.out):
        parser.error("--docs is the full run on every sequence: no --quick, --frames, --sequences or --out")
    if args.frames is not None and args.frames < 1:
        parser.error("--frames must be at least 1")
    return args


def main(argv: list[str] | None = None) -> None:
    """Run the suite; a user mistake (unknown sequence, missing map) is one line on stderr and exit 2."""
    args = parse_args(argv)
    for variable, value in OFFLINE_HUBS.items():  # the suite's own process only: importing it sets nothing
        os.environ.setdefault(variable, value)
    with user_errors("bench"):
        run_suite(args)


def run_suite(args: argparse.Namespace) -> None:
    started = time.perf_counter()
    stamp = datetime.now(timezone.utc)
    out = DOCS if args.docs else args.out or BENCH_DIR / stamp.strftime("%Y%m%d-%H%M%S")
    frames = QUICK_FRAMES if args.quick and args.frames is None else args.frames
    counts = QUICK_COUNTS if args.quick else SCALABILITY_COUNTS
    names, skipped = (args.sequences, []) if args.sequences else available_sequences(resolve_data_root(args.data_root))
    experiments = variants()
    results: dict[str, Any] = {"created": stamp.isoformat(timespec="seconds"), "command": " ".join(sys.argv),
                               "quick": args.quick, "machine": machine(), "skipped_sequences": skipped,
                               "sequences": {}, "experiments": {}}
    console = Console(stderr=True)
    columns = (TextColumn("{task.description:<40}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        cached: dict[str, CachedSequence] = {}
        for name in names:
            ensure_map(name, args.data_root)
            task = progress.add_task(f"{name}: detect, fit, embed", total=None)
            cached[name] = cache_sequence(name, args.data_root, frames,
                                          lambda total, task=task: progress.update(task, advance=1, total=total))
            results["sequences"][name] = cached[name].description | {"query_ms": cached[name].query_ms}
        for name, sequence in cached.items():
            work = sum(len(SEEDS) if v.stochastic else 1 for v in experiments)
            task = progress.add_task(f"{name}: {len(experiments)} configurations, {work} runs", total=work)
            tick = lambda task=task: progress.update(task, advance=1)  # noqa: E731
            results["experiments"][name] = [run_variant(sequence, v, tick) for v in experiments]
        results["calibration"] = held_out_calibration(list(cached.values()))
        first = cached[names[0]]
        task = progress.add_task("scalability (rooms side by side)", total=2 * len(counts))
        results["scalability"] = run_scalability(counts, 3 if args.quick else 20, first,
                                                 lambda: progress.update(task, advance=1))
        reason = "--quick skips it" if args.quick else gpu_unavailable()
        results["gpu"] = {"ran": False, "reason": reason}
        if reason is None:
            task = progress.add_task("GPU: ViT-L-14 + YOLOv8x-seg", total=None)
            clipclique = next(r for r in results["experiments"][first.name]
                              if r["label"] == METHOD_TITLES["clipclique"])
            try:
                results["gpu"] = run_gpu(first, clipclique)
            # a failed GPU section (out of memory, driver) must not lose the report
            except Exception as error:  # noqa: BLE001
                results["gpu"]["reason"] = f"it failed: {type(error).__name__}: {error}"
            progress.update(task, total=1, completed=1)
    results["wall_time_s"] = time.perf_counter() - started
    report.write(results, out)
    console.print(f"report: {out / 'report.md'} ({results['wall_time_s']:.0f} s)")
    if args.docs:
        README.write_text(report.update_readme(README.read_text(), report.readme_figures(results)))
        console.print(f"figures regenerated in {README}")


if __name__ == "__main__":
    main()
