"""Executors: serial, process pool and Dask run the same tasks, report the same way, isolate failures.

The job here is a fake (module level, so spawned workers can import it): it writes a few files and
a report, or fails in a chosen way according to the mesh file name.
"""

from __future__ import annotations

import json
import os
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from meshdeform.errors import MeshLoadError
from pipeline.executors import (
    WORKER_DIED,
    AssetOutcome,
    AssetTask,
    DaskExecutor,
    ProcessPoolJobExecutor,
    SerialExecutor,
    available_cores,
    execute_task,
    threads_per_job,
)
from pipeline.output_folder import stage_path


@dataclass
class FakeResult:
    report: dict[str, Any]


def fake_job(mesh_path: Path, recipe: Any, out_dir: Path, *, on_frame: Any = None) -> FakeResult:
    """Fails according to the file name (crash / bug / broken), else writes frames and a report."""
    name = mesh_path.name
    if "crash" in name:
        os.kill(os.getpid(), signal.SIGKILL)
    if "bug" in name:
        raise ValueError("index 7 is out of bounds\nfor axis 0")
    if "broken" in name:
        raise MeshLoadError(f"{mesh_path}: line 3: face refers to vertex 9 of 4")
    frames = int((recipe or {}).get("frames", 3))
    out_dir.mkdir(parents=True, exist_ok=True)
    outputs = []
    for i in range(1, frames + 1):
        (out_dir / f"frame_{i:04d}.txt").write_text(f"{name} {i}\n")
        outputs.append(f"frame_{i:04d}.txt")
        if on_frame is not None:
            on_frame(i, frames)
    environment = {k: os.environ.get(k) for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    (out_dir / "env.json").write_text(json.dumps({**environment, "pid": os.getpid()}))
    report = {"frames": frames, "outputs": [*outputs, "env.json"], "input_sha256": "in", "recipe_sha256": "rc"}
    return FakeResult(report)


def locking_job(mesh_path: Path, recipe: Any, out_dir: Path, *, on_frame: Any = None) -> FakeResult:
    """Like fake_job, but "locked" assets die as a worker does that is killed while it sends a
    progress event: holding the event queue's write lock."""
    if "locked" in mesh_path.name:
        import pipeline.executors

        pipeline.executors._WORKER_EVENTS._wlock.acquire()
        os.kill(os.getpid(), signal.SIGKILL)
    return fake_job(mesh_path, recipe, out_dir, on_frame=on_frame)


def slow_job(mesh_path: Path, recipe: Any, out_dir: Path, *, on_frame: Any = None) -> FakeResult:
    """Like fake_job, after a short sleep (so that two crashes overlap two running assets)."""
    time.sleep(0.3)
    return fake_job(mesh_path, recipe, out_dir, on_frame=on_frame)


def warning_job(mesh_path: Path, recipe: Any, out_dir: Path, *, on_frame: Any = None) -> FakeResult:
    """Like fake_job, after NumPy warns twice the same way and once another way."""
    import numpy as np

    with np.errstate(over="warn", invalid="warn"):
        for _ in range(2):
            np.multiply(np.array([1e308]), 10.0)
        np.subtract(np.array([np.inf]), np.inf)
    return fake_job(mesh_path, recipe, out_dir, on_frame=on_frame)


class Recorder:
    def __init__(self) -> None:
        self.events: list[tuple[str, str]] = []
        self.frames: dict[str, list[int]] = {}
        self.outcomes: dict[str, AssetOutcome] = {}

    def started(self, task: AssetTask) -> None:
        self.events.append(("started", task.key))

    def frame(self, task: AssetTask, frame: int, total: int) -> None:
        self.frames.setdefault(task.key, []).append(frame)

    def finished(self, task: AssetTask, outcome: AssetOutcome) -> None:
        self.events.append(("finished", task.key))
        self.outcomes[task.key] = outcome


def make_tasks(tmp_path: Path, names: list[str], job: Any = fake_job, frames: int = 3) -> list[AssetTask]:
    folder = tmp_path / "in"
    folder.mkdir(exist_ok=True)
    tasks = []
    for index, name in enumerate(names):
        (folder / name).write_text("v 0 0 0\n")
        tasks.append(
            AssetTask(
                index=index,
                key=name,
                mesh_path=str(folder / name),
                out_dir=str(tmp_path / "out" / Path(name).stem),
                recipe={"frames": frames},
                job=job,
            )
        )
    return tasks


def run_closing(executor: ProcessPoolJobExecutor, tasks: list[AssetTask]) -> Recorder:
    """Run `tasks` with `executor`, closed afterwards (even when a test fails); what it reported."""
    recorder = Recorder()
    try:
        executor.run(tasks, recorder)
    finally:
        executor.close()
    return recorder


def test_threads_per_job_never_below_one() -> None:
    assert threads_per_job(1, 8) == 8
    assert threads_per_job(3, 8) == 2
    assert threads_per_job(16, 8) == 1
    assert threads_per_job(2) == max(1, available_cores() // 2)


def test_execute_task_turns_errors_into_one_line_outcomes(tmp_path: Path) -> None:
    ok, broken, bug = make_tasks(tmp_path, ["fine.obj", "broken.obj", "bug.obj"])
    events: list[tuple[Any, ...]] = []
    outcome = execute_task(ok, events.append)
    assert outcome.status == "ok" and outcome.frames == 3 and outcome.error is None
    assert events[0][:2] == ("start", 0) and events[-1] == ("frame", 0, 3, 3)
    failed = execute_task(broken)
    assert failed.status == "failed" and failed.error_type == "MeshLoadError"
    assert failed.error.endswith("line 3: face refers to vertex 9 of 4") and failed.traceback is None
    assert failed.input_sha256 is not None  # the input is hashed even when the job fails
    crashed = execute_task(bug)
    assert crashed.error == "ValueError: index 7 is out of bounds for axis 0"  # one line
    assert crashed.error_type == "ValueError" and "Traceback" in (crashed.traceback or "")


def test_execute_task_removes_stale_staging_folders(tmp_path: Path) -> None:
    (task,) = make_tasks(tmp_path, ["a.obj"])
    stale = stage_path(Path(task.out_dir))
    stale.mkdir(parents=True)
    (stale / "frame_0001.txt").write_text("half")
    kept = [Path(task.out_dir).parent / name for name in (".a.old-mybackup", ".a.partial-0123abcd", ".a1.partial-x")]
    kept.append(stage_path(Path(task.out_dir).parent / "a1"))  # another asset's (a glob 'a*' would match)
    for folder in kept:
        folder.mkdir()
    assert execute_task(task).status == "ok"
    assert not stale.exists() and all(folder.exists() for folder in kept)


def test_serial_executor_reports_in_order(tmp_path: Path) -> None:
    tasks = make_tasks(tmp_path, ["a.obj", "bug.obj", "c.obj"])
    recorder = Recorder()
    SerialExecutor().run(tasks, recorder)
    assert recorder.events == [(e, k) for k in ("a.obj", "bug.obj", "c.obj") for e in ("started", "finished")]
    assert [recorder.outcomes[k].status for k in ("a.obj", "bug.obj", "c.obj")] == ["ok", "failed", "ok"]
    assert recorder.frames["a.obj"][-1] == 3


def test_process_pool_reuses_workers_and_sizes_threads(tmp_path: Path) -> None:
    tasks = make_tasks(tmp_path, [f"m{i}.obj" for i in range(6)] + ["bug.obj", "broken.obj"])
    names = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
    before = {k: os.environ.get(k) for k in names}
    executor = ProcessPoolJobExecutor(jobs=2, preload=())
    recorder = run_closing(executor, tasks)
    assert executor.pools_created == 1
    statuses = {k: o.status for k, o in recorder.outcomes.items()}
    assert statuses == {**{f"m{i}.obj": "ok" for i in range(6)}, "bug.obj": "failed", "broken.obj": "failed"}
    assert recorder.outcomes["bug.obj"].error.startswith("ValueError: ")
    envs = [json.loads((tmp_path / "out" / f"m{i}" / "env.json").read_text()) for i in range(6)]
    assert len({e["pid"] for e in envs}) <= 2 and os.getpid() not in {e["pid"] for e in envs}
    for env in envs:
        assert env["NUMBA_NUM_THREADS"] == str(threads_per_job(2))
        assert env["OMP_NUM_THREADS"] == env["OPENBLAS_NUM_THREADS"] == "1"
    assert {k: os.environ.get(k) for k in names} == before  # this process's environment is restored
    assert all(recorder.frames[f"m{i}.obj"][-1] == 3 for i in range(6))  # per-frame progress from workers


def test_pool_workers_return_the_warnings_of_a_job_for_the_log(tmp_path: Path) -> None:
    """Library warnings raised in a worker come back once each with the outcome (for the batch
    log), not on the worker's stderr."""
    (task,) = make_tasks(tmp_path, ["w.obj"], job=warning_job)
    recorder = run_closing(ProcessPoolJobExecutor(jobs=1, preload=()), [task])
    warned = recorder.outcomes["w.obj"].warnings
    assert recorder.outcomes["w.obj"].status == "ok"
    assert len(warned) == 2
    assert "RuntimeWarning: overflow encountered in multiply" in warned[0]
    assert "RuntimeWarning: invalid value encountered in subtract" in warned[1]


def test_process_pool_survives_a_worker_that_dies(tmp_path: Path) -> None:
    names = ["a.obj", "b.obj", "crash.obj", "d.obj", "e.obj", "f.obj"]
    tasks = make_tasks(tmp_path, names)
    recorder = run_closing(ProcessPoolJobExecutor(jobs=2, preload=()), tasks)
    assert set(recorder.outcomes) == set(names)
    died = recorder.outcomes["crash.obj"]
    assert died.status == "failed" and died.error_type == WORKER_DIED and "SIGKILL" in died.error
    for name in names:
        if name != "crash.obj":
            assert recorder.outcomes[name].status == "ok", recorder.outcomes[name]
            assert (tmp_path / "out" / Path(name).stem / "frame_0003.txt").is_file()


def test_process_pool_survives_a_worker_killed_while_sending_progress(tmp_path: Path) -> None:
    """A worker killed in the middle of sending an event (the pool stops its survivors so) holds the
    event queue's lock for good; the next pool's workers must not wait on it (they hung there)."""
    names = ["locked.obj", "b.obj", "c.obj"]
    recorder = run_closing(ProcessPoolJobExecutor(jobs=1, preload=()), make_tasks(tmp_path, names, job=locking_job))
    assert recorder.outcomes["locked.obj"].status == "failed"
    assert recorder.outcomes["b.obj"].status == recorder.outcomes["c.obj"].status == "ok"
    assert recorder.frames["c.obj"][-1] == 3  # the new pool's progress events arrive


def test_process_pool_blames_the_right_assets_when_two_die_together(tmp_path: Path) -> None:
    names = ["crash1.obj", "crash2.obj", "ok1.obj", "ok2.obj", "ok3.obj"]
    tasks = make_tasks(tmp_path, names, job=slow_job)
    recorder = run_closing(ProcessPoolJobExecutor(jobs=2, preload=()), tasks)
    assert {k: o.status for k, o in recorder.outcomes.items()} == {
        "crash1.obj": "failed",
        "crash2.obj": "failed",
        "ok1.obj": "ok",
        "ok2.obj": "ok",
        "ok3.obj": "ok",
    }
    assert recorder.outcomes["crash2.obj"].error_type == WORKER_DIED


@pytest.fixture(scope="module")
def dask_client() -> Any:
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=":0", silence_logs=40
    )
    client = distributed.Client(cluster, set_as_default=False)
    yield client
    client.close()
    cluster.close()


def test_dask_executor_runs_tasks_and_isolates_failures(tmp_path: Path, dask_client: Any) -> None:
    tasks = make_tasks(tmp_path, ["a.obj", "bug.obj", "broken.obj", "d.obj"], frames=4)
    recorder = Recorder()
    DaskExecutor(dask_client).run(tasks, recorder)
    assert {k: o.status for k, o in recorder.outcomes.items()} == {
        "a.obj": "ok",
        "bug.obj": "failed",
        "broken.obj": "failed",
        "d.obj": "ok",
    }
    assert recorder.outcomes["bug.obj"].error == "ValueError: index 7 is out of bounds for axis 0"
    assert (tmp_path / "out" / "d" / "frame_0004.txt").read_text() == "d.obj 4\n"


def test_dask_executor_fails_only_the_asset_that_kills_its_worker(tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    tasks = make_tasks(tmp_path, ["a.obj", "crash.obj", "c.obj"])
    recorder = Recorder()
    with (
        distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=50
        ) as cluster,
        distributed.Client(cluster, set_as_default=False) as client,
    ):
        DaskExecutor(client).run(tasks, recorder)
    assert {k: o.status for k, o in recorder.outcomes.items()} == {"a.obj": "ok", "crash.obj": "failed", "c.obj": "ok"}
    assert recorder.outcomes["crash.obj"].error_type == WORKER_DIED
    assert "KilledWorker" in recorder.outcomes["crash.obj"].error
