"""clipclique-bench's engine (clipclique.benchmark.engine) on two small demo scenes: the same results as
`clipclique-loc run` in this process and on a local Dask cluster of two worker processes (also when
one is killed mid-run), resuming with only the remaining work, and a failing task retried once and
then reported, never dropped silently."""

from __future__ import annotations

import os
import shutil
import signal
from collections import OrderedDict
from pathlib import Path

import pytest

from clipclique.benchmark import aggregate, engine, perception
from clipclique.benchmark.engine import TaskFailure, run_jobs
from clipclique.benchmark.plan import Plan, runs
from clipclique.localization.results import read_results
from clipclique.localization.run import RunSettings, prepare, run_and_save
from clipclique.pipeline import localize

pytestmark = pytest.mark.slow
SCENES = ["demo", "demo_tum"]
METHODS = ["clipclique", "sh"]
FRAMES = 6


class Recorder:
    """A Tracker that keeps what it was told (and may act on an update)."""

    def __init__(self, on_update=None) -> None:
        self.total, self.failures, self.updates, self.on_update = None, [], [], on_update

    def start(self, total: int) -> None:
        self.total = total

    def update(self, done: int, running: int, failed: int) -> None:
        self.updates.append((done, running, failed))
        if self.on_update is not None:
            self.on_update(done)

    def failed(self, failure: TaskFailure) -> None:
        self.failures.append(failure)


@pytest.fixture(scope="module")
def workspace(demo_data, tmp_path_factory):
    """A working folder (maps are built into its outputs/maps) and a data root of the two scenes."""
    data = demo_data(*SCENES, frames=FRAMES)
    folder = tmp_path_factory.mktemp("bench")
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        patch.setattr(engine, "CHUNK_FRAMES", 2)  # several tasks per run, as on a real sequence
        yield folder, data


def plan_runs(workspace, out: str) -> list[RunSettings]:
    folder, data = workspace
    return runs(Plan(SCENES, METHODS), folder / out, data, record=False)


def canonical(path: Path) -> list:
    """Every frame's decisions and scores (timings left out), as the results digest test compares them."""
    frames = read_results(path)["frames"]
    keep = ("index", "detections", "observations", "candidates", "num_cliques", "failure", "hypotheses")
    return [{key: frame[key] for key in keep} | {"evaluation": {k: v for k, v in frame["evaluation"].items()}}
            for frame in frames]


@pytest.fixture(scope="module")
def in_process(workspace):
    """The in-process run, and the settings `prepare` was called with (the runs kept emptied first)."""
    prepared = []

    def counted(settings):
        prepared.append(settings)
        return prepare(settings)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(engine, "_RUNS", OrderedDict())
        patch.setattr(engine, "prepare", counted)
        result = run_jobs(plan_runs(workspace, "in-process"), workspace[0] / "cache-a", Recorder())
    result.prepared = prepared
    return result


def folders(workspace, out: str) -> list[Path]:
    return sorted((workspace[0] / out).glob("*/*/results.json"))


def test_in_process_runs_are_those_of_clipclique_loc(workspace, in_process):
    folder, data = workspace
    assert len(in_process.documents) == 4 and not in_process.failed
    for settings in plan_runs(workspace, "in-process"):
        reference = folder / "loc" / settings.out.relative_to(folder / "in-process")
        run_and_save(RunSettings(settings.sequence, settings.method, data_root=data, out=reference, record=False))
        assert canonical(settings.out / "results.json") == canonical(reference / "results.json")
        assert (settings.out / "poses.tum").read_text() == (reference / "poses.tum").read_text()


def test_in_process_tasks_share_the_runs_the_plan_prepared(workspace, in_process):
    """Each run's sequence, map and models are loaded once, not again by its tasks (seconds for real models)."""
    assert sorted(s.out for s in in_process.prepared) == sorted(s.out for s in plan_runs(workspace, "in-process"))


