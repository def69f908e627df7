"""Rerun recordings: the conversions they are made of, and each recording read back from disk."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from clipclique.config import LocalizationConfig
from clipclique.descriptors.graph import semantic_graph
from clipclique.metrics import evaluate_frame
from clipclique.outcomes import Failure, FailureKind
from clipclique.types import Detections, Ellipsoids
from clipclique.viz import LocalizationRecorder, class_colors, write_map_recording
from clipclique.viz.convert import depth_units, ellipsoids3d, encode_jpeg, segmentation, spread_labels, voxel_downsample
from clipclique.viz.localization_recording import sample_indices
from clipclique.viz.map_recording import CEILING_MARGIN, LABEL_SPACING, below_landmarks, graph_edges
from clipclique.viz.recording import ArchetypeRows, ColumnsAtClose
from clipclique.viz.style import CORRECT, UNKNOWN, WRONG, correctness_colors, hsv_to_rgb, match_correctness, palette


@pytest.fixture(scope="module")
def run(synthetic_run):
    return synthetic_run(num_frames=6, top_n=3)


@pytest.fixture(scope="module")
def map_rrd(tmp_path_factory, run, scene_points) -> Path:
    path = tmp_path_factory.mktemp("map") / "room.map.rrd"
    points, colors = scene_points()
    write_map_recording(path, run[0], points, colors, "# Synthetic room\nbuilt for a test")
    return path


@pytest.fixture(scope="module")
def loc_rrd(tmp_path_factory, run) -> Path:
    path = tmp_path_factory.mktemp("loc") / "recording.rrd"
    map, frames = run
    with LocalizationRecorder(path, map, "# clipclique on a synthetic room\nsimulated detections") as recorder:
        for f in frames:
            recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
    return path


def rgb_of(packed: list[int]) -> np.ndarray:
    """(N, 3) uint8 from Rerun colours (packed 0xRRGGBBAA)."""
    packed = np.asarray(packed, dtype=np.uint32)
    return np.column_stack([(packed >> shift) & 0xFF for shift in (24, 16, 8)]).astype(np.uint8)


class LogSpy:
    """Records what a recorder logs (and sends as columns at close), while still writing it; reading waits for
    the recorder's thread."""

    def __init__(self, recorder: LocalizationRecorder) -> None:
        self._calls: list[tuple[str, tuple]] = []
        self.sent: list[tuple[str, dict[str, list], dict[str, list]]] = []  # path, timelines, components
        self._recorder = recorder
        self._log = recorder.stream.log
        self._send_columns = recorder.stream.send_columns
        recorder.stream.log = self
        recorder.stream.send_columns = self.send_columns

    def __call__(self, path: str, *archetypes, **kwargs) -> None:
        self._calls.append((path, archetypes))
        self._log(path, *archetypes, **kwargs)

    def send_columns(self, path: str, indexes, columns, **kwargs) -> None:
        indexes, columns = list(indexes), list(columns)
        self.sent.append((path, {index.timeline_name(): index.as_arrow_array().to_numpy().astype(np.int64).tolist()
                                for index in indexes},
                          {str(c.component_descriptor()): c.as_arrow_array().to_pylist() for c in columns}))
        self._send_columns(path, indexes=indexes, columns=columns, **kwargs)

    def rows(self, path: str, component: str) -> list[tuple[int, list]]:
        """(frame, the instances of that row) of every row sent in `path`'s columns of `component`."""
        return [(frame, value) for sent_path, timelines, components in self.sent
                if sent_path == path and component in components
                for frame, value in zip(timelines["frame"], components[component], strict=True)]

    def series(self, path: str, component: str = "Scalars:scalars") -> dict[int, object]:
        """Frame -> the one value sent at that frame in `path`'s columns of `component`."""
        rows = {}
        for frame, value in self.rows(path, component):
            assert frame not in rows, (path, frame)
            (rows[frame],) = value  # one value a row
        return rows

    @property
    def calls(self) -> list[tuple[str, tuple]]:
        self._recorder.flush()
        return self._calls

    def last(self, path: str) -> tuple:
        return [archetypes for logged, archetypes in self.calls if logged == path][-1]


def test_class_colors_follow_the_class_name_not_the_vocabulary():
    names = [f"class{i}" for i in range(40)]
    colors = class_colors(names)
    assert colors.shape == (40, 3) and colors.dtype == np.uint8
    np.testing.assert_array_equal(colors, class_colors(names))
    # the same class, the same colour, whatever else the map holds and in whatever order (was vocabulary order)
    np.testing.assert_array_equal(class_colors(["sofa", "chair"]),
                                  class_colors(["tv", "chair", "lamp", "sofa"])[[3, 1]])
    np.testing.assert_array_equal(class_colors(["Sofa "]), class_colors(["sofa"]))
    shades = palette().astype(float)
    assert len(np.unique(shades, axis=0)) == len(shades) == 48
    assert all(any((color == shade).all() for shade in shades) for color in colors.astype(float))
    distances = np.linalg.norm(shades[:, None] - shades[None], axis=-1)[np.triu_indices(len(shades), 1)]
    assert distances.min() > 20  # two classes share a colour or are told apart
    luminance = shades / 255 @ np.array([0.2126, 0.7152, 0.0722])
    assert luminance.min() >= 0.49  # readable as label text on the viewer's dark background (no dark purple)


