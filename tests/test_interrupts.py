"""Interruptions through real signals: `simulate` and `batch` subprocesses killed mid-run leave
nothing behind and say so in one line; pool workers die with a batch process killed by SIGKILL.

The meshes are small and the runs long (thousands of frames), so every signal lands mid-run;
each wait is bounded, so a hung process fails the test instead of hanging it.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.interrupts import (
    Interrupted,
    handling_signals,
    note_unwritten,
    noting_unwritten,
    publishing,
    raise_if_lost,
    unwritten_target,
    written_target,
)

REPO = Path(__file__).resolve().parents[1]
SHEET = REPO / "samples" / "meshes" / "sheet.obj"
#: seconds a test waits for a run to reach the point where it is interrupted / for a process to end;
#: a signal that lands while Numba compiles (the substep picker's parallel build compiles on its
#: first trial, mid-run, with an empty cache: 10-20 s on a loaded 2-core CI runner) is handled when
#: the compiler returns, so the end may take that long
START_TIMEOUT = 60.0
END_TIMEOUT = 45.0


def meshdeform(*args: object, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    """The `meshdeform` command in a subprocess (stderr captured), from this checkout; `env` adds
    to the environment."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONFAULTHANDLER": "1", **(env or {})}
    command = [sys.executable, "-c", "from pipeline.cli import app; app()", *map(str, args)]
    return subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def wait_for(condition, what: str, process: subprocess.Popen[str]) -> None:
    deadline = time.monotonic() + START_TIMEOUT
    while not condition():
        if process.poll() is not None:
            raise AssertionError(f"the process ended before {what}: {process.stderr.read() if process.stderr else ''}")
        if time.monotonic() > deadline:
            process.kill()
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def staging_folders(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if ".partial-" in p.name or ".old-" in p.name]


def stages_writing(root: Path) -> int:
    """Staging folders under `root` that hold a first frame: their kernels are compiled and they are
    simulating (a signal during a cold compile waits for the compiler to return)."""
    return sum(1 for stage in staging_folders(root) if stage.is_dir() and any(stage.glob("frames/*.obj")))


def writing_frames(root: Path) -> bool:
    return stages_writing(root) > 0


def finish(process: subprocess.Popen[str]) -> list[str]:
    """Wait (bounded) for the process to end; returns its stderr lines."""
    try:
        _, stderr = process.communicate(timeout=END_TIMEOUT)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGABRT)  # faulthandler prints where every thread is
        _, stderr = process.communicate()
        raise AssertionError(f"the process did not end within {END_TIMEOUT} s of the signal:\n{stderr}") from None
    return stderr.splitlines()


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_simulate_interrupted_leaves_nothing_and_says_one_line(tmp_path: Path, signum: signal.Signals) -> None:
    out = tmp_path / "out" / "x"
    process = meshdeform("simulate", SHEET, "-o", out, "--frames", 100000, "-q")
    wait_for(lambda: writing_frames(tmp_path), "the run writes its frames", process)
    process.send_signal(signum)
    lines = finish(process)
    assert process.returncode == 128 + signum.value
    assert lines == [f"error: interrupted by {signum.name}; nothing was written to {out}"], lines
    assert not staging_folders(tmp_path)
    assert not out.exists()


def test_simulate_interrupt_keeps_the_previous_output(tmp_path: Path) -> None:
    """The folder of an earlier run stays as it was: the interrupted run never replaced it."""
    out = tmp_path / "x"
    earlier = meshdeform("simulate", SHEET, "-o", out, "--frames", 2, "-q")
    _, stderr = earlier.communicate(timeout=START_TIMEOUT)  # (a cold Numba cache compiles first)
    assert earlier.returncode == 0 and not stderr, stderr
    before = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    process = meshdeform("simulate", SHEET, "-o", out, "--frames", 100000, "-q")
    wait_for(lambda: writing_frames(tmp_path), "the run writes its frames", process)
    process.send_signal(signal.SIGTERM)
    finish(process)
    assert process.returncode == 143
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x"]
    assert {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} == before


def slow_assets(tmp_path: Path, count: int, frames: int) -> tuple[Path, Path]:
    """`count` copies of the sample sheet and a recipe of `frames` frames."""
    assets = tmp_path / "assets"
    assets.mkdir()
    for i in range(count):
        shutil.copyfile(SHEET, assets / f"sheet{i}.obj")
    recipe = tmp_path / "recipe.toml"
    recipe.write_text(f'[simulation]\nsolver = "verlet"\nframes = {frames}\n[output]\nformats = ["obj"]\n')
    return assets, recipe


