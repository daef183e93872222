"""One line means one line: no library chatter on stderr, in error paths (a full disk included)
or not, from the CLI process or from batch workers.

The disk is made full for real: a tmpfs filled while the run writes, when the tests run as root and may mount one,
else a file size limit of 1 KiB (RLIMIT_FSIZE, with SIGXFSZ ignored: writes fail with EFBIG).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from pipeline.cli import app

REPO = Path(__file__).resolve().parents[1]
SHEET = REPO / "samples" / "meshes" / "sheet.obj"
#: a sitecustomize module that makes every run raise a genuine NumPy RuntimeWarning (overflow) as it
#: starts simulating, in the CLI process and in pool workers alike (valid inputs no longer raise any)
WARN_ON_SIMULATE = """
import numpy as np
import meshdeform.simulate as module

_simulate = module.simulate


def simulate(*args, **kwargs):
    np.float64(1e308) * np.float64(10.0)
    yield from _simulate(*args, **kwargs)


module.simulate = simulate
"""
TIMEOUT = 120


def run_cli(
    *args: object, fsize_limit: int | None = None, site: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """The `meshdeform` command in a subprocess; optionally with a file size limit in bytes, and with a
    folder holding a sitecustomize module first on the path."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(str(p) for p in (site, REPO) if p is not None)}

    def limit() -> None:
        import resource

        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (fsize_limit, fsize_limit))

    command = [sys.executable, "-c", "from pipeline.cli import app; app()", *map(str, args)]
    return subprocess.run(
        command,
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
        preexec_fn=limit if fsize_limit is not None else None,
    )


def start_cli(*args: object) -> subprocess.Popen[str]:
    """The `meshdeform` command started in a subprocess (stdout and stderr piped)."""
    command = [sys.executable, "-c", "from pipeline.cli import app; app()", *map(str, args)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen(command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@contextlib.contextmanager
def small_tmpfs(where: Path, size: str) -> Iterator[bool]:
    """Mount a tmpfs of `size` at `where` if this process may (root); yields whether it did."""
    where.mkdir()
    mounted = False
    if os.geteuid() == 0 and shutil.which("mount"):
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
        mounted = done.returncode == 0
    try:
        yield mounted
    finally:
        if mounted:
            subprocess.run(["umount", str(where)], capture_output=True)


def fill_once_staging_appears(disk: Path, process: subprocess.Popen[str]) -> Path:
    """Wait for the run's staging folder on `disk`, then take every free byte with a filler file (the
    run's estimate fitted when it started; the disk becomes full while it writes)."""
    import time

    deadline = time.monotonic() + TIMEOUT
    while not any(p.name.startswith(".x.partial-") for p in disk.iterdir()):
        assert process.poll() is None and time.monotonic() < deadline, "the run ended before writing"
        time.sleep(0.02)
    filler = disk / "filler.bin"
    with contextlib.suppress(OSError), open(filler, "wb", buffering=0) as handle:  # (until ENOSPC)
        while True:
            handle.write(b"\0" * (1 << 16))
    return filler


@pytest.mark.parametrize("output_format", ["obj", "usd", "vtk"])
def test_full_disk_is_one_line_and_leaves_nothing(tmp_path: Path, output_format: str) -> None:
    disk = tmp_path / "disk"
    with small_tmpfs(disk, "64m") as mounted:
        out = disk / "x"
        args = ("simulate", SHEET, "-o", out, "--frames", 200, "-f", output_format, "-q")
        if mounted:
            process = start_cli(*args)
            filler = fill_once_staging_appears(disk, process)
            stdout, stderr = process.communicate(timeout=TIMEOUT)
            done = subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)
        else:
            filler = None
            done = run_cli(*args, fsize_limit=1024)  # (per file: smaller than one frame)
        lines = done.stderr.splitlines()
        assert done.returncode == 2, done.stderr
        assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
        if output_format != "vtk":  # (VTK's writer reports a failure without its reason)
            assert ("no space left on device" if mounted else "file too large") in lines[0]
        assert "Traceback" not in done.stderr
        assert [p for p in disk.iterdir() if p != filler] == []


@pytest.fixture()
def warning_site(tmp_path: Path) -> Path:
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(WARN_ON_SIMULATE)
    return site


def test_numpy_warnings_stay_off_stderr_unless_verbose(tmp_path: Path, warning_site: Path) -> None:
    quiet = run_cli("simulate", SHEET, "-o", tmp_path / "a", "--frames", 2, "-q", site=warning_site)
    assert quiet.returncode == 0 and quiet.stderr == ""
    verbose = run_cli("--verbose", "simulate", SHEET, "-o", tmp_path / "b", "--frames", 2, "-q", site=warning_site)
    assert verbose.returncode == 0 and "RuntimeWarning: overflow" in verbose.stderr


def test_batch_workers_keep_warnings_off_stderr_and_in_the_log(tmp_path: Path, warning_site: Path) -> None:
    assets = tmp_path / "assets"
    assets.mkdir()
    shutil.copyfile(SHEET, assets / "sheet.obj")
    shutil.copyfile(SHEET, assets / "other.obj")
    recipe = tmp_path / "recipe.toml"
    recipe.write_text("[simulation]\nframes = 2\n")
    done = run_cli("batch", assets, "-r", recipe, "-o", tmp_path / "out", "-j", 2, "-q", site=warning_site)
    assert done.returncode == 0 and done.stderr == ""
    log = (tmp_path / "out" / "batch.log").read_text()
    assert "sheet.obj: " in log and "overflow" in log


def test_an_unexpected_error_is_one_line(tmp_path: Path, monkeypatch: Any) -> None:
    """A bug (here: the job raising ValueError) ends with one line and exit 1, not a traceback."""
    import pipeline.job

    def broken_job(*args: Any, **kwargs: Any) -> None:
        raise ValueError("index 7 is out of bounds\nfor axis 0")

    monkeypatch.setattr(pipeline.job, "run_job", broken_job)
    result = CliRunner().invoke(app, ["simulate", str(SHEET), "-o", str(tmp_path / "x"), "-q"])
    assert result.exit_code == 1
    assert result.stderr.splitlines() == [
        "error: unexpected ValueError: index 7 is out of bounds for axis 0 "
        "(a bug: please report it; --verbose shows the traceback)"
    ]
    verbose = CliRunner().invoke(app, ["--verbose", "simulate", str(SHEET), "-o", str(tmp_path / "x"), "-q"])
    assert verbose.exit_code == 1 and "Traceback" in verbose.stderr and "broken_job" in verbose.stderr


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("simulate", SHEET, "-o", "x", "--frames", "ten"), "error: meshdeform simulate: Invalid value for '--frames'"),
        (("simulate", SHEET, "-o", "x", "--bogus"), "error: meshdeform simulate: No such option: --bogus"),
        (("simulate", SHEET), "error: meshdeform simulate: Missing option '--out'"),
        (("check",), "error: meshdeform check: Missing argument 'RECIPE'"),
        (("nosuch",), "error: meshdeform: No such command 'nosuch'"),
    ],
)
def test_usage_errors_are_one_line_with_exit_code_2(args: tuple[object, ...], expected: str) -> None:
    """Click's usage block (usage, hint, blank line, error) becomes one line naming the command."""
    done = run_cli(*args)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [done.stderr.strip()] and done.stderr.startswith(expected), done.stderr
    assert done.stderr.rstrip().endswith("--help)")
