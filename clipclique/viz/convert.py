"""Our arrays as Rerun archetypes: ellipsoids, cameras, compressed images, detection overlays."""

from __future__ import annotations

import functools
import io
import math

import numpy as np
import rerun as rr
from PIL import Image
from rerun.encodings import ChannelDatatype
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from clipclique.types import Detections, Ellipsoids, Pose
from clipclique.viz.style import annotation_ids

JPEG_QUALITY = 85
DEPTH_UNITS_PER_METRE = 100  # depth for viewing: 16-bit centimetres ...
DEPTH_STRIDE = 4  # ... of every fourth pixel (160 x 120 of a VGA frame: a side view, not projected), raw:
# Rerun's LZ4 chunk compression makes it 22 kB a frame in 0.5 ms, where a half-size PNG took 45 kB and 18 ms


def ellipsoids3d(ellipsoids: Ellipsoids, class_ids: np.ndarray, **options) -> rr.Ellipsoids3D:
    """Ellipsoids coloured by class through the annotation context unless `colors` is given (`options`: those of
    `ellipsoid_fields`)."""
    return rr.Ellipsoids3D(**with_quaternions(ellipsoid_fields(ellipsoids, class_ids, **options)))


def ellipsoid_fields(
    ellipsoids: Ellipsoids,
    class_ids: np.ndarray,
    labels: list[str] | None = None,
    colors: np.ndarray | None = None,
    fill_mode: str = "TransparentFillMajorWireframe",
    show_labels: bool = True,
) -> dict:
    """The fields of the ellipsoids' Ellipsoids3D (those given), for an ArchetypeRows row, but `rotations` (N, 3, 3)
    where it takes quaternions: `with_quaternions` converts them, for a whole column at once when the rows are
    kept until close (scipy's conversion costs about as much for one frame as for a thousand)."""
    fields = {
        "centers": ellipsoids.centers,
        "half_sizes": ellipsoids.axes,
        "rotations": ellipsoids.rotations,
        "class_ids": annotation_ids(class_ids),
        "colors": colors,
        "labels": labels,
        "fill_mode": fill_mode,
        "show_labels": show_labels,
    }
    return {name: value for name, value in fields.items() if value is not None}


def with_quaternions(fields: dict) -> dict:
    """`fields` with their `rotations` (N, 3, 3) as Rerun's `quaternions` (N, 4), x y z w."""
    rotations = fields.pop("rotations")
    return fields | {"quaternions": Rotation.from_matrix(rotations).as_quat() if len(rotations) else np.zeros((0, 4))}


def camera(
    pose: Pose | None, intrinsics: np.ndarray, width: int, height: int, color: np.ndarray, plane: float
) -> list:
    """Transform3D (camera-to-world; cleared when the pose is unknown) + Pinhole, frustum `plane` m deep."""
    if pose is None:
        transform = rr.Transform3D.cleared()
    else:
        transform = rr.Transform3D(translation=pose.translation, mat3x3=pose.rotation)
    look = (np.asarray(intrinsics, dtype=np.float64).reshape(3, 3).tobytes(), width, height,
            tuple(np.ravel(color).tolist()))
    return [transform, pinhole(*look, plane)]


def camera_row(pose: Pose, intrinsics: np.ndarray, width: int, height: int, color: np.ndarray, plane: float) -> dict:
    """What `camera` logs for a known pose, as plain fields: a row of `camera_columns`."""
    return {"translation": pose.translation, "mat3x3": pose.rotation,
            "image_from_camera": np.asarray(intrinsics, dtype=np.float64).reshape(3, 3), "resolution": (width, height),
            "image_plane_distance": plane, "color": tuple(np.ravel(color).tolist())}


def camera_columns(rows: list[dict]) -> list[rr.ComponentColumn]:
    """Rows of `camera_row` as the columns of a Transform3D and its Pinhole, one value a row, for one `send_columns`
    call (a Pinhole sent apart from its Transform3D breaks the viewer's transform tree)."""
    field = lambda name: [row[name] for row in rows]  # noqa: E731
    return [*rr.Transform3D.columns(translation=field("translation"), mat3x3=field("mat3x3")),
            *rr.Pinhole.columns(image_from_camera=field("image_from_camera"), resolution=field("resolution"),
                                camera_xyz=[rr.ViewCoordinates.RDF] * len(rows),
                                image_plane_distance=field("image_plane_distance"), color=field("color"))]


@functools.lru_cache(maxsize=64)
def pinhole(intrinsics: bytes, width: int, height: int, color: tuple[int, ...], plane: float) -> rr.Pinhole:
    """Built once per look (`intrinsics`: 3 x 3 float64 bytes): a run's cameras share a few, and building one
    costs more than logging it."""
    return rr.Pinhole(
        image_from_camera=np.frombuffer(intrinsics, dtype=np.float64).reshape(3, 3),
        resolution=[width, height],
        camera_xyz=rr.ViewCoordinates.RDF,
        image_plane_distance=plane,
        color=color,
    )


