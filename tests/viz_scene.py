"""A small synthetic room, frames rendered from it and simulated localization results (the real
result types, hand-made values so tests know which matches are right), for the recording tests."""

from __future__ import annotations

import functools
import importlib.util
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
import numpy as np

from clipclique.config import LocalizationConfig
from clipclique.geometry import look_at
from clipclique.metrics import FrameEvaluation, evaluate_frame
from clipclique.pipeline import LocalizationResult
from clipclique.types import Camera, Detections, Ellipsoids, Frame, Hypothesis, Map, Observations, Pose

ROOT = Path(__file__).resolve().parents[1]
CLASSES = ["chair", "table", "sofa", "tv", "plant", "lamp"]
HALF_SIZES = {"chair": (0.3, 0.3, 0.45), "table": (0.8, 0.5, 0.38), "sofa": (1.0, 0.45, 0.4),
              "tv": (0.5, 0.05, 0.3), "plant": (0.2, 0.2, 0.5), "lamp": (0.15, 0.15, 0.7)}
LAYOUT = [("table", 0.0, 0.0), ("chair", -0.6, 0.45), ("chair", 0.6, 0.45), ("chair", -0.6, -0.45),
          ("chair", 0.6, -0.45), ("sofa", 0.0, 1.8), ("tv", 0.0, -2.3), ("plant", 2.5, 2.0),
          ("plant", -2.5, -2.0), ("lamp", 2.5, -2.0), ("table", -2.3, 1.5)]
WIDTH, HEIGHT = 320, 240
INTRINSICS = np.array([[260.0, 0.0, WIDTH / 2], [0.0, 260.0, HEIGHT / 2], [0.0, 0.0, 1.0]])


@dataclass
class FrameRun:
    """What the localization loop hands the recorder for one frame."""

    frame: Frame
    detections: Detections
    observations: Observations
    result: LocalizationResult
    evaluation: FrameEvaluation


def synthetic_map() -> Map:
    names = [name for name, _, _ in LAYOUT]
    centers = np.array([(x, y, HALF_SIZES[name][2]) for name, x, y in LAYOUT])
    yaw = np.linspace(0.0, np.pi, len(LAYOUT))
    c, s = np.cos(yaw), np.sin(yaw)
    rotations = np.zeros((len(LAYOUT), 3, 3))
    rotations[:, 0, 0], rotations[:, 0, 1], rotations[:, 1, 0], rotations[:, 1, 1] = c, -s, s, c
    rotations[:, 2, 2] = 1.0
    return Map(
        ellipsoids=Ellipsoids(centers, np.array([HALF_SIZES[n] for n in names]), rotations),
        class_ids=np.array([CLASSES.index(n) for n in names]),
        class_names=list(CLASSES),
        descriptions=[f"a {['grey', 'wooden', 'blue', 'black', 'green'][i % 5]} {n}" for i, n in enumerate(names)],
        instance_ids=np.arange(1, len(LAYOUT) + 1),
        encoder="simulated-clip",
    )


