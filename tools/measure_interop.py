"""Side-by-side measurements of issue 17 on the generated scenes, one process, same frames.

    .venv/bin/python tools/measure_interop.py box-only [demo_desk demo_apartment] [--max-frames N] \\
        [--set min_mode_share=0.6]
    .venv/bin/python tools/measure_interop.py soft-classes [demo demo_tum demo_apartment demo_desk]
    .venv/bin/python tools/measure_interop.py vocabularies [demo_desk demo_clutter] [--max-frames N]

box-only: each frame's detections (the scene's own detector) fitted twice, from their masks and
from their boxes alone (the masks replaced by `clipclique.interop.boxfit.box_mask` of the mask's
box), then localized. Printed: median distance of each box-only observation centre from the mask
fit of the same detection; median centre error of both against the true landmark (in the camera
frame, by instance id); top-1 success within 0.5 / 1 / 2 m of both.

soft-classes: a GOReloc-like map of each scene: every landmark's class distribution counted from
the scene's detector over every frame (seed 1, not the queries' 0), its class the most counted
(landmarks never detected keep their annotated class). Localized (clipclique and sh) with
`similarity.soft_classes` off and on; top-1 success within 0.5 / 1 / 2 m.

vocabularies (issue 38): the scene's COCO map written in LVIS names, as MSG-Loc's LVIS maps are, two ways: one
LVIS name per COCO class ("renamed": `cup` is `mug` throughout), and a name drawn per landmark among the class's
LVIS names ("mixed", seed 0: some cups are `mug`, some `cup`, some `teacup`). The scene's COCO detections meet each
map through `clipclique.interop.labels.class_lookup`, as a COCO detection file's do; each LVIS map is measured
as read and as `clipclique.interop.labels.met_by` meets it for COCO detections (classes named by their COCO
class, as `clipclique-loc run` does for a file's or YOLO's detections). Printed per map: its classes,
the landmarks whose class a COCO detection class reaches (a counterpart), and top-1 success within
0.25 / 0.5 / 1 / 2 m (clipclique and sh) beside the COCO map on the same frames.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from collections import Counter
from pathlib import Path

from clipclique.blas import one_blas_thread_by_default  # noqa: E402

one_blas_thread_by_default()  # before numpy loads, as the CLIs (clipclique.blas)

import numpy as np  # noqa: E402

from clipclique.backends import load_encoder, make_detector  # noqa: E402
from clipclique.descriptors.lookalikes import LVIS_TO_COCO  # noqa: E402
from clipclique.interop.boxfit import BoxSegmentation, box_mask  # noqa: E402
from clipclique.interop.labels import COCO, class_lookup, label_set, met_by  # noqa: E402
from clipclique.io.mapfile import save_map  # noqa: E402
from clipclique.localization.run import RunSettings, prepare, selected_frames  # noqa: E402
from clipclique.mapping.build import build_map  # noqa: E402
from clipclique.metrics import evaluate_frame  # noqa: E402
from clipclique.perception.observations import embed, extract_observations  # noqa: E402
from clipclique.pipeline import index_map, localize  # noqa: E402
from clipclique.resolve import default_detector, open_scene  # noqa: E402
from clipclique.types import Detections, Map  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
THRESHOLDS = (0.5, 1.0, 2.0)
FINE_THRESHOLDS = (0.25, 0.5, 1.0, 2.0)


def built_map(scene: str, folder: Path) -> Path:
    path = folder / f"{scene}.map.npz"
    if not path.exists():
        map, _ = build_map(open_scene(scene, ROOT / "data"), load_encoder("simulated"))
        save_map(map, path)
    return path


def success(errors: list[float | None], thresholds: tuple[float, ...] = THRESHOLDS) -> str:
    return " / ".join(f"{100 * np.mean([e is not None and e < t for e in errors]):5.1f}" for t in thresholds)


def box_only(scene: str, folder: Path, max_frames: int | None, segmentation: BoxSegmentation) -> None:
    run = prepare(RunSettings(scene, map_path=built_map(scene, folder), data_root=ROOT / "data", max_frames=max_frames))
    index = index_map(run.map, run.config)
    centre = {lm: c for lm, c in zip(run.map.instance_ids.tolist(), run.map.ellipsoids.centers)}
    errors: dict[str, list] = {"mask": [], "box": []}
    centre_errors: dict[str, list[float]] = {"mask": [], "box": []}
    apart, kept = [], Counter()
    for i in selected_frames(run):
        frame = run.sequence[i]
        detections = run.detector.detect(frame)
        boxed = Detections(np.array([box_mask(frame.depth, frame.intrinsics, b, params=segmentation)
                                     for b in detections.boxes]).reshape(detections.masks.shape),
                           detections.boxes, detections.class_ids, detections.scores, detections.instance_ids)
        fitted = {}
        for variant, dets in (("mask", detections), ("box", boxed)):
            extraction = extract_observations(frame, dets, run.config.observations)
            observations = embed(extraction, run.encoder)
            result = localize(observations, index, run.config)
            evaluation = evaluate_frame(result, observations, run.map, frame.pose, run.config, frame.index)
            errors[variant].append(evaluation.translation_error)
            world = frame.pose.inverse()
            for obs_centre, instance in zip(observations.ellipsoids.centers, observations.instance_ids.tolist()):
                if instance in centre:
                    centre_errors[variant].append(float(np.linalg.norm(obs_centre - world.apply(centre[instance]))))
            fitted[variant] = dict(zip(observations.detection_index.tolist(), observations.ellipsoids.centers))
            kept[variant] += len(observations)
        apart += [float(np.linalg.norm(c - fitted["mask"][k])) for k, c in fitted["box"].items() if k in fitted["mask"]]
    print(f"{scene}: {len(errors['mask'])} frames, detector {run.detector.name}; observations kept: mask "
          f"{kept['mask']}, box-only {kept['box']}")
    print(f"  box-only centre vs the mask fit of the same detection: median {100 * np.median(apart):.1f} cm")
    for variant in ("mask", "box"):
        print(f"  {variant:>4}: median centre error vs the landmark {100 * np.median(centre_errors[variant]):5.1f} cm; "
              f"top-1 within 0.5 / 1 / 2 m: {success(errors[variant])} %")


def counted_map(scene: str, folder: Path) -> Path:
    """The scene's map with class distributions counted from its detector (seed 1) over every frame."""
    run = prepare(RunSettings(scene, map_path=built_map(scene, folder), data_root=ROOT / "data"))
    detector = make_detector(default_detector(run.sequence), run.sequence.object_classes(), run.map.class_names, seed=1)
    counts = np.zeros((len(run.map), len(run.map.class_names)))
    row = {instance: i for i, instance in enumerate(run.map.instance_ids.tolist())}
    for frame in run.sequence:
        detections = detector.detect(frame)
        for instance, class_id in zip(detections.instance_ids.tolist(), detections.class_ids.tolist()):
            if instance in row:
                counts[row[instance], class_id] += 1
    never = counts.sum(axis=1) == 0
    counts[never, run.map.class_ids[never]] = 1
    distributions = counts / counts.sum(axis=1, keepdims=True)
    map = dataclasses.replace(run.map, class_ids=counts.argmax(axis=1).astype(np.int64),
                              class_distributions=distributions)
    path = folder / f"{scene}.counted.map.npz"
    save_map(map, path)
    unsure = distributions.max(axis=1) < 1
    changed = int((map.class_ids != run.map.class_ids).sum())
    print(f"{scene}: {len(map)} landmarks, {int(unsure.sum())} with more than one class counted, "
          f"{changed} whose most counted class is not the annotated one")
    return path