def test_annotation_context_is_rerun_s_own():
    """The context built as Arrow is the very array `rr.AnnotationContext(infos)` makes (without pyarrow.compute:
    tests/integration/test_run_imports.py)."""
    from clipclique.viz.style import annotation_context

    names = ["chair", "Table", "potted plant", ""]
    colors = class_colors(names)
    infos = [rr.AnnotationInfo(id=0, label="background", color=(0, 0, 0, 0))]
    infos += [rr.AnnotationInfo(id=i + 1, label=name, color=tuple(int(c) for c in color))
              for i, (name, color) in enumerate(zip(names, colors))]
    assert annotation_context(names).context.as_arrow_array().equals(
        rr.AnnotationContext(infos).context.as_arrow_array())
    assert annotation_context([]).context.as_arrow_array().equals(
        rr.AnnotationContext(infos[:1]).context.as_arrow_array())


def test_hsv_conversion_is_matplotlibs():
    """The class colours were matplotlib's `hsv_to_rgb`; the recording no longer imports matplotlib for them."""
    from matplotlib.colors import hsv_to_rgb as matplotlib_hsv_to_rgb

    rng = np.random.default_rng(2)
    hsv = np.vstack([rng.uniform(0, 1, (500, 3)), [[0, 0, 0.3], [0.5, 0, 1], [1 / 6, 1, 1], [5 / 6, 0.5, 0.5]]])
    np.testing.assert_array_equal(hsv_to_rgb(hsv), matplotlib_hsv_to_rgb(hsv))


def test_labels_are_spread_over_crowded_landmarks():
    """A table with chairs around it and cups on it shows the table's and the far chairs' labels only."""
    centers = np.array([[0, 0, 0.4], [0.1, 0.1, 0.8], [-0.1, 0.0, 0.8], [0.9, 0, 0.45], [-0.9, 0, 0.45], [3, 3, 0.4]])
    sizes = np.array([1.0, 0.001, 0.001, 0.1, 0.1, 0.1])
    np.testing.assert_array_equal(spread_labels(centers, sizes, LABEL_SPACING), [True, False, False, True, True, True])
    assert spread_labels(np.zeros((0, 3)), np.zeros(0), LABEL_SPACING).shape == (0,)


