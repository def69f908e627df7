"""Files in the formats object-SLAM systems publish, made from a generated scene, for the README's
"Bring your own map" (no real published file can be had here):

    .venv/bin/python tools/interop_example.py [--scene demo_tum] [--out outputs/example]

writes, for the scene's map (built with `clipclique-map build` first) and its detector:
- `map_desk.yaml` + `map_desk.objects`: a GOReloc Osmap map, ellipsoids as dual quadrics in the
  SLAM frame (the first keyframe's camera), COCO-80 classes, class counts from the scene's
  detector (seed 1) over every frame; landmarks whose class has no COCO name are left out;
- `keyframes_poses_desk_tum.txt`: the ground-truth pose of every frame (`--keyframe-every N`: every Nth) in that SLAM
  frame, with 5 mm of noise (a SLAM system's keyframes);
- `detections.json`: the OA-SLAM / VOOM / GOReloc detection JSON, boxes only, of the scene's
  detector (seed 0) on every frame, COCO-80 ids, file names with the `rgb/` prefix.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from clipclique.backends import make_detector
from clipclique.interop.coco import COCO80_INDEX, reported_classes
from clipclique.interop.protowire import encode_field, encode_packed_floats, encode_packed_uints
from clipclique.interop.quadric import encode_dual_quadric
from clipclique.io.mapfile import load_map
from clipclique.perception.yolo import coco_to_vocabulary
from clipclique.resolve import default_detector, open_scene

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="demo_tum")
    parser.add_argument("--map", type=Path, help="the scene's map [default: outputs/maps/<scene>.map.npz]")
    parser.add_argument("--out", type=Path, default=Path("outputs/example"))
    parser.add_argument("--keyframe-every", type=int, default=1, help="one keyframe every N frames")
    args = parser.parse_args()
    sequence = open_scene(args.scene, ROOT / "data")
    map = load_map(args.map or Path("outputs/maps") / f"{args.scene}.map.npz")
    coco_of = reported_classes(coco_to_vocabulary(map.class_names), map.class_names)
    args.out.mkdir(parents=True, exist_ok=True)
    slam = sequence[0].pose.inverse()  # ground truth -> the first keyframe's camera frame

    kind = default_detector(sequence)
    counting = make_detector(kind, sequence.object_classes(), map.class_names, seed=1)
    querying = make_detector(kind, sequence.object_classes(), map.class_names, seed=0)
    counts = {int(i): {} for i in map.instance_ids}
    entries, keyframes = [], []
    rng = np.random.default_rng(0)
    for frame in sequence:
        counted = counting.detect(frame)
        for instance, class_id in zip(counted.instance_ids.tolist(), counted.class_ids.tolist()):
            coco = coco_of.get(map.class_names[class_id])
            if instance in counts and coco:
                counts[instance][coco] = counts[instance].get(coco, 0) + 1
        found = querying.detect(frame)
        entries.append({"file_name": f"rgb/{frame.name}.png", "detections": [
            {"category_id": COCO80_INDEX[coco_of[map.class_names[c]]], "detection_score": round(float(s), 3),
             "bbox": [round(float(v), 1) for v in box]}
            for box, c, s in zip(found.boxes, found.class_ids, found.scores) if map.class_names[c] in coco_of]})
        if frame.index % args.keyframe_every == 0:
            pose = slam.compose(frame.pose)
            position = pose.translation + rng.normal(0, 0.005, 3)
            keyframes.append(f"{frame.timestamp:.6f} " + " ".join(
                f"{v:.7f}" for v in (*position, *Rotation.from_matrix(pose.rotation).as_quat())))

    objects, written = b"", 0
    for i, instance in enumerate(map.instance_ids.tolist()):
        coco = coco_of.get(map.class_names[map.class_ids[i]])
        if coco is None:
            continue
        tally = counts[instance] or {coco: 1}
        center = slam.apply(map.ellipsoids.centers[i])
        quadric = encode_dual_quadric(center, map.ellipsoids.axes[i], slam.rotation @ map.ellipsoids.rotations[i])
        body = (encode_field(1, encode_packed_floats(1, quadric.ravel().tolist())) + encode_field(2, instance)
                + encode_packed_uints(3, [COCO80_INDEX[c] for c in tally])
                + encode_packed_uints(4, list(tally.values())))
        objects += encode_field(1, body)
        written += 1
    (args.out / "map_desk.objects").write_bytes(objects)
    (args.out / "map_desk.yaml").write_text(
        f'%YAML:1.0\n---\nobjectsFile: "map_desk.objects"\nnObjects: {written}\n')
    (args.out / "keyframes_poses_desk_tum.txt").write_text("\n".join(keyframes) + "\n")
    (args.out / "detections.json").write_text(json.dumps(entries))
    print(f"wrote {args.out}/: map_desk.yaml, map_desk.objects, keyframes_poses_desk_tum.txt ({len(keyframes)} "
          f"keyframes), detections.json ({len(entries)} frames)")


if __name__ == "__main__":
    main()
