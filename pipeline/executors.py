"""Where per-asset jobs run: in this process, in a pool of worker processes, or on a Dask cluster.

All three executors take the same `AssetTask`s and report through the same `Reporter`
(`started`, `frame`, `finished`, always called in the calling thread), so the batch logic,
the manifest and the progress display do not care where a job ran. A job never raises out of
an executor: every failure, including a worker process that dies (segfault, out of memory,
killed), becomes a failed `AssetOutcome` for that asset alone.

Workers set their thread counts before the engine is imported: Numba gets `cores // jobs`
threads (at least 1) and the BLAS/OpenMP pools 1, so N jobs on N cores do not oversubscribe.
Pool workers die with the batch process, even when it is killed with SIGKILL, and then never put
an output folder into place (`pipeline.interrupts.watch_parent`); they keep library warnings off
stderr, and each job's warnings travel back in its outcome, for the batch log.
"""

from __future__ import annotations

import contextlib
import importlib
import multiprocessing
import os
import queue as queue_module
import signal
import threading
import time
import traceback
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from pipeline.diagnostics import collecting_warnings, quiet_worker
from pipeline.hashing import file_sha256
from pipeline.interrupts import noting_unwritten, watch_parent, worker_job
from pipeline.memory import MALLOC_ENVIRONMENT, tune_malloc
from pipeline.output_folder import remove_stale_stages

#: a job: (mesh path, recipe, output folder, on_frame=callback) -> an object with a `report` dict
JobFunction = Callable[..., Any]
#: a progress event sent from a worker: ("start", index, pid) or ("frame", index, frame, total)
Event = tuple[Any, ...]

#: environment variables that size the native thread pools of NumPy's BLAS and OpenMP
SINGLE_THREAD_POOLS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")
#: Python warning filter for the pool's helper processes: the resource tracker would warn on stderr
#: about the semaphores of a batch process that was killed (it could not release them itself)
QUIET_RESOURCE_TRACKER = "ignore:resource_tracker:UserWarning"
#: seconds between two per-frame progress messages of one job (the last frame is always sent)
FRAME_EVENT_INTERVAL = 0.05
#: error type recorded when the process running an asset died
WORKER_DIED = "WorkerDied"


@dataclass(frozen=True)
class AssetTask:
    """One asset to run: picklable, so it can travel to a worker process or a Dask worker.

    index: position in the batch (stable: the sorted discovery order).
    key: the asset's name in the manifest (its path relative to the assets folder).
    mesh_path / out_dir: absolute paths (the same on every machine of a Dask cluster).
    recipe: the merged per-asset Recipe, or an object whose `load()` returns it (built in the
        worker from the files: `pipeline.assets.AssetRecipe`).
    job: the job function; None means `pipeline.job.run_job` (tests inject fakes).
    """

    index: int
    key: str
    mesh_path: str
    out_dir: str
    recipe: Any
    job: JobFunction | None = None


@dataclass(frozen=True)
class AssetOutcome:
    """What became of one asset: status "ok" or "failed", with the one-line error when it failed."""

    status: str
    seconds: float
    error: str | None = None
    error_type: str | None = None
    outputs: list[str] = field(default_factory=list)
    frames: int | None = None
    input_sha256: str | None = None
    recipe_sha256: str | None = None
    #: the formatted traceback of unexpected errors (bugs), for the log only
    traceback: str | None = None
    #: the distinct Python / library warnings the job raised (NumPy, Numba...), for the log only
    warnings: list[str] = field(default_factory=list)


class Reporter(Protocol):
    """Receives what happens to the tasks; executors call it from the thread that called `run`."""

    def started(self, task: AssetTask) -> None: ...

    def frame(self, task: AssetTask, frame: int, total: int) -> None: ...

    def finished(self, task: AssetTask, outcome: AssetOutcome) -> None: ...


class Executor(Protocol):
    """Runs tasks somewhere and reports each one's progress and outcome; never raises for a job."""

    name: str

    def run(self, tasks: Sequence[AssetTask], reporter: Reporter) -> None: ...

    def close(self) -> None: ...


