"""COCO classes and the COCO results format with RLE masks: shared by `--detector file:` and any
reader of COCO mask files (detectron2, mmdetection and ultralytics `save_json` write them).

Two id schemes name the same 80 classes: the contiguous 0-based ids that OA-SLAM, VOOM, GOReloc
and YOLO use (`clipclique.perception.yolo.COCO_NAMES[i]`), and the 1-based 91-id scheme with gaps of COCO's
own annotation files and results (`COCO91_IDS[i]` is class i's id there).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clipclique.interop.errors import InteropError
from clipclique.io.safeio import read_json
from clipclique.perception.yolo import COCO_NAMES

COCO91_IDS: tuple[int, ...] = (
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 27, 28, 31, 32, 33, 34,
    35, 36, 37, 38, 39, 40, 41, 42, 43, 44, 46, 47, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 60, 61, 62, 63,
    64, 65, 67, 70, 72, 73, 74, 75, 76, 77, 78, 79, 80, 81, 82, 84, 85, 86, 87, 88, 89, 90,
)
COCO91_TO_80: dict[int, int] = {coco91: index for index, coco91 in enumerate(COCO91_IDS)}
COCO80_INDEX: dict[str, int] = {name: index for index, name in enumerate(COCO_NAMES)}


@dataclass
class CocoResult:
    """One detection of a COCO results file."""

    image: str  # the image's file name (from the image list)
    class_name: str  # COCO name
    box: np.ndarray  # (4,) xyxy pixels
    score: float
    mask: np.ndarray | None  # (H, W) bool, None without a segmentation


def decode_rle(segmentation: object, where: str) -> np.ndarray:
    """(H, W) bool mask of a COCO RLE segmentation `{"size": [h, w], "counts": str | list}`: runs of 0s
    and 1s in column-major order, compressed (pycocotools' text form) or not; runs that do not fill
    exactly h * w pixels are refused."""
    if not (isinstance(segmentation, dict) and isinstance(segmentation.get("size"), list)
            and len(segmentation["size"]) == 2
            and all(isinstance(v, int) and 0 < v <= 1 << 15 for v in segmentation["size"])
            and isinstance(segmentation.get("counts"), (str, list))):
        raise InteropError(f"{where}: segmentation is not an RLE {{'size': [h, w], 'counts': ...}}")
    height, width = segmentation["size"]
    counts = segmentation["counts"]
    if isinstance(counts, str):
        counts = _string_counts(counts, where)
    elif not all(isinstance(c, int) and not isinstance(c, bool) for c in counts):
        raise InteropError(f"{where}: uncompressed RLE counts must be integers")
    if any(c < 0 for c in counts) or sum(counts) != height * width:
        raise InteropError(f"{where}: corrupt RLE counts (runs of {sum(counts)} pixels for a {height}x{width} mask)")
    values = np.arange(len(counts)) % 2 == 1  # runs alternate 0, 1, 0, ...
    return np.repeat(values, counts).reshape(width, height).T


def _string_counts(text: str, where: str) -> list[int]:
    """The run lengths of pycocotools' compressed RLE text: each a 5-bit-per-character varint ('0' + value,
    0x20 = more follows, 0x10 of the last = negative), from the third on a difference to the run two before."""
    counts: list[int] = []
    position = 0
    while position < len(text):
        value = shift = 0
        while True:
            if position >= len(text):
                raise InteropError(f"{where}: corrupt RLE counts (the text ends inside a number)")
            code = ord(text[position]) - 48
            if not 0 <= code < 64:
                raise InteropError(f"{where}: corrupt RLE counts (a character outside the RLE alphabet)")
            value |= (code & 0x1F) << shift
            position += 1
            shift += 5
            if not code & 0x20:
                if code & 0x10:
                    value -= 1 << shift
                break
        counts.append(value + counts[-2] if len(counts) > 2 else value)
    return counts


def encode_rle(mask: np.ndarray) -> dict:
    """The compressed RLE of one (H, W) bool mask, as COCO results store it (counts as text)."""
    from pycocotools import mask as coco_mask

    rle = coco_mask.encode(np.asfortranarray(mask.astype(np.uint8)))
    return {"size": [int(v) for v in rle["size"]], "counts": rle["counts"].decode("ascii")}


def read_image_list(path: Path) -> dict[int, str]:
    """image id -> file name from a COCO annotation file's `images` array (or a bare list of them)."""
    data = read_json(path, "COCO image list", InteropError)
    images = data.get("images") if isinstance(data, dict) else data
    if not isinstance(images, list):
        raise InteropError(f"{path}: expected a COCO annotation file with an 'images' list")
    out = {}
    for index, image in enumerate(images):
        if not (isinstance(image, dict) and isinstance(image.get("id"), int)
                and isinstance(image.get("file_name"), str)):
            raise InteropError(f"{path}: images[{index}] needs an integer 'id' and a 'file_name'")
        out[image["id"]] = image["file_name"]
    return out


