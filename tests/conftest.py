"""Shared test options and fixtures: generated demo scenes, a tiny ScanNet scene and a tiny TUM sequence in
the official formats, and a small synthetic room with hand-made localization results for the recording tests.

Tests are grouped by layer: unit/ (fast library tests, `make test-fast`), integration/ (readers
and tools on generated scenes), e2e/ (full runs, the benchmark, the README), fuzz/ (hostile inputs).
Fixtures that hand out helpers return the function, so no test module imports another.
"""

from __future__ import annotations

from clipclique.blas import one_blas_thread_by_default

one_blas_thread_by_default()  # as the CLIs run (a speed setting; where a plugin loaded numpy first it does nothing)

import dataclasses  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from PIL import Image  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from clipclique.config import LocalizationConfig  # noqa: E402
from clipclique.metrics import FrameEvaluation, evaluate_frame  # noqa: E402
from clipclique.pipeline import LocalizationResult  # noqa: E402
from clipclique.sim.poses import look_at  # noqa: E402
from clipclique.types import Camera, Detections, Ellipsoids, Frame, Hypothesis, Map, Observations, Pose  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]  # the repository
SMALL_SIZE = (160, 120)  # width, height of the small demo scenes most tests read


def pytest_addoption(parser) -> None:
    parser.addoption("--force-regen", action="store_true", default=False,
                     help="rewrite tests/golden/ from this tree's results and print what moved "
                          "(tests/e2e/test_golden.py)")


def pytest_sessionstart(session) -> None:
    """numba's stale cache files dropped (`drop_stale_kernels`); before a parallel run's workers start, its kernels
    compiled into its cache and, for the whole suite, the golden results' full-size scenes generated, side by side
    (tests/warm_up.py; seconds once they exist)."""
    config = session.config
    if hasattr(config, "workerinput"):
        return  # a worker: the controller did it
    from tests.warm_up import drop_stale_kernels

    drop_stale_kernels()
    if not getattr(config.option, "numprocesses", None):
        return  # a run without workers: each test compiles and generates what it needs
    whole_suite = not config.args or [Path(arg).resolve() for arg in config.args] == [ROOT / "tests"]
    jobs = ["kernels", "scenes"] if whole_suite else ["kernels"]
    started = [subprocess.Popen([sys.executable, str(ROOT / "tests" / "warm_up.py"), job]) for job in jobs]
    failed = [job for job, process in zip(jobs, started) if process.wait() != 0]
    if failed:
        pytest.exit(f"tests/warm_up.py {' and '.join(failed)} failed (its error is above)", returncode=1)


# `make test` runs with `--dist loadscope`: a module's tests share its fixtures, so they go to one worker
# together, except where a scope of their own lets costly independent tests spread over the workers: each
# golden scene's runs (they share that scene's map), the docs' printed-examples check (its own scratch root) and
# the docs pages whose blocks make all they use (tests/e2e/test_readme.py's SELF_CONTAINED).
OWN_SCOPES = {
    "tests/e2e/test_golden.py::test_the_same_inputs_give_the_same_bytes": "golden demo_desk",
    "tests/e2e/test_readme.py::test_printed_examples_are_current": "printed examples",
}
GOLDEN_RUN = re.compile(r"tests/e2e/test_golden\.py::test_results_hold_the_golden_ones\[(\w+)-\w+\]")


def scope_of(nodeid: str) -> str:
    """The work unit a test goes to a worker in (xdist's scheduler asks for every test)."""
    if golden := GOLDEN_RUN.fullmatch(nodeid):
        return f"golden {golden[1]}"
    if nodeid.startswith("tests/e2e/test_readme.py::test_self_contained_page_block_runs["):
        return "self-contained docs pages"
    return OWN_SCOPES.get(nodeid, nodeid.split("::")[0])