def batch_with_two_jobs_running(
    tmp_path: Path, count: int, frames: int
) -> tuple[subprocess.Popen[str], Path, list[int]]:
    """`meshdeform batch -j 2` over `slow_assets(tmp_path, count, frames)`, once both workers write
    frames: the batch process, its output folder and its workers' pids."""
    assets, recipe = slow_assets(tmp_path, count, frames)
    out = tmp_path / "out"
    process = meshdeform("batch", assets, "-r", recipe, "-o", out, "-j", 2, "-q")
    wait_for(lambda: out.is_dir() and stages_writing(out) == 2, "two jobs running", process)
    return process, out, children(process.pid)


def asset_folders(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if p.is_dir() and not p.name.startswith("."))


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_batch_interrupted_stops_its_workers_and_leaves_no_staging(tmp_path: Path, signum: signal.Signals) -> None:
    """The signal goes to the batch process alone (as `kill PID` does): it stops its workers,
    removes their staging folders, writes its manifest and says so in one line."""
    process, out, workers = batch_with_two_jobs_running(tmp_path, 3, 100000)
    assert len(workers) >= 2
    process.send_signal(signum)
    lines = finish(process)
    assert process.returncode == 128 + signum.value
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"error: interrupted by {signum.name}; finished assets are kept"), lines
    assert not staging_folders(out)
    assert asset_folders(out) == []
    assert all(gone(pid) for pid in workers)


def children(pid: int) -> list[int]:
    """Pids of the pool workers of process `pid` (from /proc: psutil is not needed)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            command = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        parent = int(stat.rsplit(")", 1)[1].split()[1])
        if parent == pid and b"spawn_main" in command:
            found.append(int(entry.name))
    return found


def gone(pid: int) -> bool:
    """The process has ended: no such pid, or a zombie not yet reaped by whoever adopted it."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return state in ("Z", "X")


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="reads worker processes from /proc (Linux)")
def test_workers_die_with_a_killed_batch_and_never_publish(tmp_path: Path) -> None:
    """kill -9 of the batch process alone: its workers end within seconds, and no asset folder
    appears afterwards, although their jobs would have finished (a job here takes ~1-3 s)."""
    process, out, workers = batch_with_two_jobs_running(tmp_path, 2, 1500)
    assert len(workers) == 2
    before = asset_folders(out)
    process.kill()
    process.communicate(timeout=END_TIMEOUT)
    deadline = time.monotonic() + 5.0
    while not all(gone(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert all(gone(pid) for pid in workers), "pool workers outlived their batch process"
    time.sleep(4.0)  # longer than the jobs had left to run
    assert asset_folders(out) == before == []


def test_a_worker_whose_parent_is_already_gone_exits_at_once(tmp_path: Path) -> None:
    """A worker started for a parent that has died (its pid is not its parent's) exits at once."""
    code = "import os; from pipeline.interrupts import watch_parent; watch_parent(os.getppid() + 1); print('alive')"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=END_TIMEOUT)
    assert done.returncode == 143 and done.stdout == "" and done.stderr == ""


# -- in this process: the handlers themselves ---------------------------------------------------


def test_a_signal_raises_interrupted_with_the_conventional_exit_code() -> None:
    with handling_signals(), pytest.raises(Interrupted) as raised:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1.0)  # the handler runs at the next bytecode
    assert raised.value.signum == signal.SIGTERM and raised.value.exit_code == 143
    assert str(raised.value) == "interrupted by SIGTERM"


def test_a_signal_inside_publishing_waits_for_its_end() -> None:
    steps = []
    with handling_signals(), pytest.raises(Interrupted) as raised:
        with publishing():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            steps.append("renamed")
        steps.append("after")
    assert steps == ["renamed"] and raised.value.exit_code == 130


def test_a_signal_while_numba_holds_its_compiler_lock_waits_for_the_release() -> None:
    """A signal while the main thread loads, compiles or saves a kernel (Numba's compiler lock,
    nested as a kernel compiles its callees) is raised once the outermost hold is released:
    raised inside, it left llvmlite's half-built objects behind, and an interrupted cold-cache run
    failed with "no compiled object yet" or crashed on its way out (SIGSEGV, in CI)."""
    from numba.core.compiler_lock import global_compiler_lock

    steps = []
    with handling_signals(), pytest.raises(Interrupted) as raised:
        with global_compiler_lock:
            with global_compiler_lock:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(0.05)  # the handler runs at the next bytecode
                steps.append("compiled")
            time.sleep(0.05)
            steps.append("saved")
        steps.append("after")
    assert steps == ["compiled", "saved"] and raised.value.exit_code == 143