def test_two_worker_processes_give_the_same_numbers(workspace, in_process):
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) \
            as cluster, Client(cluster) as client:
        assert all(address.startswith("tcp://127.0.0.1:") for address in client.nthreads())
        result = run_jobs(plan_runs(workspace, "cluster"), workspace[0] / "cache-b", Recorder(), client)
    assert len(result.documents) == 4 and not result.failed
    a, b = folders(workspace, "in-process"), folders(workspace, "cluster")
    assert ([p.relative_to(workspace[0] / "in-process") for p in a]
            == [p.relative_to(workspace[0] / "cluster") for p in b])
    for left, right in zip(a, b):
        assert canonical(left) == canonical(right)


def test_a_worker_killed_mid_run_has_its_tasks_redone(workspace, in_process):
    from distributed import Client, LocalCluster

    killed = []
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) \
            as cluster, Client(cluster) as client:
        pids = client.run(os.getpid)  # worker address -> its process

        def kill_one(done: int) -> None:
            if done >= 1 and not killed:
                killed.append(done)
                os.kill(pids[sorted(pids)[0]], signal.SIGKILL)

        tracker = Recorder(kill_one)
        result = run_jobs(plan_runs(workspace, "killed"), workspace[0] / "cache-c", tracker, client)
    assert killed and killed[0] < tracker.total  # it died with work left
    assert len(result.documents) == 4 and not result.failed
    for left, right in zip(folders(workspace, "in-process"), folders(workspace, "killed")):
        assert canonical(left) == canonical(right)


def test_resume_does_only_the_remaining_work(workspace, in_process):
    folder, _ = workspace
    shutil.copytree(folder / "in-process", folder / "resumed")
    shutil.copytree(folder / "cache-a", folder / "cache-r")
    shutil.rmtree(folder / "resumed" / "demo" / "sh")  # interrupted before these two runs were written
    shutil.rmtree(folder / "resumed" / "demo_tum" / "clipclique")
    tum_cache = next(p for p in (folder / "cache-r").glob("demo_tum-*")
                     if '"encoder": null' not in (p / "key.json").read_text())
    for index in (2, 3):  # ... and before two frames of demo_tum were perceived
        perception.frame_file(tum_cache, index).unlink()
    before = {p: p.stat().st_mtime_ns for p in folders(workspace, "resumed")}
    result = run_jobs(plan_runs(workspace, "resumed"), folder / "cache-r", Recorder())
    assert result.skipped == 2 and len(result.documents) == 4
    assert result.tasks == 1 + FRAMES // 2 * 2  # one perception chunk (frames 2-3), three localization chunks per run
    assert {p: p.stat().st_mtime_ns for p in before} == before  # finished runs untouched
    for left, right in zip(folders(workspace, "in-process"), folders(workspace, "resumed")):
        assert canonical(left) == canonical(right)


def test_a_failing_task_is_retried_once_then_reported(workspace, in_process, monkeypatch):
    calls = []

    def failing(run, index, observations, gt_pose, frame_index):
        calls.append((run.settings.method, frame_index))
        if run.settings.method == "sh" and run.sequence.name == "demo" and frame_index == 3:
            raise ValueError("the GPU fell over")
        return original(run, index, observations, gt_pose, frame_index)

    original = engine.localize_observed
    monkeypatch.setattr(engine, "localize_observed", failing)
    tracker = Recorder()
    result = run_jobs(plan_runs(workspace, "failing"), workspace[0] / "cache-a", tracker)
    assert calls.count(("sh", 3)) == 3  # two sh runs have a frame 3; the failing one is tried twice
    assert [f.reason for f in tracker.failures] == ["demo frame 3: ValueError: the GPU fell over"]
    assert tracker.failures[0].task.label() == "demo / sh, localize frames 2-3"
    assert result.failed == [{"sequence": "demo", "run": "sh",
                              "reasons": ["demo frame 3: ValueError: the GPU fell over"]}]
    assert len(result.documents) == 3 and not (workspace[0] / "failing" / "demo" / "sh").exists()
    aggregate.write(result, workspace[0] / "failing", "clipclique-bench demo demo_tum")
    assert ("demo / sh: demo frame 3: ValueError: the GPU fell over"
            in (workspace[0] / "failing" / "report.md").read_text())
    monkeypatch.setattr(engine, "localize_observed", original)
    again = run_jobs(plan_runs(workspace, "failing"), workspace[0] / "cache-a", Recorder())  # the rerun does the rest
    assert again.skipped == 3 and again.tasks == FRAMES // 2 and not again.failed