def read_coco_results(path: Path, images: dict[int, str]) -> list[CocoResult]:
    """Every detection of a COCO results file (91-id categories), images named through `images`."""
    data = read_json(path, "COCO results file", InteropError)
    if not isinstance(data, list):
        raise InteropError(f"{path}: a COCO results file is a JSON list of detections")
    out = []
    for index, entry in enumerate(data):
        where = f"{path}, detection {index}"
        if not isinstance(entry, dict):
            raise InteropError(f"{where}: not an object")
        image, category, box, score = (entry.get(k) for k in ("image_id", "category_id", "bbox", "score"))
        if image not in images:
            raise InteropError(f"{where}: image_id {image!r} is not in the image list")
        if category not in COCO91_TO_80:
            raise InteropError(f"{where}: category_id {category!r} is not a COCO class id (1..90)")
        values = _numbers(box, 4, f"{where}: bbox")
        if values[2] <= 0 or values[3] <= 0:
            raise InteropError(f"{where}: bbox {box} has no area (width and height must be positive)")
        if not (isinstance(score, (int, float)) and 0 <= score <= 1):
            raise InteropError(f"{where}: score {score!r} is not a number in [0, 1]")
        mask = decode_rle(entry["segmentation"], where) if "segmentation" in entry else None
        out.append(CocoResult(images[image], COCO_NAMES[COCO91_TO_80[category]],
                              np.array([values[0], values[1], values[0] + values[2], values[1] + values[3]]),
                              float(score), mask))
    return out


def _numbers(value: object, count: int, where: str) -> list[float]:
    if not (isinstance(value, list) and len(value) == count
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            and np.isfinite(value).all()):
        raise InteropError(f"{where} should be {count} finite numbers, got {str(value)[:80]}")
    return [float(v) for v in value]


def coco_results(image_ids: list[int], class_names: list[str], boxes: np.ndarray, scores: np.ndarray,
                 masks: np.ndarray) -> list[dict]:
    """COCO results entries (91-id categories, xywh boxes, RLE masks) of one image's detections;
    classes outside COCO are left out (COCO has no id for them)."""
    out = []
    for image_id, name, box, score, mask in zip(image_ids, class_names, boxes, scores, masks):
        if name not in COCO80_INDEX:
            continue
        x0, y0, x1, y1 = (float(v) for v in box)
        out.append({"image_id": int(image_id), "category_id": COCO91_IDS[COCO80_INDEX[name]],
                    "bbox": [x0, y0, x1 - x0, y1 - y0], "score": float(score), "segmentation": encode_rle(mask)})
    return out


def write_json(path: Path, data: object) -> None:
    """A JSON file written whole (the caller stages it)."""
    try:
        Path(path).write_text(json.dumps(data))
    except OSError as error:
        raise InteropError(f"{path}: cannot write ({error.strerror or error})") from None


def reported_classes(vocabulary: np.ndarray, class_names: list[str]) -> dict[str, str]:
    """Map class -> the first COCO class that `vocabulary` (COCO-80 id -> map class id) maps to it: what a
    detection of that map class is written as, so that reading it back gives the same map class."""
    out: dict[str, str] = {}
    for coco, mapped in enumerate(vocabulary[:len(COCO_NAMES)]):
        if mapped >= 0:
            out.setdefault(class_names[mapped], COCO_NAMES[coco])
    return out


OBJECT_ID_KEYS = ("track_id", "instance_id", "object_id")  # an object's id across images, by tool