def soft_classes(scene: str, folder: Path) -> None:
    path = counted_map(scene, folder)
    for method in ("clipclique", "sh"):
        for soft in (False, True):
            run = prepare(RunSettings(scene, method=method, map_path=path, data_root=ROOT / "data",
                                      overrides=[f"similarity.soft_classes={str(soft).lower()}"]))
            index = index_map(run.map, run.config)
            errors = []
            for i in selected_frames(run):
                frame = run.sequence[i]
                detections = run.detector.detect(frame)
                observations = embed(extract_observations(frame, detections, run.config.observations), run.encoder)
                result = localize(observations, index, run.config)
                errors.append(evaluate_frame(result, observations, run.map, frame.pose, run.config,
                                             frame.index).translation_error)
            print(f"  {method:>10} soft_classes={'on ' if soft else 'off'}: top-1 within 0.5 / 1 / 2 m: "
                  f"{success(errors)} %")


def lvis_names(coco: str) -> list[str]:
    """The LVIS names of a COCO class: its own name where LVIS has it, and each LVIS name LVIS_TO_COCO maps to it."""
    lvis = set(label_set("lvis").names)
    return [name for name in (coco, *sorted(n for n, c in LVIS_TO_COCO.items() if c == coco)) if name in lvis]


def lvis_map(map: Map, mixed: bool) -> Map:
    """`map` in LVIS names as an import with `--labels lvis` records it: each class's first LVIS name, or
    (`mixed`) a name drawn per landmark (seed 0)."""
    rng = np.random.default_rng(0)
    names = [lvis_names(name) or [name] for name in map.class_names]
    chosen = [str(rng.choice(names[c])) if mixed else names[c][0] for c in map.class_ids.tolist()]
    vocabulary = sorted(set(chosen))
    source = dict(map.provenance.get("source", {})) | {"labels": "lvis"}
    return dataclasses.replace(map, class_names=vocabulary, provenance=dict(map.provenance) | {"source": source},
                               class_ids=np.array([vocabulary.index(n) for n in chosen], dtype=np.int64))