# -- threads ---------------------------------------------------------------------------------


def available_cores() -> int:
    """Cores this process may use (the CPU affinity mask where the OS has one)."""
    with contextlib.suppress(AttributeError, OSError):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def threads_per_job(jobs: int, cores: int | None = None) -> int:
    """Numba threads for each of `jobs` concurrent jobs: cores // jobs, at least 1."""
    return max(1, (cores or available_cores()) // max(1, jobs))


def worker_environment(threads: int) -> dict[str, str]:
    """Environment for a worker process: Numba sized to `threads`, BLAS/OpenMP pools to one thread."""
    env = {name: "1" for name in SINGLE_THREAD_POOLS}
    env["NUMBA_NUM_THREADS"] = str(threads)
    env.update(MALLOC_ENVIRONMENT)
    warning_filters = os.environ.get("PYTHONWARNINGS")
    if not warning_filters:
        env["PYTHONWARNINGS"] = QUIET_RESOURCE_TRACKER
    elif QUIET_RESOURCE_TRACKER not in warning_filters:
        env["PYTHONWARNINGS"] = f"{warning_filters},{QUIET_RESOURCE_TRACKER}"
    return env


@contextlib.contextmanager
def patched_environ(values: Mapping[str, str]) -> Iterator[None]:
    """Set environment variables for the block (spawned children inherit them), then restore."""
    saved = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, old in saved.items():
            if old is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = old


def set_numba_threads(threads: int) -> None:
    """Ask Numba (if it is loaded) to use `threads` threads in this thread; no-op beyond its maximum."""
    import sys

    numba = sys.modules.get("numba")
    if numba is None:
        return
    with contextlib.suppress(Exception):
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


# -- running one task ------------------------------------------------------------------------


def one_line(exc: BaseException) -> tuple[str, str]:
    """(error line, type name): our typed errors keep their message, others get `Type: message`.
    A recipe's error is named RecipeError whichever of its kinds it is (the manifest's documented
    `error_type`; `LocatedError` is how the recipe reader words it, not a kind of its own)."""
    from meshdeform.errors import MeshdeformError, RecipeError

    text = " ".join(str(exc).split()) or "(no message)"
    name = RecipeError.__name__ if isinstance(exc, RecipeError) else type(exc).__name__
    return (text if isinstance(exc, MeshdeformError) else f"{name}: {text}"), name


def _input_hash(path: str) -> str | None:
    """sha256 of the input (`pipeline.hashing.file_sha256`), or None when it cannot be read."""
    try:
        return file_sha256(path)
    except OSError:
        return None


def _default_job() -> JobFunction:
    from pipeline.job import run_job

    return run_job


def execute_task(task: AssetTask, emit: Callable[[Event], None] | None = None) -> AssetOutcome:
    """Run one task's job and describe the outcome; never raises an Exception (only interrupts).

    `emit` receives ("start", index, pid) before the job and throttled ("frame", index, i, n)
    events during it.
    """
    started = time.perf_counter()
    tune_malloc()  # in whichever process runs the job (pool and Dask workers included)
    if emit is not None:
        emit(("start", task.index, os.getpid()))
    last = [0.0]

    def on_frame(frame: int, total: int) -> None:
        now = time.perf_counter()
        if emit is not None and (frame >= total or now - last[0] >= FRAME_EVENT_INTERVAL):
            last[0] = now
            emit(("frame", task.index, frame, total))

    out_dir = Path(task.out_dir)
    try:
        # (a job's error ends in its outcome: the folder it kept from being written is not noted for the CLI)
        with collecting_warnings() as warned, noting_unwritten():
            remove_stale_stages(out_dir)
            job = task.job or _default_job()
            recipe = task.recipe.load() if hasattr(task.recipe, "load") else task.recipe
            result = job(Path(task.mesh_path), recipe, out_dir, on_frame=on_frame)
        report: dict[str, Any] = dict(getattr(result, "report", None) or {})
    except Exception as exc:
        from meshdeform.errors import MeshdeformError

        error, kind = one_line(exc)
        recipe_sha = None
        with contextlib.suppress(Exception):
            from pipeline.recipe import recipe_hash

            recipe_sha = recipe_hash(recipe)  # unbound (NameError, suppressed) if loading failed
        return AssetOutcome(
            status="failed",
            seconds=round(time.perf_counter() - started, 4),
            error=error,
            error_type=kind,
            input_sha256=_input_hash(task.mesh_path),
            recipe_sha256=recipe_sha,
            traceback=None if isinstance(exc, MeshdeformError) else traceback.format_exc(),
            warnings=list(warned),
        )
    frames = report.get("frames")
    return AssetOutcome(
        status="ok",
        seconds=round(time.perf_counter() - started, 4),
        outputs=[str(p) for p in report.get("outputs", [])],
        frames=int(frames) if frames is not None else None,
        input_sha256=report.get("input_sha256"),
        recipe_sha256=report.get("recipe_sha256"),
        warnings=list(warned),
    )


def died_outcome(description: str) -> AssetOutcome:
    """The outcome of an asset whose worker process died under it."""
    return AssetOutcome(
        status="failed",
        seconds=0.0,
        error=f"worker process died while running this asset ({description})",
        error_type=WORKER_DIED,
    )


def lost_outcome(exc: Exception) -> AssetOutcome:
    """The outcome of an asset whose task could not be sent or whose result never came back (`exc`)."""
    error, kind = one_line(exc)
    return AssetOutcome(status="failed", seconds=0.0, error=error, error_type=kind)


def _describe_exit(code: int | None) -> str:
    """`killed by SIGSEGV` / `exit code 3` / `unknown exit status` for a dead process."""
    if code is None:
        return "crash, out of memory or killed"
    if code < 0:
        with contextlib.suppress(ValueError):
            return f"killed by {signal.Signals(-code).name}"
        return f"killed by signal {-code}"
    return f"exit code {code}"


# -- in this process -------------------------------------------------------------------------


class SerialExecutor:
    """Runs the tasks one after another in this process (`--jobs 0`): no isolation from crashes,
    but debuggers, profilers and tracebacks work as usual."""

    name = "serial"

    def run(self, tasks: Sequence[AssetTask], reporter: Reporter) -> None:
        for task in tasks:

            def emit(event: Event, task: AssetTask = task) -> None:
                if event[0] == "start":
                    reporter.started(task)
                elif event[0] == "frame":
                    reporter.frame(task, event[2], event[3])

            reporter.finished(task, execute_task(task, emit))

    def close(self) -> None:
        pass


# -- worker processes --------------------------------------------------------------------------

_WORKER_EVENTS: Any = None


def _init_worker(env: dict[str, str], events: Any, threads: int, preload: tuple[str, ...], parent: int) -> None:
    """Pool initializer: bound to the batch process `parent` (the worker dies with it), library
    chatter off stderr, thread pools sized, engine imported once, progress queue remembered.

    A Ctrl-C in the terminal reaches the workers too: the running job is interrupted and removes
    its staging folder, then the worker ends; the parent stops the pool and removes the staging
    folders of workers it terminated.
    """
    global _WORKER_EVENTS
    watch_parent(parent)
    quiet_worker()
    os.environ.update(env)
    _WORKER_EVENTS = events
    for module in preload:  # numpy, numba and the engine, once per worker (an error shows in the job)
        with contextlib.suppress(Exception):
            importlib.import_module(module)
    set_numba_threads(threads)


def _pool_task(task: AssetTask) -> AssetOutcome:
    """What a pool worker runs: the task, with progress events to the parent's queue."""
    events = _WORKER_EVENTS
    with worker_job():
        return execute_task(task, events.put if events is not None else None)


def _running_at_death(remaining: Sequence[AssetTask], started: dict[int, int]) -> list[AssetTask]:
    """The unfinished tasks each worker was running when the pool broke: per worker pid, the last
    one it started (a result sent just before the break may be lost; that task is not a suspect)."""
    last: dict[int, int] = {}
    for index, pid in started.items():  # in start order (one queue, read in order)
        last[pid] = index
    running = set(last.values())
    return [t for t in remaining if t.index in running]


class ProcessPoolJobExecutor:
    """Runs tasks in a pool of `jobs` worker processes (spawn), created once and reused; each worker
    imports the `preload` modules (the engine) once, when it starts.

    A worker that dies takes the pool down with it (concurrent.futures marks the pool broken and
    stops the other workers). The executor then knows which assets had started and not finished:
    with one such asset, that one failed; with several, each is rerun alone in a one-worker pool
    to find the culprit. Everything else is resubmitted to a fresh pool. Each round fails or
    finishes at least one asset, so a batch always ends.
    """

    name = "processes"

    def __init__(self, jobs: int, cores: int | None = None, preload: Sequence[str] = ("pipeline.job",)) -> None:
        self.jobs = max(1, jobs)
        self.preload = tuple(preload)
        self.threads = threads_per_job(self.jobs, cores)
        self._context = multiprocessing.get_context("spawn")
        self._events: Any = None
        self._pool: ProcessPoolExecutor | None = None
        self._pool_size = 0
        self.pools_created = 0

    # The pool is created lazily and kept for the whole batch; it is replaced only after a crash.
    def _get_pool(self, size: int) -> ProcessPoolExecutor:
        if self._pool is not None and self._pool_size == size:
            return self._pool
        self._shutdown_pool()
        env = worker_environment(self.threads)
        with patched_environ(env):  # (the queue's lock starts the resource tracker: it inherits env)
            if self._events is None:
                self._events = self._context.SimpleQueue()  # synchronous put: no event lost on a crash
            self._pool = ProcessPoolExecutor(
                max_workers=size,
                mp_context=self._context,
                initializer=_init_worker,
                initargs=(env, self._events, self.threads, self.preload, os.getpid()),
            )
        self._pool_size = size
        self.pools_created += 1
        return self._pool

    def _shutdown_pool(self) -> None:
        """Stop the pool's workers. It is only called with no work outstanding (all results in, or
        the batch interrupted), so they are terminated rather than asked to exit: a worker's
        interpreter teardown (Numba, LLVM) takes about a second, for nothing."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        for process in list((getattr(pool, "_processes", None) or {}).values()):
            with contextlib.suppress(Exception):
                process.terminate()
        pool.shutdown(wait=True, cancel_futures=True)

    def _drain(
        self, running: dict[int, AssetTask], done: set[int], started: dict[int, int], reporter: Reporter
    ) -> None:
        events = self._events
        while events is not None and not events.empty():
            event = events.get()
            index = event[1]
            if index in done or index not in running:
                continue
            if event[0] == "start":
                started[index] = event[2]
                reporter.started(running[index])
            elif event[0] == "frame":
                reporter.frame(running[index], event[2], event[3])

    def _round(
        self, tasks: list[AssetTask], size: int, reporter: Reporter, done: set[int]
    ) -> tuple[bool, dict[int, int], dict[int, int | None]]:
        """Run `tasks` in a pool of `size`; returns (pool broke, started pids, exit codes by pid)."""
        env = worker_environment(self.threads)
        pool = self._get_pool(size)
        running = {t.index: t for t in tasks}
        started: dict[int, int] = {}
        with patched_environ(env):  # workers may be (re)spawned at submit time
            futures: dict[Future[AssetOutcome], AssetTask] = {pool.submit(_pool_task, t): t for t in tasks}
        processes = getattr(pool, "_processes", None) or {}
        broken = False
        pending = set(futures)
        while pending:
            finished, pending = wait(pending, timeout=0.1, return_when=FIRST_COMPLETED)
            self._drain(running, done, started, reporter)
            for future in sorted(finished, key=lambda f: futures[f].index):
                task = futures[future]
                try:
                    outcome = future.result()
                except BrokenProcessPool:
                    broken = True
                    continue
                except Exception as exc:  # the task could not be sent or its result not received
                    outcome = lost_outcome(exc)
                done.add(task.index)
                reporter.finished(task, outcome)
        self._drain(running, done, started, reporter)
        exit_codes: dict[int, int | None] = {}
        if broken:  # join the dead pool first: its exit codes are known only once it is reaped
            snapshot = dict(processes)
            self._shutdown_pool()
            exit_codes = {pid: process.exitcode for pid, process in snapshot.items()}
            # a worker killed while sending an event (the one that died, or one the pool stopped)
            # leaves the queue's write lock held for good: the next pool's workers would wait on it
            # forever, so they get a queue of their own
            self._events = None
        return broken, started, exit_codes

    def run(self, tasks: Sequence[AssetTask], reporter: Reporter) -> None:
        done: set[int] = set()
        todo = list(tasks)
        try:
            while todo:
                broken, started, exit_codes = self._round(todo, min(self.jobs, len(todo)), reporter, done)
                remaining = [t for t in todo if t.index not in done]
                if not broken:
                    todo = remaining
                    continue
                suspects = _running_at_death(remaining, started)
                if not suspects:  # died before any job started: the workers cannot start at all
                    for task in remaining:
                        done.add(task.index)
                        reporter.finished(task, died_outcome("the worker process could not start"))
                    return
                # The pool stops the surviving workers with SIGTERM: a worker that ended any other
                # way is the one that died. Without such a clear answer, rerun the suspects alone.
                terminated = -signal.SIGTERM.value
                culprits = [t for t in suspects if exit_codes.get(started[t.index], terminated) != terminated]
                if len(suspects) == 1 or culprits:
                    for culprit in culprits or suspects:
                        done.add(culprit.index)
                        code = exit_codes.get(started[culprit.index])
                        reporter.finished(culprit, died_outcome(_describe_exit(code)))
                else:
                    self._isolate(suspects, reporter, done)
                todo = [t for t in remaining if t.index not in done]
        except BaseException:
            self._shutdown_pool()
            raise

    def _isolate(self, suspects: list[AssetTask], reporter: Reporter, done: set[int]) -> None:
        """Rerun assets that were running when a worker died one at a time, to blame the right one."""
        todo = list(suspects)
        while todo:
            broken, started, exit_codes = self._round(todo, 1, reporter, done)
            remaining = [t for t in todo if t.index not in done]
            if broken:
                blamed = _running_at_death(remaining, started) or remaining[:1]
                for task in blamed:
                    done.add(task.index)
                    code = exit_codes.get(started.get(task.index, -1))
                    reporter.finished(task, died_outcome(_describe_exit(code)))
            todo = [t for t in remaining if t.index not in done]
        self._shutdown_pool()

    def close(self) -> None:
        self._shutdown_pool()
        self._events = None


# -- Dask ----------------------------------------------------------------------------------------


def _dask_task(task: AssetTask, topic: str) -> AssetOutcome:
    """What a Dask worker runs: Numba sized to this worker's share of cores, progress as events."""
    from distributed import get_worker

    worker = get_worker()
    nthreads = getattr(worker.state, "nthreads", None) or getattr(worker, "nthreads", 1) or 1
    set_numba_threads(threads_per_job(nthreads))

    def emit(event: Event) -> None:
        with contextlib.suppress(Exception):
            worker.log_event(topic, list(event))

    return execute_task(task, emit)


class DaskExecutor:
    """Submits the same tasks to a Dask distributed scheduler (`--dask tcp://host:port`).

    Workers need meshdeform installed and the assets and output folders at the same absolute
    paths (a shared file system). When a worker dies, the scheduler blames every task it held
    (also those queued on it) and, after `distributed.scheduler.allowed-failures` deaths, fails them
    with KilledWorker. So with several such failures, each of those assets is run again alone:
    the innocent ones then finish, the one that kills its worker fails (`WorkerDied`).
    """

    name = "dask"

    def __init__(self, address: str | Any, timeout: float = 10.0) -> None:
        from distributed import Client

        if isinstance(address, str):
            self.client = Client(address, timeout=timeout, set_as_default=False)
            self._own_client = True
        else:
            self.client = address
            self._own_client = False

    def run(self, tasks: Sequence[AssetTask], reporter: Reporter) -> None:
        killed = self._run(tasks, reporter, hold_killed=True)
        if len(killed) == 1:  # the task that kills its worker always ends in KilledWorker
            reporter.finished(*killed[0])
            return
        for task, _ in killed:
            self._run([task], reporter, hold_killed=False)

    def _run(
        self, tasks: Sequence[AssetTask], reporter: Reporter, hold_killed: bool
    ) -> list[tuple[AssetTask, AssetOutcome]]:
        """Run tasks and report them; with `hold_killed`, KilledWorker outcomes are returned instead."""
        from distributed import as_completed

        inbox: queue_module.Queue[Event] = queue_module.Queue()
        topic = f"meshdeform-batch-{uuid.uuid4().hex}"

        def on_event(event: Any) -> None:
            message = event[1] if isinstance(event, tuple | list) and len(event) == 2 else event
            inbox.put(tuple(message))

        self.client.subscribe_topic(topic, on_event)
        by_index = {t.index: t for t in tasks}
        futures = [
            self.client.submit(
                _dask_task, task, topic, key=f"meshdeform-{topic[-12:]}-{task.index}", pure=False, retries=0
            )
            for task in tasks
        ]
        key_to_task = {f.key: t for f, t in zip(futures, tasks, strict=True)}
        stop = threading.Event()

        def collect() -> None:
            with contextlib.suppress(Exception):  # the main loop fails whatever is left without a result
                _collect()

        def _collect() -> None:
            for future in as_completed(futures, loop=self.client.loop):
                if stop.is_set():
                    return
                task = key_to_task[future.key]
                try:
                    outcome = future.result()
                except Exception as exc:  # KilledWorker, a worker lost, a result that cannot travel
                    error, kind = one_line(exc)
                    outcome = died_outcome(f"Dask: {error}") if kind == "KilledWorker" else lost_outcome(exc)
                inbox.put(("done", task.index, outcome))

        collector = threading.Thread(target=collect, name="meshdeform-dask-results", daemon=True)
        collector.start()
        done: set[int] = set()
        killed: list[tuple[AssetTask, AssetOutcome]] = []
        try:
            while len(done) < len(tasks):
                try:
                    event = inbox.get(timeout=0.1)
                except queue_module.Empty:
                    if not collector.is_alive() and inbox.empty():
                        break
                    continue
                kind, index = event[0], event[1]
                if index in done or index not in by_index:
                    continue
                if kind == "start":
                    reporter.started(by_index[index])
                elif kind == "frame":
                    reporter.frame(by_index[index], event[2], event[3])
                elif kind == "done":
                    done.add(index)
                    if hold_killed and event[2].error_type == WORKER_DIED:
                        killed.append((by_index[index], event[2]))
                    else:
                        reporter.finished(by_index[index], event[2])
        except BaseException:
            stop.set()
            with contextlib.suppress(Exception):
                self.client.cancel(futures)
            raise
        finally:
            with contextlib.suppress(Exception):
                self.client.unsubscribe_topic(topic)
        for task in tasks:  # the collector stopped early: should not happen, but never lose an asset
            if task.index not in done:
                reporter.finished(
                    task,
                    AssetOutcome(
                        status="failed",
                        seconds=0.0,
                        error="Dask returned no result for this asset",
                        error_type="DaskError",
                    ),
                )
        return sorted(killed, key=lambda item: item[0].index)

    def close(self) -> None:
        if self._own_client:
            with contextlib.suppress(Exception):
                self.client.close()


def make_executor(jobs: int, dask: str | None = None) -> Executor:
    """The executor for the command's options: Dask when an address is given, else `jobs` processes
    (0 runs in this process)."""
    if dask:
        return DaskExecutor(dask)
    if jobs <= 0:
        return SerialExecutor()
    return ProcessPoolJobExecutor(jobs)
