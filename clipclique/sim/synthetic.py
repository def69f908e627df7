"""Synthetic maps and query observations with known ground truth, for tests and benchmarks.

Everything here is simulated: landmarks are random labelled ellipsoids in a room, "CLIP"
embeddings are random unit vectors (an observation's image embedding is its landmark's text
embedding plus noise), and observations are a neighbourhood of landmarks moved into the frame of a
camera looking at it, with centre noise, partial-view shrinking and false detections. Each
observation's "detection box" is its observed ellipsoid projected into the simulated camera's
image (`SIMULATED_CAMERA`); one out of view gets an empty box.
"""

from __future__ import annotations

import numpy as np

from clipclique.sim.poses import look_at
from clipclique.types import Camera, Ellipsoids, Map, Observations, Pose
from clipclique.verify.projection import box_area, project

ENCODER = "simulated-clip"
SIMULATED_CAMERA = Camera(np.array([[320.0, 0.0, 320.0], [0.0, 320.0, 240.0], [0.0, 0.0, 1.0]]), 640, 480, 8.0)


def synthetic_map(
    rng: np.random.Generator,
    num_landmarks: int = 40,
    num_classes: int = 8,
    room: tuple[float, float, float] = (5.0, 5.0, 1.5),
    embedding_dim: int = 32,
) -> Map:
    """Random landmarks in a box `room` (metres), several per class, with simulated text embeddings."""
    centers = rng.uniform(0.0, 1.0, size=(num_landmarks, 3)) * np.asarray(room)
    angles = rng.uniform(0.0, 2 * np.pi, num_landmarks)
    rotations = np.zeros((num_landmarks, 3, 3))
    rotations[:, 0, 0] = rotations[:, 1, 1] = np.cos(angles)
    rotations[:, 1, 0] = np.sin(angles)
    rotations[:, 0, 1] = -np.sin(angles)
    rotations[:, 2, 2] = 1.0
    class_ids = rng.integers(0, num_classes, num_landmarks)
    names = [f"class{c}" for c in range(num_classes)]
    return Map(
        ellipsoids=Ellipsoids(centers, rng.uniform(0.1, 0.6, size=(num_landmarks, 3)), rotations),
        class_ids=class_ids,
        class_names=names,
        descriptions=[f"{names[c]} number {i}" for i, c in enumerate(class_ids)],
        instance_ids=np.arange(num_landmarks) + 1,
        text_embeddings=_unit(rng.normal(size=(num_landmarks, embedding_dim))).astype(np.float32),
        encoder=ENCODER,
        provenance={"simulated": True},
    )


def duplicate_rooms(map: Map, copies: int, gap: float = 2.0) -> Map:
    """`copies` side-by-side copies of `map` along x, `gap` metres apart (the paper's scalability
    set-up); copy j's instance ids are offset by j * (max id + 1)."""
    centers = map.ellipsoids.centers
    shift = np.ptp(centers[:, 0]) + gap if len(centers) else 0.0
    offsets = np.zeros((copies, 1, 3))
    offsets[:, 0, 0] = np.arange(copies) * shift
    stride = int(map.instance_ids.max()) + 1 if len(map) else 1
    tile = lambda array: np.concatenate([array] * copies)  # noqa: E731
    return Map(
        ellipsoids=Ellipsoids(
            (centers[None] + offsets).reshape(-1, 3), tile(map.ellipsoids.axes), tile(map.ellipsoids.rotations)
        ),
        class_ids=tile(map.class_ids),
        class_names=list(map.class_names),
        descriptions=list(map.descriptions) * copies,
        instance_ids=(map.instance_ids[None] + stride * np.arange(copies)[:, None]).ravel(),
        text_embeddings=None if map.text_embeddings is None else tile(map.text_embeddings),
        encoder=map.encoder,
        provenance={**map.provenance, "duplicated_rooms": copies},
    )


def synthetic_query(
    map: Map,
    rng: np.random.Generator,
    num_visible: int = 10,
    num_outliers: int = 2,
    center_noise: float = 0.05,
    embedding_noise: float = 0.5,
) -> tuple[Observations, Pose]:
    """Observations of the `num_visible` landmarks nearest a random map point, seen by a camera 2-5 m
    away looking at that point, plus `num_outliers` false detections (instance id -1). Returns
    (observations, camera-to-map pose).

    A map of fewer than `num_visible` landmarks is seen whole."""
    num_visible = min(num_visible, len(map))
    anchor = map.ellipsoids.centers[rng.integers(len(map))]
    visible = np.argsort(np.linalg.norm(map.ellipsoids.centers - anchor, axis=1))[:num_visible]
    direction = rng.normal(size=3)
    pose = look_at(anchor + rng.uniform(2.0, 5.0) * direction / np.linalg.norm(direction), anchor)
    seen = map.ellipsoids.subset(visible).transformed(pose.inverse())
    seen.centers = seen.centers + rng.normal(scale=center_noise, size=seen.centers.shape)
    seen.axes = seen.axes * rng.uniform(0.6, 1.0, size=seen.axes.shape)  # partial views look smaller

    false = map.ellipsoids.subset(rng.integers(len(map), size=num_outliers)).transformed(pose.inverse())
    false.centers = false.centers + rng.uniform(-1.5, 1.5, size=false.centers.shape)
    ellipsoids = Ellipsoids(
        np.concatenate((seen.centers, false.centers)),
        np.concatenate((seen.axes, false.axes)),
        np.concatenate((seen.rotations, false.rotations)),
    )
    class_ids = np.concatenate((map.class_ids[visible], rng.integers(0, len(map.class_names), num_outliers)))
    embeddings = None
    if map.text_embeddings is not None:
        dim = map.text_embeddings.shape[1]
        true = map.text_embeddings[visible] + rng.normal(scale=embedding_noise / np.sqrt(dim), size=(num_visible, dim))
        embeddings = _unit(np.concatenate((true, rng.normal(size=(num_outliers, dim))))).astype(np.float32)
    seen_in_image = project(ellipsoids, np.eye(3)[None], np.zeros((1, 3)), SIMULATED_CAMERA)
    boxes = np.where(seen_in_image.visible[0, :, None], seen_in_image.boxes[0], 0.0)
    observations = Observations(
        ellipsoids=ellipsoids,
        class_ids=class_ids,
        image_embeddings=embeddings,
        instance_ids=np.concatenate((map.instance_ids[visible], -np.ones(num_outliers, dtype=np.int64))),
        detection_index=np.arange(num_visible + num_outliers),
        boxes=boxes,
        mask_areas=np.round(np.pi / 4 * box_area(boxes)).astype(np.int64),  # the ellipse inscribed in the box
        camera=SIMULATED_CAMERA,
    )
    return observations, pose


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)