def pytest_xdist_make_scheduler(config, log):
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ByScope(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return scope_of(nodeid)

    return ByScope(config, log)


@pytest.fixture(scope="session")
def repository() -> Path:
    """The repository root (tools/, docs/, data/)."""
    return ROOT


# ---- generated demo scenes -----------------------------------------------------------------------

DemoData = Callable[..., Path]


@pytest.fixture(scope="session")
def demo_data(tmp_path_factory) -> DemoData:
    """`demo_data("demo", "demo_tum", frames=4, size=(160, 120))`: a data root holding demo/<name> for
    each scene, generated once per session (the same walk, fewer frames; frames or size None: the
    scene's own). Shared: read it, copy a scene to change it."""
    from clipclique.sim.demo import DEMO_SCENES, generate

    base = tmp_path_factory.mktemp("demo-data")

    def make(*names: str, frames: int | None = 4, size: tuple[int, int] | None = SMALL_SIZE) -> Path:
        root = base / f"{frames or 'all'}-frames-{'x'.join(map(str, size)) if size else 'full-size'}"
        for name in names:
            folder = root / "demo" / name
            if folder.is_dir():
                continue
            folder.mkdir(parents=True)
            changes = (({"num_frames": frames} if frames else {})
                       | ({"width": size[0], "height": size[1]} if size else {}))
            generate(folder, name, dataclasses.replace(DEMO_SCENES[name], **changes))
        return root

    return make


FullSizeMaps = Callable[[str], Path]


@pytest.fixture(scope="session")
def full_size_maps(tmp_path_factory) -> FullSizeMaps:
    """`full_size_maps("demo_desk")`: the map of a whole generated scene under the repository's data/ (generated
    there on first use, as `make demo` does), built with the simulated encoder once per session."""
    from clipclique.backends import load_encoder
    from clipclique.io.mapfile import save_map
    from clipclique.mapping.build import build_map
    from clipclique.resolve import open_scene

    folder = tmp_path_factory.mktemp("full-size-maps")
    built: dict[str, Path] = {}

    def make(scene: str) -> Path:
        if scene not in built:
            map, _ = build_map(open_scene(scene, ROOT / "data"), load_encoder("simulated"))
            built[scene] = folder / f"{scene}.map.npz"
            save_map(map, built[scene])
        return built[scene]

    return make


# ---- a tiny ScanNet scene ------------------------------------------------------------------------

SCANNET_SCENE = "scene0007_00"
TSV_HEADER = "id\traw_category\tcategory\tcount\tnyu40id\teigen13id\tnyuClass\tnyu40class\teigen13class"
TSV_ROWS = ["2\tchair\tchair\t4646\t5\t4\tchair\tchair\tChair",
            "10\toffice chair\toffice chair\t1113\t5\t4\tchair\tchair\tChair",
            "1\twall\twall\t8277\t1\t12\twall\twall\tWall"]


def write_scannet_scene(root: Path, tsv: bool = False, descriptions: bool = True) -> tuple[Path, dict[str, np.ndarray]]:
    """Scene scene0007_00 under root/scannet/scans: an office chair (objectId 0), a plain chair (1) and a
    wall (2), plus 3 exported frames; its folder and each object's points."""
    from plyfile import PlyData, PlyElement

    folder = root / "scannet" / "scans" / SCANNET_SCENE
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    parts = {
        "office chair": rng.uniform([0, 0, 0], [0.5, 0.5, 1.0], (200, 3)),
        "chair": rng.uniform([2, 0, 0], [2.5, 0.5, 0.9], (150, 3)),
        "wall": rng.uniform([0, 3, 0], [4, 3.05, 2.5], (300, 3)),
    }
    xyz = np.concatenate(list(parts.values()))
    vertex = np.zeros(len(xyz), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"),
                                       ("blue", "u1"), ("alpha", "u1"), ("label", "u2")])
    vertex["x"], vertex["y"], vertex["z"] = xyz.T
    vertex["red"] = 200
    vertex["label"] = np.repeat([10, 2, 1], [200, 150, 300])
    face = np.zeros(2, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[0, 1, 2], [3, 4, 5]]
    PlyData([PlyElement.describe(vertex, "vertex"),
             PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"})]).write(
        str(folder / f"{SCANNET_SCENE}_vh_clean_2.labels.ply"))
    # Segment ids as ScanNet's over-segmentation writes them: arbitrary integers, several per object,
    # one segment (9) in no group.
    segments = np.concatenate([np.repeat([1001, 17], 100), np.repeat([512, 9], [140, 10]), np.full(300, 3)])
    (folder / f"{SCANNET_SCENE}_vh_clean_2.0.010000.segs.json").write_text(
        json.dumps({"sceneId": SCANNET_SCENE, "segIndices": segments.tolist()}))
    groups = [
        {"id": 0, "objectId": 0, "segments": [1001, 17], "label": "office chair"},
        {"id": 1, "objectId": 1, "segments": [512], "label": "chair"},
        {"id": 2, "objectId": 2, "segments": [3], "label": "wall"},
    ]
    (folder / f"{SCANNET_SCENE}.aggregation.json").write_text(json.dumps({"sceneId": f"scannet.{SCANNET_SCENE}",
                                                                          "appId": "Aggregator.v2",
                                                                          "segGroups": groups}))
    if tsv:
        (root / "scannet" / "scannetv2-labels.combined.tsv").write_text("\n".join([TSV_HEADER, *TSV_ROWS]) + "\n")
    if descriptions:
        (folder / f"{SCANNET_SCENE}_descriptions.json").write_text(json.dumps({"0": "a purple office chair"}))
    for sub in ("color", "depth", "pose", "intrinsic", "instance-filt"):
        (folder / sub).mkdir()
    intrinsics = np.array([[577.0, 0, 319.5, 0], [0, 577.0, 239.5, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    np.savetxt(folder / "intrinsic" / "intrinsic_depth.txt", intrinsics)
    for n in range(3):
        pose = np.eye(4)
        pose[:3, 3] = [n, 0.5, 1.2]
        if n == 1:
            pose[:] = -np.inf  # SensReader writes -inf where tracking was lost
        np.savetxt(folder / "pose" / f"{n}.txt", pose)
        Image.fromarray(np.full((968, 1296, 3), 40 * n, np.uint8)).save(folder / "color" / f"{n}.jpg")
        Image.fromarray(np.full((480, 640), 1500 + n, np.uint16)).save(folder / "depth" / f"{n}.png")
        instance = np.zeros((480, 640), np.uint8)
        instance[100:200, 100:300] = 1  # objectId 0 + 1
        Image.fromarray(instance).save(folder / "instance-filt" / f"{n}.png")
    return folder, parts


TUM_NAME = "rgbd_dataset_freiburg2_desk"
TUM_T0 = 1311868164.0


def write_tum_sequence(root: Path, annotations: bool = True, rounded: bool = False) -> Path:
    """A tiny TUM sequence in the official formats: four colour frames 0.1 s apart (the third has no depth image
    within 20 ms), a 100 Hz trajectory, two objects annotated in the first frame. `rounded`: the patch of depth
    they cover is a dome 10 cm deep instead of flat, so that each object fits an ellipsoid (a map builds)."""
    folder = root / "tum" / TUM_NAME
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    rgb_times = TUM_T0 + np.array([0.0, 0.1, 0.2, 0.3]) + 0.0013
    depth_times = TUM_T0 + np.array([0.008, 0.111, 0.245, 0.289])  # 0.2 s frame: nearest depth 45 ms away
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps", "# timestamp filename"]
    for t in rgb_times:
        Image.fromarray(np.full((480, 640, 3), 90, np.uint8)).save(folder / "rgb" / f"{t:.6f}.png")
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
    for t in depth_times:
        depth = np.zeros((480, 640), np.uint16)
        depth[200:280, 300:380] = 10000  # 2 m at factor 5000
        if rounded:
            rows, cols = np.mgrid[200:280, 300:380]
            depth[200:280, 300:380] -= (500 * np.sqrt(np.clip(1 - ((rows - 240) / 40) ** 2 - ((cols - 340) / 40) ** 2,
                                                              0, 1))).astype(np.uint16)
        Image.fromarray(depth).save(folder / "depth" / f"{t:.6f}.png")
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
    (folder / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (folder / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    gt = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for k, t in enumerate(TUM_T0 - 0.05 + np.arange(0, 0.5, 0.01)):  # 100 Hz, own phase
        q = Rotation.from_euler("z", 0.01 * k).as_quat()
        gt.append(f"{t:.4f} {1 + 0.01 * k:.4f} 2.0000 3.0000 " + " ".join(f"{v:.6f}" for v in q))
    (folder / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    if annotations:
        (folder / "annotations" / "instances").mkdir(parents=True)
        (folder / "annotations" / "objects.csv").write_text('id,class,description\n4,monitor,"a black monitor, '
                                                            'wide"\n9,cup,\n')
        ids = np.zeros((480, 640), np.uint16)
        ids[200:280, 300:340] = 4
        ids[200:280, 340:380] = 9
        Image.fromarray(ids).save(folder / "annotations" / "instances" / f"{rgb_times[0]:.6f}.png")
    return folder


@pytest.fixture(scope="session")
def tum_sequence() -> Callable[..., Path]:
    """write_tum_sequence (its folder is tum/TUM_NAME; colour images at TUM_T0 + 0.0013, + 0.1013, ...)."""
    return write_tum_sequence


@pytest.fixture(scope="session")
def bag_tools():
    """tools/tum_to_bag.py as a module: `write_bag(folder, out, storage, layout)` writes a TUM folder as a ROS bag,
    and its message makers (`typestore`, `image`, `camera_info`, ...) build hostile ones."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("tum_to_bag", ROOT / "tools" / "tum_to_bag.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def scannet_scene() -> Callable[..., tuple[Path, dict[str, np.ndarray]]]:
    """`scannet_scene(root, tsv=False, descriptions=True)` writes the tiny ScanNet scene (write_scannet_scene)."""
    return write_scannet_scene


# ---- a synthetic room for the recording tests ----------------------------------------------------

ROOM_CLASSES = ["chair", "table", "sofa", "tv", "plant", "lamp"]
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


def room_map() -> Map:
    names = [name for name, _, _ in LAYOUT]
    centers = np.array([(x, y, HALF_SIZES[name][2]) for name, x, y in LAYOUT])
    yaw = np.linspace(0.0, np.pi, len(LAYOUT))
    c, s = np.cos(yaw), np.sin(yaw)
    rotations = np.zeros((len(LAYOUT), 3, 3))
    rotations[:, 0, 0], rotations[:, 0, 1], rotations[:, 1, 0], rotations[:, 1, 1] = c, -s, s, c
    rotations[:, 2, 2] = 1.0
    return Map(
        ellipsoids=Ellipsoids(centers, np.array([HALF_SIZES[n] for n in names]), rotations),
        class_ids=np.array([ROOM_CLASSES.index(n) for n in names]),
        class_names=list(ROOM_CLASSES),
        descriptions=[f"a {['grey', 'wooden', 'blue', 'black', 'green'][i % 5]} {n}" for i, n in enumerate(names)],
        instance_ids=np.arange(1, len(LAYOUT) + 1),
        encoder="simulated-clip",
    )


def room_points(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Floor and two walls as a dense point cloud with colours (more points than a recording keeps)."""
    rng = np.random.default_rng(seed)
    floor = np.column_stack((rng.uniform(-3.5, 3.5, 60_000), rng.uniform(-3, 3, 60_000), np.zeros(60_000)))
    wall = np.column_stack((rng.uniform(-3.5, 3.5, 30_000), np.full(30_000, 3.0), rng.uniform(0, 2.5, 30_000)))
    points = np.vstack((floor, wall))
    colors = np.where(points[:, 2:3] > 0, [180, 170, 150], [110, 90, 70]).astype(np.uint8)
    return points, colors


def _render(map: Map, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def room_run(num_frames: int = 6, top_n: int = 3, seed: int = 0) -> tuple[Map, list[FrameRun]]:
    """A camera circling the room; every third frame (2, 5, ...) localizes wrongly (its top-1 is a wrong clique)."""
    rng = np.random.default_rng(seed)
    map = room_map()
    runs = []
    for index in range(num_frames):
        angle = 2 * np.pi * index / max(num_frames, 1)
        gt = look_at(np.array([3.2 * np.cos(angle), 3.2 * np.sin(angle), 1.6]), np.array([0.0, 0.0, 0.4]))
        rgb, depth, instances = _render(map, gt)
        frame = Frame(index, 1_305_031_102.0 + index / 30, rgb, depth, INTRINSICS, gt, instances, f"{index:06d}")
        runs.append(_localize(map, frame, top_n, wrong=index % 3 == 2, rng=rng))
    return map, runs


def _localize(map: Map, frame: Frame, top_n: int, wrong: bool, rng: np.random.Generator) -> FrameRun:
    seen = [i for i, inst in enumerate(map.instance_ids) if (frame.instances == inst).sum() > 50]
    masks = np.stack([frame.instances == map.instance_ids[i] for i in seen] + [np.zeros_like(frame.depth, bool)])
    masks[-1, 10:40, 10:60] = True  # a false detection
    boxes = np.array([_box(mask) for mask in masks], dtype=float)
    class_ids = np.append(map.class_ids[seen], ROOM_CLASSES.index("plant"))
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


@pytest.fixture(scope="session")
def synthetic_run() -> Callable[..., tuple[Map, list[FrameRun]]]:
    """`synthetic_run(num_frames=6, top_n=3, seed=0)`: the recording room's map and one FrameRun per frame
    (the real result types, hand-made values so tests know which matches are right)."""
    return room_run


@pytest.fixture(scope="session")
def scene_points() -> Callable[..., tuple[np.ndarray, np.ndarray]]:
    """`scene_points(seed=0)`: the recording room's floor and walls, points and colours."""
    return room_points


def run_rerun_cli(*args: str) -> subprocess.CompletedProcess:
    from clipclique.viz.screenshot import viewer_binary

    return subprocess.run([str(viewer_binary()), *args], capture_output=True, text=True, timeout=120)


def read_entities(path: Path) -> dict[str, tuple[int, set[str]]]:
    """Entity path -> (rows logged, data columns) of a recording, read back with `rerun rrd print`; the rows are
    those of its column with the most (a recording may send an entity's components in chunks of their own)."""
    printed = run_rerun_cli("rrd", "print", str(path))
    assert printed.returncode == 0, printed.stderr
    counts: dict[str, dict[str, int]] = {}  # entity -> column -> rows
    for rows, entity, columns in re.findall(r"with (\d+) rows .*? - (\S+) - data columns: \[(.*)\]", printed.stdout):
        for column in columns.split():
            counts.setdefault(entity, {})[column] = counts.get(entity, {}).get(column, 0) + int(rows)
    return {entity: (max(columns.values()), set(columns)) for entity, columns in counts.items()}


@pytest.fixture(scope="session")
def rerun_cli() -> Callable[..., subprocess.CompletedProcess]:
    """`rerun_cli("rrd", "verify", PATH)`: the rerun binary of this installation, run to completion."""
    return run_rerun_cli


@pytest.fixture(scope="session")
def recorded_entities() -> Callable[[Path], dict[str, tuple[int, set[str]]]]:
    """`recorded_entities(path)`: entity path -> (rows logged, data columns) of a recording."""
    return read_entities