def test_ellipsoids_carry_rerun_quaternions_and_annotation_ids():
    quarter_turn = np.array([[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])  # 90 deg about z
    archetype = ellipsoids3d(Ellipsoids(np.ones((1, 3)), np.array([[0.3, 0.2, 0.1]]), quarter_turn), np.array([4]))
    quaternion = archetype.quaternions.as_arrow_array().to_pylist()[0]
    np.testing.assert_allclose(quaternion, [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-7)  # x y z w
    assert archetype.class_ids.as_arrow_array().to_pylist() == [5]  # 0 is the background id


def test_segmentation_higher_score_wins_and_zero_is_background():
    masks = np.zeros((2, 4, 5), dtype=bool)
    masks[0, :, :3] = True
    masks[1, :, 2:4] = True
    detections = Detections(masks, np.zeros((2, 4)), np.array([0, 6]), np.array([0.9, 0.4]), np.array([1, 2]))
    label = segmentation(detections, (4, 5))
    np.testing.assert_array_equal(label[0], [1, 1, 1, 7, 0])  # column 2 overlaps: score 0.9 (class 0) wins
    assert label.dtype == np.uint8
    empty = Detections(np.zeros((0, 4, 5), bool), np.zeros((0, 4)), np.zeros(0, int), np.zeros(0), np.zeros(0, int))
    assert not segmentation(empty, (4, 5)).any()


def test_segmentation_reads_masks_in_their_boxes_only_where_they_lie_there():
    """Masks that lie in their boxes are painted from their boxes alone: byte for byte the image of painting
    every mask over the whole frame (overlaps, ties in score, boxes with fractional, edge and out-of-frame
    corners, an empty mask); a mask outside its box is painted whole when the detector does not promise."""
    def painted_whole(detections: Detections, shape: tuple[int, int]) -> np.ndarray:
        ids = detections.class_ids + 1
        label = np.zeros(shape, dtype=np.min_scalar_type(ids.max()))
        for k in np.argsort(detections.scores, kind="stable"):
            label[detections.masks[k]] = ids[k]
        return label

    rng = np.random.default_rng(4)
    shape = (30, 40)
    boxes = np.array([[0, 0, 12.5, 9.2], [5.7, 3.1, 40, 30], [30.2, 20.9, 44, 35], [-3, -2, 4, 5], [10, 10, 10, 10],
                      [8, 2, 20, 14]])
    masks = np.zeros((len(boxes), *shape), bool)
    for mask, (x0, y0, x1, y1) in zip(masks, boxes):
        rows, columns = (slice(max(int(np.floor(y0)), 0), int(np.ceil(y1))),
                         slice(max(int(np.floor(x0)), 0), int(np.ceil(x1))))
        mask[rows, columns] = rng.random(mask[rows, columns].shape) < 0.7
    scores = np.array([0.9, 0.5, 0.5, 0.7, 0.2, 0.5])  # ties: the later detection paints over
    class_ids = np.array([3, 300, 1, 0, 7, 2])  # an id over 255: uint16
    for ids in (class_ids, class_ids % 200):
        inside = Detections(masks, boxes, ids, scores, np.arange(len(ids)), masks_in_boxes=True)
        label = segmentation(inside, shape)
        expected = painted_whole(inside, shape)
        assert label.dtype == expected.dtype
        np.testing.assert_array_equal(label, expected)
        assert len(np.unique(label)) > 4
    outside = masks.copy()
    outside[0, 25:, 30:] = True  # beyond its box
    spilled = Detections(outside, boxes, class_ids, scores, np.arange(len(boxes)))
    np.testing.assert_array_equal(segmentation(spilled, shape), painted_whole(spilled, shape))
    assert (segmentation(spilled, shape)[25:, 30:] != 0).all()


def test_depth_is_subsampled_centimetres_and_jpeg_is_small():
    depth = np.full((8, 12), 9.0, dtype=np.float32)
    depth[0, 0], depth[0, 4], depth[4, 0], depth[4, 4], depth[1, 1] = 0.0, 1.234, np.nan, 4.0, 2.0
    units = depth_units(depth)
    assert units.dtype == np.uint16
    np.testing.assert_array_equal(units, [[0, 123, 900], [0, 400, 900]])  # every 4th pixel; invalid -> 0
    rgb = np.random.default_rng(0).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    rgb[:, :160] = 90  # half flat, as real images are
    assert len(encode_jpeg(rgb)) < rgb.nbytes / 3


def test_voxel_downsample_keeps_one_point_per_cell_and_caps():
    points = np.array([[0.01, 0.01, 0.0], [0.02, 0.03, 0.0], [0.2, 0.0, 0.0], [0.0, 0.0, 0.31]])
    colors = np.arange(12, dtype=np.uint8).reshape(4, 3)
    kept, kept_colors = voxel_downsample(points, colors, voxel=0.05, max_points=10)
    np.testing.assert_array_equal(kept, points[[0, 2, 3]])
    np.testing.assert_array_equal(kept_colors, colors[[0, 2, 3]])
    assert len(voxel_downsample(points, None, voxel=0.05, max_points=2)[0]) == 2


def test_ceiling_points_are_left_out(run):
    map = run[0]
    top = (map.ellipsoids.centers[:, 2] + map.ellipsoids.axes.max(axis=1)).max()  # the lamp, 0.7 + 0.7 m
    heights = np.array([0.0, 1.0, top + CEILING_MARGIN - 0.01, top + CEILING_MARGIN + 0.01, 2.8])
    points = np.column_stack((np.zeros(5), np.zeros(5), heights))
    kept, colors = below_landmarks(map, points, np.arange(15).reshape(5, 3))
    np.testing.assert_array_equal(kept[:, 2], heights[:3])
    np.testing.assert_array_equal(colors[:, 0], [0, 3, 6])


def test_graph_edges_are_the_semantic_graph():
    centers = np.random.default_rng(1).uniform(0, 3, (30, 3))
    edges = graph_edges(centers, 0.8)
    expected = {tuple(pair) for pair in np.argwhere(np.triu(semantic_graph(centers, 0.8).toarray(), 1))}
    assert {tuple(edge) for edge in edges} == expected and len(expected) > 5
    assert np.all(np.linalg.norm(centers[edges[:, 0]] - centers[edges[:, 1]], axis=1) < 0.8)


def test_trajectories_are_thinned_to_a_bound():
    np.testing.assert_array_equal(sample_indices(4, limit=10), [0, 1, 2, 3])
    many = sample_indices(1001, limit=300)
    assert len(many) == 300 and many[0] == 0 and many[-1] == 1000
    assert np.diff(many).max() <= 4  # evenly spread: no gap much over 1000 / 300


def test_match_colors_green_right_red_wrong_grey_unknown():
    correct = match_correctness(np.array([3, 3, -1]), np.array([3, 4, 3]))
    np.testing.assert_array_equal(correct, [1, 0, -1])
    np.testing.assert_array_equal(correctness_colors(correct), [CORRECT, WRONG, UNKNOWN])


def test_map_recording_verifies_and_holds_every_entity(map_rrd, run, rerun_cli, recorded_entities):
    verified = rerun_cli("rrd", "verify", str(map_rrd))
    assert verified.returncode == 0, verified.stderr
    entities = recorded_entities(map_rrd)
    assert {"Ellipsoids3D:centers", "Ellipsoids3D:half_sizes", "Ellipsoids3D:quaternions", "Ellipsoids3D:labels",
            "Ellipsoids3D:class_ids", "description", "instance_id"} <= entities["/world/map/landmarks"][1]
    assert "LineStrips3D:strips" in entities["/world/map/graph"][1]
    assert "Points3D:positions" in entities["/world/map/scene"][1]
    assert "AnnotationContext:context" in entities["/"][1]
    assert "TextDocument:text" in entities["/description"][1]
    assert "EyeControls3D:look_target" in {c for _, columns in entities.values() for c in columns}  # blueprint
    assert not map_rrd.with_name(map_rrd.name + ".partial").exists()


def test_a_map_without_landmarks_records_without_warnings(tmp_path, run):
    import warnings

    empty = dataclasses.replace(run[0], ellipsoids=Ellipsoids.empty(), class_ids=np.zeros(0, int), descriptions=[],
                                instance_ids=np.zeros(0, int))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # rerun warned: "AnyValues: No valid component batches to return"
        write_map_recording(tmp_path / "empty.rrd", empty, None, None, "x")
        with LocalizationRecorder(tmp_path / "loc.rrd", empty, "x"):
            pass
    assert (tmp_path / "empty.rrd").is_file() and (tmp_path / "loc.rrd").is_file()


def test_map_recording_scene_is_downsampled(tmp_path, run, scene_points):
    """120k input points on a 5 cm grid over 7 x 6 m of floor and 7 x 2.5 m of wall: about 24k kept."""
    points, colors = scene_points()
    full, light = tmp_path / "full.rrd", tmp_path / "light.rrd"
    write_map_recording(light, run[0], points, colors, "x")
    write_map_recording(full, run[0], None, None, "x")
    scene_bytes = light.stat().st_size - full.stat().st_size
    assert scene_bytes < 24_000 * 15 * 1.2  # 12 B position + 3 B colour per kept point, plus slack
    assert scene_bytes > 24_000 * 15 * 0.3  # ... and the scene is there


def test_localization_recording_verifies_and_holds_every_stage(loc_rrd, run, rerun_cli, recorded_entities):
    verified = rerun_cli("rrd", "verify", str(loc_rrd))
    assert verified.returncode == 0, verified.stderr
    entities = recorded_entities(loc_rrd)
    frames = len(run[1])
    per_frame = {
        "/world/camera/gt": "Pinhole:image_from_camera",
        "/world/camera/gt/rgb": "EncodedImage:blob",
        "/depth": "DepthImage:buffer",
        "/world/camera/gt/detections/masks": "SegmentationImage:buffer",
        "/world/camera/gt/detections/boxes": "Boxes2D:class_ids",
        "/world/camera/estimate/1": "Transform3D:translation",
        "/world/observations/gt": "Ellipsoids3D:centers",
        "/world/observations/estimate": "Ellipsoids3D:centers",
        "/world/correspondences/candidates": "LineStrips3D:strips",
        "/world/hypotheses/1": "LineStrips3D:strips",
        "/world/hypotheses/3": "LineStrips3D:strips",
        "/world/trajectory/gt": "LineStrips3D:strips",
        "/world/trajectory/estimate": "Points3D:positions",
        "/metrics/error/translation_m": "Scalars:scalars",
        "/metrics/error/rotation_deg": "Scalars:scalars",
        "/metrics/count/candidates": "Scalars:scalars",
        "/metrics/count/cliques": "Scalars:scalars",
        "/metrics/time/matching": "Scalars:scalars",
        "/metrics/time/inliers": "Scalars:scalars",
        "/metrics/match/recall": "Scalars:scalars",
        "/metrics/confidence/top1": "Scalars:scalars",
        "/world/camera/gt/projected_landmarks": "LineStrips2D:strips",
    }
    for entity, column in per_frame.items():
        rows, columns = entities[entity]
        assert column in columns, entity
        assert rows == frames, entity
    assert "Transform3D:mat3x3" in entities["/world/camera/gt"][1]
    assert "Ellipsoids3D:class_ids" in entities["/world/map/landmarks"][1]
    assert entities["/log"][0] >= frames  # one line per frame at least
    assert "TextDocument:text" in entities["/description"][1]


def test_localization_recording_has_frame_and_tum_timelines(loc_rrd, rerun_cli):
    printed = rerun_cli("rrd", "print", "-vv", "--entity", "/metrics/count/cliques", str(loc_rrd))
    assert "index_name: frame" in printed.stdout and "index_name: time" in printed.stdout


def test_localization_recording_size_per_frame(tmp_path, loc_rrd, run):
    """Compressed images keep a 320x240 frame far below its raw 400 kB (rgb + float depth + masks)."""
    map, frames = run
    with LocalizationRecorder(tmp_path / "empty.rrd", map, "# clipclique on a synthetic room\nsimulated detections"):
        pass
    per_frame = (loc_rrd.stat().st_size - (tmp_path / "empty.rrd").stat().st_size) / len(frames)
    assert 5_000 < per_frame < 60_000


def test_matches_are_coloured_by_ground_truth(tmp_path, run):
    map, frames = run
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    good, bad = frames[0], frames[2]  # frame 2's top-1 is a wrong clique (see the synthetic_run fixture)
    for f in (good, bad):
        recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
    recorder.close()
    candidates = spy.rows("world/correspondences/candidates", "LineStrips3D:colors")
    top1 = spy.rows("world/hypotheses/1", "LineStrips3D:colors")
    assert [frame for frame, _ in candidates] == [frame for frame, _ in top1] == [good.frame.index, bad.frame.index]
    for f, (_, strip_colors), (_, top1_colors) in zip((good, bad), candidates, top1):
        visible = len(f.observations)
        candidate_colors = rgb_of(strip_colors)
        assert (candidate_colors == CORRECT).all(axis=1).sum() == visible  # the true pairs
        assert (candidate_colors == WRONG).all(axis=1).sum() == len(f.result.candidates) - visible
        expected = CORRECT if f is good else WRONG
        assert (len(top1_colors) == len(f.result.hypotheses[0].correspondences)
                and (rgb_of(top1_colors) == expected).all())


def test_stale_ranks_are_cleared_and_failures_logged(tmp_path, run):
    map, frames = run
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    first, second = frames[0], frames[1]
    recorder.log_frame(first.frame, first.detections, first.observations, first.result, first.evaluation)
    failed = dataclasses.replace(second.result, hypotheses=[], failure=Failure(kind=FailureKind.FEW_MATCHED, count=2))
    recorder.log_frame(second.frame, second.detections, second.observations, failed, None)
    recorder.close()  # clears and the text log are sent as columns at close
    for rank in (1, 2, 3):
        assert spy.series(f"world/hypotheses/{rank}", "Clear:is_recursive") == {second.frame.index: True}
        assert spy.series(f"world/camera/estimate/{rank}", "Clear:is_recursive") == {second.frame.index: True}
    assert spy.series("world/observations/estimate", "Clear:is_recursive") == {second.frame.index: False}
    assert spy.series("world/observations/gt", "Clear:is_recursive") == {}  # the truth still places them
    placed = spy.rows("world/observations/gt", "Ellipsoids3D:centers")
    assert [(frame, len(centers)) for frame, centers in placed] == [
        (first.frame.index, len(first.observations)), (second.frame.index, len(second.observations))]
    lines = [(frame, text, level) for (frame, (text,)), (_, (level,))
             in zip(spy.rows("log", "TextLog:text"), spy.rows("log", "TextLog:level"), strict=True)]
    assert ([frame for frame, text, _ in lines if text.startswith(f"frame {frame} ")]
            == [first.frame.index, second.frame.index])
    assert [(frame, level) for frame, text, level in lines if "no pose" in text] == [(second.frame.index, "WARN")]


def test_error_plots_leave_a_gap_and_mark_a_frame_without_a_pose(tmp_path, run):
    """A Clear is a hole in rerun's time series: no line bridges the failed frame to the next success."""
    map, frames = run
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    for i, f in enumerate(frames[:3]):
        result = (dataclasses.replace(f.result, hypotheses=[], failure=Failure(kind=FailureKind.FEW_MATCHED, count=2))
                  if i == 1 else f.result)
        evaluation = evaluate_frame(result, f.observations, map, f.frame.pose, LocalizationConfig(), i)
        recorder.log_frame(f.frame, f.detections, f.observations, result, evaluation)
    recorder.close()
    indices = [f.frame.index for f in frames[:3]]
    for path in ("metrics/error/translation_m", "metrics/error/rotation_deg"):
        assert sorted(spy.series(path)) == [indices[0], indices[2]]
        assert spy.series(path, "Clear:is_recursive") == {indices[1]: False}
    assert spy.series("metrics/error/no_pose") == {indices[1]: 0.0}
    assert not any(path.startswith("metrics") for path, _ in spy.calls)  # sent as columns only
    assert (tmp_path / "r.rrd").stat().st_size > 0


def test_metrics_are_sent_at_close_one_value_per_frame(tmp_path, run):
    """The per-frame scalars reach the recording as one column per series when it closes, each frame's own
    values at its own frame (and on the TUM timeline `time` at its stamp)."""
    map, frames = run
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    for f in frames:
        recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
    recorder.flush()
    assert spy.sent == []  # nothing before close
    recorder.close()
    indices = [f.frame.index for f in frames]
    assert len(set(indices)) == len(frames) > 3
    assert spy.series("metrics/count/observations") == {i: len(f.observations) for i, f in zip(indices, frames)}
    assert spy.series("metrics/count/candidates") == {i: len(f.result.candidates) for i, f in zip(indices, frames)}
    assert spy.series("metrics/error/translation_m") == pytest.approx(
        {i: f.evaluation.translation_error for i, f in zip(indices, frames)})
    assert spy.series("metrics/time/matching") == pytest.approx(
        {i: f.result.timings["matching"] for i, f in zip(indices, frames)})
    (timelines,) = [t for path, t, _ in spy.sent if path == "metrics/count/cliques"]
    assert timelines["frame"] == indices
    np.testing.assert_allclose(np.array(timelines["time"]) / 1e9, [f.frame.timestamp for f in frames], atol=1e-6)


def test_a_run_that_fails_leaves_no_recording(tmp_path, run):
    map, frames = run
    path = tmp_path / "broken.rrd"
    with pytest.raises(RuntimeError), LocalizationRecorder(path, map, "x") as recorder:
        f = frames[0]
        recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
        raise RuntimeError("the run died")
    assert list(tmp_path.iterdir()) == []


def test_a_recording_whose_layout_fails_leaves_nothing(tmp_path):
    from clipclique.viz.recording import RecordingFile

    def broken_blueprint():
        raise ValueError("no layout")

    with pytest.raises(ValueError), RecordingFile(tmp_path / "r.rrd", "test", broken_blueprint):
        pass
    assert list(tmp_path.iterdir()) == []


def test_rotation_error_is_logged_in_degrees(tmp_path, run):
    map, frames = run
    f = frames[2]
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    evaluation = dataclasses.replace(f.evaluation, rotation_error=math.pi / 2)
    recorder.log_frame(f.frame, f.detections, f.observations, f.result, evaluation)
    recorder.close()
    assert spy.series("metrics/error/rotation_deg") == {f.frame.index: pytest.approx(90.0)}


def test_a_frame_without_ground_truth_is_placed_by_the_estimate(tmp_path, run):
    map, frames = run
    f = frames[0]
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    recorder.log_frame(dataclasses.replace(f.frame, pose=None), f.detections, f.observations, f.result, None)
    transform = spy.last("world/camera/gt")[0]
    assert len(transform.translation.as_arrow_array()) == 0  # cleared, not left at the last pose
    assert len(transform.mat3x3.as_arrow_array()) == 0
    recorder.close()
    ((frame, centers),) = spy.rows("world/observations/estimate", "Ellipsoids3D:centers")
    expected = f.result.hypotheses[0].pose.apply(f.observations.ellipsoids.centers)
    assert frame == f.frame.index
    np.testing.assert_allclose(np.array(centers), expected, atol=1e-5)
    assert spy.series("world/observations/gt", "Clear:is_recursive") == {f.frame.index: False}
    assert spy.rows("world/trajectory/gt", "LineStrips3D:strips") == []


def test_archetype_rows_come_back_as_what_logging_each_row_would_log():
    """`ArchetypeRows` columns hold, row by row, the batches `stream.log(path, archetype(**row))` logs at that frame:
    every component of each row (an empty row's too), one value a row for the splat fields, a field a row leaves out
    not at all, and a timestamp only on the rows that had one."""
    sent = {}

    class Stream:
        def send_columns(self, path, indexes, columns):
            times = {index.timeline_name(): index.as_arrow_array().to_pylist() for index in indexes}
            for column in columns:
                sent[path, str(column.component_descriptor()), "time" in times] = (times["frame"],
                                                                                   column.as_arrow_array().to_pylist())

    strips = ArchetypeRows(rr.LineStrips3D, ("strips", "colors", "labels"))
    rows = [(3, None, {"strips": np.arange(12.0).reshape(2, 2, 3),
                       "colors": np.array([[255, 0, 0], [0, 9, 0]], np.uint8),
                       "labels": ["a", "b"], "radii": -1.5}),
            (4, None, {"strips": np.zeros((0, 2, 3)), "colors": np.zeros((0, 3), np.uint8), "labels": [],
                       "radii": -2.5}),
            (7, 1.5e9, {"strips": np.ones((1, 2, 3)), "colors": np.array([[1, 2, 3]], np.uint8), "labels": ["c"],
                        "radii": -1.0})]
    values = ArchetypeRows(rr.AnyValues)
    late = ColumnsAtClose()
    for frame, stamp, row in rows:
        late.add("p", frame, stamp, row, strips)
        late.add("p", frame, stamp, {"score": float(frame) / 4, "size": frame}, values)
    late.add("q", 5, None, {"strips": [np.zeros((3, 3))], "radii": -2.0},
             ArchetypeRows(rr.LineStrips3D, ("strips", "colors")))
    late.send(Stream())
    for frame, stamp, row in rows:
        for batch in [*rr.LineStrips3D(**row).as_component_batches(),
                      *rr.AnyValues(score=float(frame) / 4, size=frame).as_component_batches()]:
            frames, logged = sent["p", str(batch.component_descriptor()), stamp is not None]
            assert (logged[frames.index(frame)] == batch.as_arrow_array().to_pylist()), (frame,
                                                                                         batch.component_descriptor())
    assert sent["p", "LineStrips3D:radii", False] == ([3, 4], [[-1.5], [-2.5]])
    assert sent["p", "score", True] == ([7], [[1.75]]) and sent["p", "size", False] == ([3, 4], [[3], [4]])
    assert sent["p", "LineStrips3D:strips", False][1][1] == []  # the empty row is there, empty
    assert len(sent) == 14  # p: strips, colours, labels, radii, score, size with and without a stamp
    assert {descriptor for path, descriptor, _ in sent if path == "q"} == {"LineStrips3D:strips", "LineStrips3D:radii"}
    assert sent["q", "LineStrips3D:strips", False] == ([5], [[np.zeros((3, 3)).tolist()]])


def test_cameras_kept_until_close_are_what_logging_them_live_logs():
    """An estimated camera sent at close (Transform3D and Pinhole in one call) holds, row by row, the batches the
    live `camera` logs; and the placed observations' quaternions, converted once for all rows, are each row's own."""
    from scipy.spatial.transform import Rotation

    from clipclique.types import Pose
    from clipclique.viz.convert import camera, camera_columns, camera_row, ellipsoid_fields
    from clipclique.viz.localization_recording import ELLIPSOIDS

    rng = np.random.default_rng(3)
    intrinsics = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    poses = [Pose(Rotation.random(random_state=k).as_matrix(), rng.normal(size=3)) for k in range(3)]
    colors = [np.array([255, 200, 0, alpha]) for alpha in (255, 110, 110)]
    columns = camera_columns([camera_row(pose, intrinsics, 640, 480, color, 0.25)
                              for pose, color in zip(poses, colors)])
    sent = {str(column.component_descriptor()): column.as_arrow_array().to_pylist() for column in columns}
    for k, (pose, color) in enumerate(zip(poses, colors)):
        for archetype in camera(pose, intrinsics, 640, 480, color, 0.25):
            for batch in archetype.as_component_batches():
                assert sent[str(batch.component_descriptor())][k] == batch.as_arrow_array().to_pylist()
    assert ({"Transform3D:translation", "Transform3D:mat3x3", "Pinhole:image_from_camera", "Pinhole:resolution"}
            <= set(sent))

    rows = [ellipsoid_fields(Ellipsoids(rng.normal(size=(n, 3)), rng.uniform(0.1, 1, (n, 3)),
                                        Rotation.random(n, random_state=n).as_matrix().reshape(n, 3, 3)),
                             np.arange(n), [f"o{i}" for i in range(n)], np.full((n, 3), 200, np.uint8),
                             "MajorWireframe",
                             False) for n in (4, 1, 3)]
    sent = {str(column.component_descriptor()): column.as_arrow_array().to_pylist()
            for column in ELLIPSOIDS([dict(row) for row in rows])}
    for k, row in enumerate(rows):
        quaternions = Rotation.from_matrix(row["rotations"]).as_quat()
        live = rr.Ellipsoids3D(**{name: value for name, value in row.items() if name != "rotations"},
                               quaternions=quaternions)
        for batch in live.as_component_batches():
            assert sent[str(batch.component_descriptor())][k] == batch.as_arrow_array().to_pylist()


def test_images_sent_a_few_frames_at_a_time_hold_what_logging_each_frame_would():
    """The rgb, depth and mask images go as columns every few frames (`send(full=N)`): each row holds the batches
    `rr.EncodedImage`, `rr.DepthImage` and `rr.SegmentationImage` make of that frame's image, and nothing waits
    past N frames but the rest at close."""
    from clipclique.viz.convert import depth_fields, image_fields, rgb_fields
    from clipclique.viz.localization_recording import DEPTH_IMAGES, ENCODED_IMAGES, SEGMENTATION_IMAGES

    rng = np.random.default_rng(5)
    frames = [(rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), rng.uniform(0, 9, (24, 32)).astype(np.float32),
               rng.integers(0, 300 if k == 1 else 5, (24, 32)).astype(np.uint16 if k == 1 else np.uint8))
              for k in range(3)]
    frames[0][1][3, 4] = np.nan
    sent = []

    class Stream:
        def send_columns(self, path, indexes, columns):
            (frame_index,) = indexes
            sent.append((path, frame_index.as_arrow_array().to_pylist(),
                         {str(c.component_descriptor()): c.as_arrow_array().to_pylist() for c in columns}))

    images = ColumnsAtClose()
    for k, (rgb, depth, mask) in enumerate(frames):
        images.add("rgb", k, None, rgb_fields(rgb), ENCODED_IMAGES)
        images.add("depth", k, None, depth_fields(depth), DEPTH_IMAGES)
        images.add("masks", k, None, image_fields(mask) | {"opacity": 0.45, "draw_order": 1.0}, SEGMENTATION_IMAGES)
        images.send(Stream(), full=2)
        assert [frames_sent for _, frames_sent, _ in sent] == ([] if k == 0 else [[0, 1]] * 3)
    images.send(Stream())
    assert [(path, frames_sent) for path, frames_sent, _ in sent[3:]] == [("rgb", [2]), ("depth", [2]), ("masks", [2])]
    for path, frames_sent, columns in sent:
        for row, k in enumerate(frames_sent):
            rgb, depth, mask = frames[k]
            live = {"rgb": rr.EncodedImage(contents=encode_jpeg(rgb), media_type="image/jpeg"),
                    "depth": rr.DepthImage(depth_units(depth), meter=100),
                    "masks": rr.SegmentationImage(mask, opacity=0.45, draw_order=1.0)}[path]
            batches = live.as_component_batches()
            assert {str(batch.component_descriptor()) for batch in batches} == set(columns)
            for batch in batches:
                assert columns[str(batch.component_descriptor())][row] == batch.as_arrow_array().to_pylist(), (path, k)


def test_trajectories_so_far_are_sent_at_close_one_row_a_frame(tmp_path, run):
    """At each frame the viewer shows the ground-truth path and the top-1 positions up to that frame (sent as
    columns at close, as they were once logged frame by frame)."""
    map, frames = run
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    for f in frames[:3]:
        recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
    assert spy.sent == []  # nothing before close
    recorder.close()
    indices = [f.frame.index for f in frames[:3]]
    paths = spy.rows("world/trajectory/gt", "LineStrips3D:strips")
    assert [frame for frame, _ in paths] == indices
    for k, (_, (strip,)) in enumerate(paths):
        np.testing.assert_allclose(strip, [f.frame.pose.translation for f in frames[:k + 1]], atol=1e-6)
    points = spy.rows("world/trajectory/estimate", "Points3D:positions")
    assert [frame for frame, _ in points] == indices
    np.testing.assert_allclose(points[-1][1], [f.result.hypotheses[0].pose.translation for f in frames[:3]], atol=1e-6)
    colors = [color for _, color in spy.rows("world/trajectory/estimate", "Points3D:colors")]
    assert [len(c) for c in colors] == [1, 2, 3] and colors[1] == colors[2][:2]  # a point keeps its colour
    assert spy.series("world/trajectory/estimate", "Points3D:radii") == {i: pytest.approx(-4.0) for i in indices}


def test_projected_landmarks_are_outlined_with_their_overlap(tmp_path, run):
    """The map under each frame's top-1 pose is drawn as ellipse outlines, those supporting the pose
    labelled with the IoU of their box and the detection's; a correct pose overlaps its detections
    far better than a wrong one (frame 2: shuffled correspondences, 0.8 m off)."""
    from clipclique.verify.projection import box_iou

    map, frames = run
    recorder = LocalizationRecorder(tmp_path / "r.rrd", map, "x")
    spy = LogSpy(recorder)
    medians = []
    for f in (frames[0], frames[2]):
        recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
    recorder.close()
    path = "world/camera/gt/projected_landmarks"
    outlines = spy.rows(path, "LineStrips2D:strips")
    assert [frame for frame, _ in outlines] == [frames[0].frame.index, frames[2].frame.index]
    for f, (_, strips), (_, labels) in zip((frames[0], frames[2]), outlines, spy.rows(path, "LineStrips2D:labels")):
        strips = [np.asarray(s) for s in strips]
        pairs = f.result.hypotheses[0].correspondences
        supported = [i for i, label in enumerate(labels) if "IoU" in label]
        ious = np.array([float(labels[i].rsplit(" ", 1)[1]) for i in supported])
        if f is frames[0]:  # a correct pose sees every landmark it rests on
            assert len(supported) == len(pairs)
            outline_boxes = np.array([[*strips[i].min(axis=0), *strips[i].max(axis=0)] for i in supported])
            outline_boxes = np.clip(outline_boxes, 0, [f.frame.rgb.shape[1], f.frame.rgb.shape[0]] * 2)  # as boxes are
            np.testing.assert_allclose(ious, box_iou(outline_boxes, f.observations.boxes[pairs[:, 0]]), atol=0.02)
        ious = np.pad(ious, (0, len(pairs) - len(ious)))  # a landmark out of view overlaps nothing
        medians.append(np.median(ious))
    assert medians[0] > 0.35 and medians[1] < medians[0] - 0.2, medians


def test_crowded_detection_labels_show_on_hover_only():
    """Of boxes whose labels (under each box's centre) would overlap, the largest keeps its visible label; the boxes
    are the ones `rr.Boxes2D` makes of the xyxy corners."""
    from clipclique.types import Detections
    from clipclique.viz.convert import box_fields

    boxes = np.array([[100, 100, 300, 200], [150, 150, 250, 210], [400, 100, 460, 200], [100, 300, 200, 400.5]], float)
    detections = Detections(masks=np.zeros((4, 480, 640), bool), boxes=boxes, class_ids=np.array([0, 1, 2, 0]),
                            scores=np.full(4, 0.5), instance_ids=np.arange(4))
    labelled, crowded = box_fields(detections, ["chair", "cup", "tv"])
    assert labelled["labels"] == ["chair 0.50", "tv 0.50", "chair 0.50"] and labelled["show_labels"] is True
    assert crowded["labels"] == ["cup 0.50"] and crowded["show_labels"] is False  # 10 px from the chair's label
    np.testing.assert_array_equal(labelled["class_ids"], [1, 3, 1])
    for fields, keep in ((labelled, [0, 2, 3]), (crowded, [1])):
        expected = rr.Boxes2D(array=boxes[keep], array_format=rr.Box2DFormat.XYXY)
        for name in ("centers", "half_sizes"):
            assert rr.Boxes2D(**{name: fields[name]}).as_component_batches()[0].as_arrow_array().to_pylist() == \
                getattr(expected, name).as_arrow_array().to_pylist()
    assert all(len(fields) == 0 for fields in box_fields(Detections(np.zeros((0, 4, 5), bool), np.zeros((0, 4)),
                                                                    np.zeros(0, int), np.zeros(0), np.zeros(0, int)),
                                                         [])[0].values() if not isinstance(fields, bool))


def test_the_localization_layout_hides_the_semantic_graph(loc_rrd, recorded_entities):
    """A dense map's graph (the desk's: hundreds of edges) buries the matches: the 3D view opens without it."""
    overrides = {path: columns for path, (_, columns) in recorded_entities(loc_rrd).items() if "/overrides/" in path}
    assert [columns for path, columns in overrides.items() if "/overrides/world/map/graph" in path] == [
        {"EntityBehavior:visible"}]


def test_window_sources_and_odometry_path_are_placed_by_the_newest_pose(tmp_path, run):
    from clipclique.multiframe.window import WindowConfig, Windower
    from clipclique.viz.localization_recording import WINDOW_PATH, WINDOW_SOURCES

    map, frames = run
    windower = Windower(WindowConfig(size=2), [f.frame.pose for f in frames], map.class_names)
    query = windower.query(1, frames[1].observations, lambda i: frames[i].observations)
    newest = frames[1]
    with LocalizationRecorder(tmp_path / "window.rrd", map, "# window") as recorder:
        spy = LogSpy(recorder)
        recorder.log_frame(newest.frame, newest.detections, query.observations, newest.result, newest.evaluation)
        recorder.log_window(query, newest.frame.pose)
    ((frame, centers),) = spy.rows(WINDOW_SOURCES, "Ellipsoids3D:centers")
    count = len(frames[0].observations) + len(frames[1].observations)
    centers = np.array(centers, float)
    assert frame == newest.frame.index and len(centers) == count
    # every source observation lands in the world where its own frame's ground truth puts it
    expected = np.vstack([f.frame.pose.apply(f.observations.ellipsoids.centers) for f in frames[:2]])
    np.testing.assert_allclose(centers, expected, atol=1e-4)
    ((_, source_frames),) = spy.rows(WINDOW_SOURCES, "frame")
    assert source_frames == [0] * len(frames[0].observations) + [1] * len(frames[1].observations)
    ((_, (path,)),) = spy.rows(WINDOW_PATH, "LineStrips3D:strips")
    np.testing.assert_allclose(path, [f.frame.pose.translation for f in frames[:2]], atol=1e-4)


def test_a_frame_that_fails_to_log_fails_the_run_and_leaves_no_recording(tmp_path, run):
    """Frames are logged on the recorder's own thread; an error there reaches the caller, and the
    half-written recording is dropped."""
    map, frames = run
    path = tmp_path / "r.rrd"
    recorder = LocalizationRecorder(path, map, "x")
    f = frames[0]
    recorder.log_frame(f.frame, f.detections, None, f.result, f.evaluation)  # no observations: the thread fails
    with pytest.raises(AttributeError):
        recorder.flush()
    with pytest.raises(AttributeError):
        recorder.close()
    assert not path.exists() and not list(tmp_path.iterdir())


def test_a_run_that_fails_drops_the_frames_still_queued(tmp_path, run):
    map, frames = run
    path = tmp_path / "r.rrd"
    with pytest.raises(RuntimeError), LocalizationRecorder(path, map, "x") as recorder:
        for f in frames:
            recorder.log_frame(f.frame, f.detections, f.observations, f.result, f.evaluation)
        raise RuntimeError("the run failed")
    assert not list(tmp_path.iterdir())


def test_the_alignment_layout_hides_the_semantic_graph_the_map_layout_shows_it(tmp_path, recorded_entities):
    """Two maps' graphs bury the correspondences, as a map's buries a localization recording's matches."""
    from clipclique.config import make_config
    from clipclique.pipeline import align_maps
    from clipclique.sim.synthetic import synthetic_map
    from clipclique.viz.align_recording import write_alignment_recording

    map = synthetic_map(np.random.default_rng(3), 20)
    write_alignment_recording(tmp_path / "align.rrd", map.subset(np.arange(12)), map,
                              align_maps(map.subset(np.arange(12)), map, make_config("clipclique")), "# aligned")
    write_map_recording(tmp_path / "map.rrd", map, None, None, description="# map")
    hidden = {name: [columns for path, (_, columns) in recorded_entities(tmp_path / name).items()
                     if "/overrides/world/map/graph" in path] for name in ("align.rrd", "map.rrd")}
    assert hidden == {"align.rrd": [{"EntityBehavior:visible"}], "map.rrd": []}