def encode_jpeg(rgb: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(buffer, format="JPEG", quality=quality)
    return buffer.getvalue()


def depth_units(depth: np.ndarray) -> np.ndarray:
    """Metric depth for viewing: every `DEPTH_STRIDE`-th pixel as uint16 in `1 / DEPTH_UNITS_PER_METRE`
    metre steps, invalid pixels 0."""
    depth = depth[::DEPTH_STRIDE, ::DEPTH_STRIDE]
    valid = np.isfinite(depth) & (depth > 0)
    units = np.where(valid, np.round(depth * DEPTH_UNITS_PER_METRE), 0).clip(0, np.iinfo(np.uint16).max)
    return units.astype(np.uint16)


def rgb_fields(rgb: np.ndarray) -> dict:
    """The fields of the rgb's EncodedImage (a JPEG), for an ArchetypeRows row."""
    return {"blob": encode_jpeg(rgb), "media_type": "image/jpeg"}


def depth_fields(depth: np.ndarray) -> dict:
    """The fields of the depth's DepthImage (see `depth_units`), for an ArchetypeRows row."""
    return image_fields(depth_units(depth)) | {"meter": DEPTH_UNITS_PER_METRE}


def image_fields(image: np.ndarray) -> dict:
    """The buffer and format `rr.DepthImage(image)` or `rr.SegmentationImage(image)` make of a 2D array."""
    height, width = image.shape
    format = rr.components.ImageFormat(width=width, height=height,
                                       channel_datatype=ChannelDatatype.from_np_dtype(image.dtype))
    return {"buffer": image.tobytes(), "format": format}


def segmentation(detections: Detections, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) annotation ids of the detection masks (0 = none); where masks overlap the higher score
    wins. uint8 while the ids fit, which halves the (uncompressed) image. Masks that lie in their boxes
    (`Detections.masks_in_boxes`) are read in their boxes only (a pixel's margin either side): the same image."""
    if len(detections) == 0:
        return np.zeros(shape, dtype=np.uint8)
    ids = annotation_ids(detections.class_ids)
    label = np.zeros(shape, dtype=np.min_scalar_type(ids.max()))
    everywhere = (slice(None), slice(None))
    for k in np.argsort(detections.scores, kind="stable"):  # a higher score paints over a lower one
        rows, columns = box_window(detections.boxes[k], shape) if detections.masks_in_boxes else everywhere
        np.copyto(label[rows, columns], ids[k], where=detections.masks[k, rows, columns], casting="unsafe")
    return label


def box_window(box: np.ndarray, shape: tuple[int, int]) -> tuple[slice, slice]:
    """(rows, columns) of an xyxy pixel box widened by a pixel and clipped to an (H, W) image: every pixel
    of a mask inside the box, whichever way its edges were rounded."""
    x0, y0, x1, y1 = np.asarray(box, dtype=np.float64).tolist()
    height, width = shape
    return (slice(min(max(math.floor(y0) - 1, 0), height), min(max(math.ceil(y1) + 1, 0), height)),
            slice(min(max(math.floor(x0) - 1, 0), width), min(max(math.ceil(x1) + 1, 0), width)))


BOX_LABEL_WIDTH = 3.0  # a box label (`potted plant 0.51`) is about this many times wider than tall
BOX_LABEL_SPACING = 32.0  # image pixels: labels whose anchors are nearer (across: x BOX_LABEL_WIDTH) would overlap


def box_fields(detections: Detections, class_names: list[str]) -> tuple[dict, dict]:
    """The detection boxes with a visible label where it does not crowd a larger box's (the viewer draws it
    under the box's centre), and the crowded ones labelled on hover only: the fields of two Boxes2D (an
    ArchetypeRows row each), centres and half sizes as `rr.Boxes2D(array=..., array_format=XYXY)` makes them."""
    labels = np.array([f"{class_names[c]} {s:.2f}" for c, s in zip(detections.class_ids, detections.scores)],
                      dtype=object)
    boxes = np.asarray(detections.boxes, dtype=np.float64).reshape(-1, 4)
    anchors = np.column_stack(((boxes[:, 0] + boxes[:, 2]) / 2 / BOX_LABEL_WIDTH, boxes[:, 3]))
    shown = spread_labels(anchors, (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]), BOX_LABEL_SPACING)
    class_ids = annotation_ids(detections.class_ids)
    centers = (boxes[:, :2] + boxes[:, 2:]) / 2
    half_sizes = boxes[:, 2:] - centers
    return tuple({"centers": centers[keep], "half_sizes": half_sizes[keep], "class_ids": class_ids[keep],
                  "labels": labels[keep].tolist(), "show_labels": visible}
                 for keep, visible in ((shown, True), (~shown, False)))


def spread_labels(centers: np.ndarray, sizes: np.ndarray, spacing: float) -> np.ndarray:
    """(N,) bool: which landmarks show their label. Largest first, a label is kept when no kept one is
    within `spacing` (in the units of `centers`), so a dining table with its chairs, cups and books shows a few
    labels, not a heap; the same in the image for detection boxes."""
    shown = np.zeros(len(centers), bool)
    if len(centers) == 0:
        return shown
    neighbours = cKDTree(centers).query_ball_point(centers, spacing)
    for i in np.argsort(-sizes, kind="stable"):
        shown[i] = not shown[neighbours[i]].any()
    return shown




def voxel_downsample(
    points: np.ndarray, colors: np.ndarray | None, voxel: float, max_points: int
) -> tuple[np.ndarray, np.ndarray | None]:
    """One point per `voxel`-sized cell (the first), then an even subsample down to `max_points`."""
    cells = np.floor(points / voxel).astype(np.int64)
    _, keep = np.unique(cells, axis=0, return_index=True)
    keep.sort()
    if len(keep) > max_points:
        keep = keep[np.linspace(0, len(keep) - 1, max_points).astype(np.int64)]
    return points[keep], None if colors is None else colors[keep]