def scene_points(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Floor and two walls as a dense point cloud with colours (more points than a recording keeps)."""
    rng = np.random.default_rng(seed)
    floor = np.column_stack((rng.uniform(-3.5, 3.5, 60_000), rng.uniform(-3, 3, 60_000), np.zeros(60_000)))
    wall = np.column_stack((rng.uniform(-3.5, 3.5, 30_000), np.full(30_000, 3.0), rng.uniform(0, 2.5, 30_000)))
    points = np.vstack((floor, wall))
    colors = np.where(points[:, 2:3] > 0, [180, 170, 150], [110, 90, 70]).astype(np.uint8)
    return points, colors


def render(map: Map, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RGB, depth and instance image: each landmark drawn as a disc at its centre's depth."""
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    rgb = np.empty((HEIGHT, WIDTH, 3), dtype=np.uint8)
    rgb[:] = (60 + v[..., None] * 0.4).astype(np.uint8)
    depth = np.full((HEIGHT, WIDTH), 5.0, dtype=np.float32)
    instances = np.zeros((HEIGHT, WIDTH), dtype=np.int32)
    centers = pose.inverse().apply(map.ellipsoids.centers)
    for i in np.argsort(-centers[:, 2]):  # far to near: nearer objects occlude
        x, y, z = centers[i]
        if z < 0.3:
            continue
        cu, cv = INTRINSICS[0, 0] * x / z + WIDTH / 2, INTRINSICS[1, 1] * y / z + HEIGHT / 2
        radius = INTRINSICS[0, 0] * map.ellipsoids.axes[i].max() / z
        disc = (u - cu) ** 2 + (v - cv) ** 2 < radius**2
        rgb[disc] = 40 + 35 * map.class_ids[i] + np.array([20, 90, 140]) * (i % 2)
        depth[disc], instances[disc] = z, map.instance_ids[i]
    return rgb, depth, instances


def synthetic_run(num_frames: int = 6, top_n: int = 3, seed: int = 0) -> tuple[Map, list[FrameRun]]:
    """A camera circling the room; every third frame localizes wrongly (its top-1 is a wrong clique)."""
    rng = np.random.default_rng(seed)
    map = synthetic_map()
    runs = []
    for index in range(num_frames):
        angle = 2 * np.pi * index / max(num_frames, 1)
        gt = look_at(np.array([3.2 * np.cos(angle), 3.2 * np.sin(angle), 1.6]), np.array([0.0, 0.0, 0.4]))
        rgb, depth, instances = render(map, gt)
        frame = Frame(index, 1_305_031_102.0 + index / 30, rgb, depth, INTRINSICS, gt, instances, f"{index:06d}")
        runs.append(_localize(map, frame, top_n, wrong=index % 3 == 2, rng=rng))
    return map, runs


def _localize(map: Map, frame: Frame, top_n: int, wrong: bool, rng: np.random.Generator) -> FrameRun:
    seen = [i for i, inst in enumerate(map.instance_ids) if (frame.instances == inst).sum() > 50]
    masks = np.stack([frame.instances == map.instance_ids[i] for i in seen] + [np.zeros_like(frame.depth, bool)])
    masks[-1, 10:40, 10:60] = True  # a false detection
    boxes = np.array([_box(mask) for mask in masks], dtype=float)
    class_ids = np.append(map.class_ids[seen], CLASSES.index("plant"))
    instance_ids = np.append(map.instance_ids[seen], -1)
    detections = Detections(masks, boxes, class_ids, rng.uniform(0.5, 0.99, len(masks)), instance_ids)

    in_camera = map.ellipsoids.subset(np.array(seen)).transformed(frame.pose.inverse())
    in_camera.centers = in_camera.centers + rng.normal(0, 0.03, in_camera.centers.shape)
    observations = Observations(in_camera, class_ids[:-1], None, instance_ids[:-1], np.arange(len(seen)), boxes[:-1],
                                masks[:-1].sum(axis=(1, 2)), Camera(INTRINSICS, WIDTH, HEIGHT))

    truth = np.column_stack((np.arange(len(seen)), seen))
    shuffled = np.column_stack((np.arange(len(seen)), np.roll(seen, 1)))
    candidates = np.vstack((truth, shuffled))
    hypotheses = []
    for rank in range(top_n):
        bad = wrong if rank == 0 else rank % 2 == 1
        offset = rng.normal(0, 0.8 if bad else 0.05, 3)
        pose = Pose(frame.pose.rotation, frame.pose.translation + offset)
        hypotheses.append(Hypothesis(pose, shuffled[:3] if bad else truth, float(3.0 - rank * 0.4),
                                     verification=0.5 if bad else 3.0, confidence=0.1 if bad else 0.9))
    result = LocalizationResult(
        hypotheses=hypotheses,
        candidates=candidates,
        candidate_scores=rng.uniform(0.3, 0.9, len(candidates)),
        similarity=rng.uniform(0, 1, (len(seen), len(map))),
        num_cliques=int(rng.integers(5, 40)),
        cap_hit=None,
        failure=None,
        notes=["simulated detections and CLIP"],
        timings={"descriptors": 0.002, "similarity": 0.001, "matching": 0.0005, "inliers": 0.01, "pose": 0.001},
    )
    evaluation = evaluate_frame(result, observations, map, frame.pose, LocalizationConfig(), frame.index)
    return FrameRun(frame, detections, observations, result, evaluation)


def _box(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    return cols[0], rows[0], cols[-1] + 1, rows[-1] + 1


@functools.cache
def load_screenshot_tool() -> ModuleType:
    """tools/screenshot.py as a module (tools/ holds scripts, not a package)."""
    spec = importlib.util.spec_from_file_location("clipclique_screenshot_tool", ROOT / "tools" / "screenshot.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up here
    spec.loader.exec_module(module)
    return module


def rerun_cli(*args: str) -> subprocess.CompletedProcess:
    binary = load_screenshot_tool().viewer_binary()
    return subprocess.run([str(binary), *args], capture_output=True, text=True, timeout=120)


def recorded_entities(path: Path) -> dict[str, tuple[int, set[str]]]:
    """Entity path -> (rows logged, data columns) of a recording, read back with `rerun rrd print`."""
    printed = rerun_cli("rrd", "print", str(path))
    assert printed.returncode == 0, printed.stderr
    entities: dict[str, tuple[int, set[str]]] = {}
    for rows, entity, columns in re.findall(r"with (\d+) rows .*? - (\S+) - data columns: \[(.*)\]", printed.stdout):
        count, known = entities.get(entity, (0, set()))
        entities[entity] = (count + int(rows), known | set(columns.split()))
    return entities