def test_a_cold_cache_run_interrupted_while_it_compiles_ends_with_its_one_line(tmp_path: Path) -> None:
    """With an empty kernel cache the run compiles for seconds before its first frame; a signal
    then ends it as any other (once the compiler lets go), never with an error or a crash."""
    out = tmp_path / "out" / "x"
    cache = {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    process = meshdeform("simulate", SHEET, "-o", out, "--frames", 100000, "-q", env=cache)
    wait_for(lambda: any((tmp_path / "cache").rglob("*.nbi")), "the run compiles kernels into its cache", process)
    process.send_signal(signal.SIGTERM)
    lines = finish(process)
    assert process.returncode == 143, lines
    assert lines == [f"error: interrupted by SIGTERM; nothing was written to {out}"], lines
    assert not out.exists()


def test_signals_during_the_cleanup_of_an_interrupt_are_ignored() -> None:
    cleaned = False
    with handling_signals():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)
        except Interrupted:
            os.kill(os.getpid(), signal.SIGTERM)  # a second `kill` while cleaning up
            time.sleep(0.05)
            cleaned = True
    assert cleaned


def test_an_interrupt_swallowed_by_a_finalizer_is_raised_again_by_the_run_loop() -> None:
    """A signal handled while a `__del__` runs raises there; Python reports it as unraisable and goes
    on (what left a CI run writing frames after SIGHUP). The run loop's check raises it again."""

    class SignalsOnCollection:
        def __del__(self) -> None:
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.2)  # the handler runs inside this finalizer

    previous_hook = sys.unraisablehook
    with handling_signals():
        try:
            SignalsOnCollection()  # collected at once: the Interrupted is lost in __del__
            reached_the_loop = True
            with pytest.raises(Interrupted) as raised:
                raise_if_lost()
        finally:
            sys.unraisablehook = previous_hook
    assert reached_the_loop and raised.value.signum == signal.SIGHUP
    raise_if_lost()  # outside the block nothing is pending


def test_handlers_are_restored_after_the_block() -> None:
    before = signal.getsignal(signal.SIGTERM)
    with handling_signals():
        assert signal.getsignal(signal.SIGTERM) is not before
    assert signal.getsignal(signal.SIGTERM) is before


def test_interrupted_travels_between_processes() -> None:
    import pickle

    copy = pickle.loads(pickle.dumps(Interrupted(signal.SIGHUP)))
    assert isinstance(copy, KeyboardInterrupt) and copy.exit_code == 129


def test_the_unwritten_folder_is_noted_only_where_someone_listens(tmp_path: Path) -> None:
    error, other = OSError("disk full"), OSError("disk full")
    note_unwritten(error, tmp_path / "ignored")  # no `noting_unwritten` block: nobody listens
    with noting_unwritten():
        assert unwritten_target(error) is None
        note_unwritten(error, tmp_path / "out")
        note_unwritten(error, tmp_path / "later")  # the first folder noted stays
        with noting_unwritten():  # an inner block (a batch job) keeps its own notes
            note_unwritten(other, tmp_path / "job")
            assert unwritten_target(other) == tmp_path / "job" and unwritten_target(error) is None
        assert unwritten_target(error) == tmp_path / "out" and unwritten_target(other) is None
    assert unwritten_target(error) is None


def test_an_error_before_the_staging_folder_names_the_output_not_written(tmp_path: Path) -> None:
    """A job that stops before its staging folder exists (reading the mesh, building the model,
    compiling kernels: where a cold-cache run spends its first seconds) still names the folder
    it did not write, for the CLI's line."""
    from meshdeform.errors import MeshLoadError
    from pipeline.job import run_job
    from pipeline.recipe import load_recipe

    broken = tmp_path / "broken.obj"
    broken.write_text("v 0 0 0\nf 1 2 3\n")
    out = tmp_path / "out" / "x"
    with noting_unwritten():
        with pytest.raises(MeshLoadError) as raised:
            run_job(broken, load_recipe(None), out)
        assert unwritten_target(raised.value) == out and written_target(raised.value) is None
    assert not out.exists()


def test_a_signal_that_waited_for_the_renames_says_the_folder_was_written(tmp_path: Path, monkeypatch) -> None:
    """A signal during the renames is delivered once the folder is in place: the line then says
    it was written in full, never that nothing was."""
    import pipeline.output_folder as output_folder
    from pipeline.commands.errors import interrupted_message

    commit = output_folder._commit

    def commit_with_a_signal(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)  # the handler runs at the next bytecode, and waits for the block's end
        return commit(*args, **kwargs)

    monkeypatch.setattr(output_folder, "_commit", commit_with_a_signal)
    out = tmp_path / "out"
    with handling_signals(), noting_unwritten():
        with pytest.raises(Interrupted) as raised, output_folder.staged_directory(out) as stage:
            (stage / "a.txt").write_text("a")
        assert written_target(raised.value) == out and unwritten_target(raised.value) is None
        assert interrupted_message(raised.value) == f"interrupted by SIGTERM; {out} had been written in full"
    assert (out / "a.txt").read_text() == "a"