@dataclass
class CocoObjectMask:
    """One object's mask in one image of a COCO annotation file."""

    image: str  # the image's file name
    object_id: int  # the object's id across images (a map landmark's id)
    class_name: str  # the category's name, as the file spells it
    mask: np.ndarray  # (H, W) bool


def read_coco_annotations(path: Path) -> list[CocoObjectMask]:
    """The instance masks of a COCO annotation file (`images`, `categories`, `annotations`), as annotation
    tools export them: segmentation as RLE or polygons, classes by category name, and each annotation's
    object id across images in `track_id`, `instance_id` or `object_id` (top level or under `attributes`,
    as CVAT writes it). COCO's own per-annotation `id` names a mask, not an object, so it is not used."""
    data = read_json(path, "COCO annotation file", InteropError)
    if not (isinstance(data, dict) and all(isinstance(data.get(k), list)
                                           for k in ("images", "categories", "annotations"))):
        raise InteropError(f"{path}: a COCO annotation file is an object with 'images', 'categories' "
                           "and 'annotations' lists")
    images = {}
    for index, image in enumerate(data["images"]):
        if not (isinstance(image, dict) and isinstance(image.get("id"), int) and isinstance(image.get("file_name"), str)
                and all(isinstance(image.get(k), int) and 0 < image[k] <= 1 << 15 for k in ("width", "height"))):
            raise InteropError(f"{path}: images[{index}] needs an integer 'id', a 'file_name', 'width' and 'height'")
        images[image["id"]] = image
    categories = {}
    for index, category in enumerate(data["categories"]):
        if not (isinstance(category, dict) and isinstance(category.get("id"), int)
                and isinstance(category.get("name"), str) and category["name"].strip()):
            raise InteropError(f"{path}: categories[{index}] needs an integer 'id' and a 'name'")
        categories[category["id"]] = category["name"].strip()
    out = []
    for index, entry in enumerate(data["annotations"]):
        where = f"{path}, annotation {index}"
        if not isinstance(entry, dict):
            raise InteropError(f"{where}: not an object")
        image = images.get(entry.get("image_id"))
        if image is None:
            raise InteropError(f"{where}: image_id {entry.get('image_id')!r} is not in 'images'")
        if entry.get("category_id") not in categories:
            raise InteropError(f"{where}: category_id {entry.get('category_id')!r} is not in 'categories'")
        object_id = _object_id(entry, where)
        segmentation = entry.get("segmentation")
        if isinstance(segmentation, list):
            mask = _polygons(segmentation, image["height"], image["width"], where)
        else:
            mask = decode_rle(segmentation, where)
            if mask.shape != (image["height"], image["width"]):
                raise InteropError(f"{where}: RLE of {mask.shape[1]} x {mask.shape[0]} for an image of "
                                   f"{image['width']} x {image['height']}")
        out.append(CocoObjectMask(image["file_name"], object_id, categories[entry["category_id"]], mask))
    return out


def _object_id(entry: dict, where: str) -> int:
    attributes = entry.get("attributes") if isinstance(entry.get("attributes"), dict) else {}
    for key in OBJECT_ID_KEYS:
        for source in (entry, attributes):
            value = source.get(key)
            if value is not None:
                if not (isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= 65535):
                    raise InteropError(f"{where}: {key} {value!r} is not an object id in 1..65535")
                return value
    raise InteropError(f"{where}: no object id ({', '.join(OBJECT_ID_KEYS)}): a map needs to know which masks of "
                       "different images show one object")


def _polygons(polygons: list, height: int, width: int, where: str) -> np.ndarray:
    """(H, W) bool: the union of COCO polygons `[[x0, y0, x1, y1, ...], ...]`."""
    from pycocotools import mask as coco_mask

    if not polygons or not all(isinstance(p, list) and len(p) >= 6 and len(p) % 2 == 0 for p in polygons):
        raise InteropError(f"{where}: a polygon segmentation is a list of [x0, y0, x1, y1, ...] with 3 points or more")
    for polygon in polygons:
        _numbers(polygon, len(polygon), f"{where}: polygon")
    merged = coco_mask.merge(coco_mask.frPyObjects([[float(v) for v in p] for p in polygons], height, width))
    return decode_rle({"size": [int(v) for v in merged["size"]], "counts": merged["counts"].decode("ascii")}, where)