def test_a_transient_failure_is_retried_and_leaves_no_trace(workspace, in_process, monkeypatch):
    failed = []

    def flaky(observations, index, config):
        if not failed:
            failed.append(True)
            raise OSError("worker lost its disk for a moment")
        return localize(observations, index, config)

    monkeypatch.setattr("clipclique.localization.run.localize", flaky)
    tracker = Recorder()
    result = run_jobs(plan_runs(workspace, "flaky"), workspace[0] / "cache-a", tracker)
    assert failed and not tracker.failures and not result.failed and len(result.documents) == 4
    for left, right in zip(folders(workspace, "in-process"), folders(workspace, "flaky")):
        assert canonical(left) == canonical(right)


def test_frames_without_annotations_are_left_out_as_clipclique_loc_leaves_them(tmp_path, monkeypatch, tum_sequence):
    """The tiny TUM sequence annotates one of its three frames: the benchmark's run is clipclique-loc's, note
    included."""
    from clipclique.mapping.run import run_build

    folder = tum_sequence(tmp_path, rounded=True)
    monkeypatch.chdir(tmp_path)
    run_build(folder.name, tmp_path, Path("outputs/maps") / f"{folder.name}.map.npz", encoder_spec="none", rrd=False)
    result = run_jobs(runs(Plan([folder.name]), tmp_path / "bench", tmp_path, record=False), tmp_path / "cache",
                      Recorder())
    reference = run_and_save(RunSettings(folder.name, data_root=tmp_path, out=tmp_path / "loc", record=False))
    (document,) = result.documents
    assert document["summary"]["frames"] == 1 and document["summary"]["not_annotated"] == 2
    assert (document["run"]["notes"] == reference["run"]["notes"]
            and any("no annotations" in n for n in reference["run"]["notes"]))
    assert (canonical(tmp_path / "bench" / folder.name / "clipclique" / "results.json")
            == canonical(tmp_path / "loc" / "results.json"))


def test_run_inputs_shared_with_clipclique_loc_give_its_results_in_process_and_on_a_cluster(workspace, in_process):
    """--map, --same-place, --window, --odometry and --odometry-drift (clipclique.localization.inputs): a window's
    earlier frames are perceived and read from the cache; before, clipclique-bench had none of these options."""
    from distributed import Client, LocalCluster

    from clipclique.localization.inputs import RunInputs

    folder, data = workspace
    inputs = RunInputs(map=folder / "outputs" / "maps" / "demo.map.npz", same_place=True, window=3,
                       odometry="groundtruth", odometry_drift=2.0)
    plan = Plan(["demo_tum"], ["clipclique"], stride=2, inputs=inputs)
    (settings,) = runs(plan, folder / "inputs-a", data, record=False)
    assert settings.map_path == inputs.map and settings.window == 3 and "window=3" in settings.run_name()
    result = run_jobs([settings], folder / "cache-inputs", Recorder())
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) \
            as cluster, Client(cluster) as client:
        on_cluster = run_jobs(runs(plan, folder / "inputs-b", data, record=False), folder / "cache-inputs-b",
                              Recorder(),
                              client)
    assert not result.failed and not on_cluster.failed
    reference = folder / "loc-inputs"
    run_and_save(RunSettings("demo_tum", data_root=data, out=reference, record=False, stride=2, **inputs.settings()))
    expected = canonical(reference / "results.json")
    assert len(expected) == 3
    for out in (settings.out, folder / "inputs-b" / settings.out.relative_to(folder / "inputs-a")):
        assert canonical(out / "results.json") == expected
        assert (out / "poses.tum").read_text() == (reference / "poses.tum").read_text()
    # 3: not selected, perceived for the window
    assert read_results(settings.out / "results.json")["frames"][2]["window"]["frames"] == [2, 3, 4]