def in_vocabulary(detections: Detections, names: list[str], lookup: dict[str, int]) -> Detections:
    """`detections` (class ids into `names`) with class ids into the map `lookup` reaches; the others dropped."""
    ids = np.array([lookup.get(names[c].lower(), -1) for c in detections.class_ids.tolist()], dtype=np.int64)
    keep = ids >= 0
    return Detections(detections.masks[keep], detections.boxes[keep], ids[keep], detections.scores[keep],
                      detections.instance_ids[keep], detections.masks_in_boxes)


def vocabularies(scene: str, folder: Path, max_frames: int | None) -> None:
    coco_run = prepare(RunSettings(scene, map_path=built_map(scene, folder), data_root=ROOT / "data",
                                   max_frames=max_frames))
    coco = coco_run.map
    detected = sorted({coco.class_names[c] for c in coco.class_ids.tolist()})
    renamed, mixed = lvis_map(coco, mixed=False), lvis_map(coco, mixed=True)
    maps = {"COCO": coco, "LVIS, renamed, as read": renamed, "LVIS, renamed, met": met_by(renamed, COCO)[0],
            "LVIS, mixed, as read": mixed, "LVIS, mixed, met": met_by(mixed, COCO)[0]}
    frames = list(selected_frames(coco_run))
    print(f"{scene}: {len(coco)} landmarks, {len(frames)} frames, detector {coco_run.detector.name}")
    for label, map in maps.items():
        lookup = class_lookup(map.class_names)
        reached = {lookup[name.lower()] for name in detected if name.lower() in lookup}
        found = int(np.isin(map.class_ids, sorted(reached)).sum())
        line = [f"  {label:>22}: {len(map.class_names)} classes, {found} of {len(map)} landmarks with a counterpart;"]
        for method in ("clipclique", "sh"):
            run = prepare(RunSettings(scene, method=method, map_path=built_map(scene, folder),
                                      data_root=ROOT / "data", max_frames=max_frames))
            index = index_map(map, run.config)
            errors = []
            for i in frames:
                frame = run.sequence[i]
                detections = in_vocabulary(run.detector.detect(frame), coco.class_names, lookup)
                observations = embed(extract_observations(frame, detections, run.config.observations), run.encoder)
                result = localize(observations, index, run.config)
                errors.append(evaluate_frame(result, observations, map, frame.pose, run.config,
                                             frame.index).translation_error)
            line.append(f"{method} {success(errors, FINE_THRESHOLDS)} %")
        print(" ".join(line))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiment", choices=("box-only", "soft-classes", "vocabularies"))
    parser.add_argument("scenes", nargs="*")
    parser.add_argument("--max-frames", type=int)
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="a BoxSegmentation setting (clipclique/interop/boxfit.py), for box-only")
    args = parser.parse_args()
    segmentation = BoxSegmentation(**{key: type(getattr(BoxSegmentation(), key))(value)
                                      for key, _, value in (item.partition("=") for item in args.set)})
    with tempfile.TemporaryDirectory() as folder:
        if args.experiment == "box-only":
            for scene in args.scenes or ["demo_desk", "demo_apartment"]:
                box_only(scene, Path(folder), args.max_frames, segmentation)
        elif args.experiment == "vocabularies":
            for scene in args.scenes or ["demo_desk", "demo_clutter"]:
                vocabularies(scene, Path(folder), args.max_frames)
        else:
            for scene in args.scenes or ["demo", "demo_tum", "demo_apartment", "demo_desk"]:
                soft_classes(scene, Path(folder))


if __name__ == "__main__":
    main()
