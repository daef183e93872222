"""Output folders meshdeform may write, and how it writes them without losing anyone's files.

Every folder meshdeform writes carries MARKER_NAME (`.meshdeform.json`), listing the files it wrote. An
existing folder is replaced whole only when it is such a result and holds nothing else; any other
non-empty folder is refused up front (`check_output_folder`), or (overwrite) written into file by file,
keeping every file meshdeform did not write (`_merge`). A run writes into a staging folder beside the
target that takes its place only when the run succeeded (`staged_directory`); `output_lock` keeps two
runs off one folder. docs/batch.md, "Output folders".
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import shutil
import stat
import uuid
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from meshdeform.atomic import write_text_atomic
from meshdeform.errors import MeshdeformError
from pipeline import __version__
from pipeline.hashing import file_sha256
from pipeline.interrupts import note_unwritten, note_written, publishing

#: the job's report in every result folder (a marker of its own for results older than MARKER_NAME)
REPORT_NAME = "report.json"
#: the stamp in every folder meshdeform writes: {"tool", "version", "files": [what it wrote, relative]}
MARKER_NAME = ".meshdeform.json"
#: staging folders of `staged_directory` beside their target NAME: `.NAME.partial-meshdeform-<32 hex>` and
#: `.NAME.old-meshdeform-<32 hex>` (no name a person picks: only these are ever removed as leftovers)
STAGE_PATTERN = re.compile(r"^\.(?P<target>.+)\.(?P<kind>partial|old)-meshdeform-[0-9a-f]{32}$")
#: `output_lock` holds `.NAME` + this beside the target while a run writes it
LOCK_SUFFIX = ".meshdeform.lock"


def stage_path(target: Path, kind: str = "partial") -> Path:
    """A fresh staging ("partial") or set-aside ("old") folder name beside `target` (STAGE_PATTERN)."""
    return target.parent / f".{target.name}.{kind}-meshdeform-{uuid.uuid4().hex}"


def is_stage_of(name: str, target_name: str) -> bool:
    """Is `name` a staging or set-aside folder of the output folder named `target_name`?"""
    match = STAGE_PATTERN.match(name)
    return match is not None and match.group("target") == target_name


class OutputFolderError(MeshdeformError):
    """meshdeform will not write this output folder: it would replace or mix with files it did not write."""


@dataclass(frozen=True)
class FolderState:
    """What an output path holds now.

    path: the folder, symlinks resolved (where meshdeform would write).
    kind: "absent", "not_dir" (a file or other non-folder), "empty" (nothing, or only meshdeform's
        staging leftovers), "result" (a previous meshdeform result and nothing else), "mixed" (a previous
        result plus entries meshdeform did not write) or "foreign" (non-empty, no meshdeform marker).
    listed: the files the previous result's marker lists (empty unless it has one).
    foreign: what meshdeform did not write: relative POSIX paths ("mixed") or the top-level names ("foreign").
    """

    path: Path
    kind: str
    listed: frozenset[str] = frozenset()
    foreign: tuple[str, ...] = ()


# -- the marker --------------------------------------------------------------------------------


def _is_safe_relative(name: str) -> bool:
    """A marker entry meshdeform could have written: a plain relative POSIX path inside the folder."""
    pure = PurePosixPath(name)
    return bool(name) and not pure.is_absolute() and ".." not in pure.parts and "\\" not in name and str(pure) == name


def read_marker(folder: Path) -> frozenset[str] | None:
    """The files a previous meshdeform run wrote into `folder` (its MARKER_NAME), or None when it has none.

    Folders written before the marker existed are recognised by their report.json ("tool": "meshdeform"
    and its "outputs" list). A marker entry that leaves the folder ("..", absolute) makes it no marker.
    """
    for name, key in ((MARKER_NAME, "files"), (REPORT_NAME, "outputs")):
        try:
            data = json.loads((folder / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        files = data.get(key) if isinstance(data, dict) and data.get("tool") == "meshdeform" else None
        if isinstance(files, list) and all(isinstance(f, str) and _is_safe_relative(f) for f in files):
            return frozenset(files) | ({REPORT_NAME} if name == REPORT_NAME else frozenset())
    return None


def _files_under(folder: Path) -> list[str]:
    """Relative POSIX paths of the files under `folder`, sorted."""
    found = []
    for here, _dirs, files in os.walk(folder):
        base = Path(here).relative_to(folder).as_posix()
        found += [name if base == "." else f"{base}/{name}" for name in files]
    return sorted(found)


@dataclass(frozen=True)
class FileRecord:
    """What a marker vouches for one file meshdeform wrote: its size in bytes and the hex sha256 of
    its bytes (None in markers written before digests were kept: the size alone then)."""

    size: int
    sha256: str | None


@functools.lru_cache(maxsize=1 << 16)
def _sha256_of(path: str, identity: tuple[int, int, int, int]) -> str:
    """sha256 of the file at `path` whose stat is `identity` (device, inode, size, mtime in ns): one
    run checks a previous result up to five times (the command, the job, the staging, the commit,
    the merge) and stamps the files it staged twice; each file is read once while it stays as it was
    (an edit in place changes its mtime, a replacement its inode)."""
    return file_sha256(path)


def _sha256(path: Path, info: os.stat_result) -> str:
    """sha256 of the plain file at `path`, whose lstat is `info` (`_sha256_of`)."""
    return _sha256_of(str(path), (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns))


def file_records(root: Path, files: Sequence[str]) -> dict[str, FileRecord]:
    """Size and sha256 of the `files` (relative POSIX) that are plain files under `root`."""
    records: dict[str, FileRecord] = {}
    for name in files:
        with contextlib.suppress(OSError):
            info = os.lstat(root / name)
            if stat.S_ISREG(info.st_mode):
                records[name] = FileRecord(info.st_size, _sha256(root / name, info))
    return records


def write_marker(folder: Path, files: Sequence[str], records: Mapping[str, FileRecord] | None = None) -> None:
    """Write MARKER_NAME: tool, version, the files meshdeform wrote into `folder`, their sizes in bytes and
    the sha256 of their bytes (`records`, else read from `folder`), so a listed file the user changed
    since, even to the same size, is not taken for meshdeform's. Deterministic: the same outputs give
    the same bytes (no times)."""
    listed = sorted(set(files) - {MARKER_NAME})
    records = file_records(folder, listed) if records is None else records
    # (not report.json's: its timings change it from run to run, and the marker stays the same bytes)
    vouched = [name for name in listed if name in records and name != REPORT_NAME]
    stamp = {
        "tool": "meshdeform",
        "version": __version__,
        "files": listed,
        "sizes": {name: records[name].size for name in vouched},
        "sha256": {name: records[name].sha256 for name in vouched if records[name].sha256 is not None},
    }
    write_text_atomic(folder / MARKER_NAME, json.dumps(stamp, indent=2) + "\n")


def marker_records(folder: Path) -> dict[str, FileRecord]:
    """What `write_marker` recorded in `folder`'s marker ({} for none, or for a marker without sizes)."""
    try:
        data = json.loads((folder / MARKER_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    sizes = data.get("sizes") if isinstance(data, dict) else None
    if not isinstance(sizes, dict):
        return {}
    digests = data.get("sha256")
    digests = digests if isinstance(digests, dict) else {}
    return {
        name: FileRecord(size, digest if isinstance(digest := digests.get(name), str) else None)
        for name, size in sizes.items()
        if isinstance(name, str) and isinstance(size, int) and _is_safe_relative(name)
    }


def _still_as_written(path: Path, record: FileRecord) -> bool:
    """Is the file at `path` (present) still a plain file of the recorded size and bytes?"""
    try:
        info = os.lstat(path)
        if not stat.S_ISREG(info.st_mode) or info.st_size != record.size:
            return False
        return record.sha256 is None or _sha256(path, info) == record.sha256
    except OSError:  # unreadable: not vouched for
        return False


def _changed_since_written(folder: Path) -> list[str]:
    """Listed files that are no longer what the marker recorded (another size, other bytes, no longer
    a plain file): the user changed them, and they are the user's now. Files gone are not listed."""
    return sorted(
        name
        for name, record in marker_records(folder).items()
        if os.path.lexists(folder / name) and not _still_as_written(folder / name, record)
    )


# -- what is at a path -------------------------------------------------------------------------


def _own_leftover(name: str) -> bool:
    """Names meshdeform leaves only when a run was killed: staging folders, lock files (in the folder
    that holds output folders, never deeper)."""
    return bool(STAGE_PATTERN.match(name)) or (name.startswith(".") and name.endswith(LOCK_SUFFIX))


def _foreign_in_result(folder: Path, listed: frozenset[str]) -> list[str]:
    """Entries of a result folder meshdeform did not write: files (or symlinks, never meshdeform's) that
    neither its marker nor `meshdeform preview` account for, and empty folders no listed file needs."""
    needed = {str(parent) for name in listed for parent in PurePosixPath(name).parents} - {"."}
    foreign: list[str] = []
    for here, dirs, files in os.walk(folder):  # symlinked folders are listed, never entered
        base = Path(here).relative_to(folder).as_posix()
        prefix = "" if base == "." else base + "/"
        for name in list(dirs):
            if not prefix and _own_leftover(name):
                dirs.remove(name)
            elif os.path.islink(os.path.join(here, name)):
                foreign.append(prefix + name)
                dirs.remove(name)
        if not dirs and not files and prefix and base not in needed:
            foreign.append(prefix)  # an empty folder the result does not have
        for name in files:
            rel = prefix + name
            own = rel in listed or rel == MARKER_NAME or (not prefix and _own_leftover(name))
            if not own or os.path.islink(os.path.join(here, name)):
                foreign.append(rel)
    return sorted(foreign)


def inspect_folder(target: Path) -> FolderState:
    """Classify what is at `target` (see FolderState); reads only."""
    path = Path(os.path.realpath(target))
    if not os.path.lexists(path):
        return FolderState(path, "absent")
    if not path.is_dir():
        return FolderState(path, "not_dir")
    names = sorted(name for name in os.listdir(path) if not _own_leftover(name))
    if not names:
        return FolderState(path, "empty")
    listed = read_marker(path)
    if listed is None:
        return FolderState(path, "foreign", foreign=tuple(names))
    foreign = sorted({*_foreign_in_result(path, listed), *_changed_since_written(path)})
    return FolderState(path, "mixed" if foreign else "result", listed, tuple(foreign))


# -- may it be written -------------------------------------------------------------------------


def entry_count(count: int) -> str:
    """`count` folder entries in words ("1 entry", "3 entries"), for the refusals' lines."""
    return f"{count} entr{'y' if count == 1 else 'ies'}"


def _resolved(target: Path, label: str) -> Path:
    """`target` with symlinks resolved; a symlink to a missing path is refused (OutputFolderError)."""
    if os.path.islink(target) and not os.path.exists(target):
        raise OutputFolderError(f"{label}: is a symbolic link to a missing path; choose another --out")
    return Path(os.path.realpath(target))


def holds_folder_of(real: Path, what: str, path: Path | str) -> str | None:
    """Why the folder `real` (symlinks resolved) may not be written for the file `path` (a `what`:
    "input", "recipe"): "is the folder of" or "contains" the file's folder, found by the file's own path
    or the one it links to ("..", trailing slashes resolved); None when it holds neither."""
    folders = {Path(os.path.realpath(Path(os.path.abspath(path)).parent)), Path(os.path.realpath(path)).parent}
    for folder in sorted(folders):
        if folder.is_relative_to(real):
            where = "is the folder of" if folder == real else "contains"
            return f"{where} the {what} {path}"
    return None


def linked_part(base: Path, relative: str) -> str | None:
    """The first part of `relative` (a POSIX path inside the folder `base`) that is a symbolic link,
    as a relative POSIX path; None when none is (parts that do not exist yet are none). A batch writes
    its asset folders only inside its OUT: a link there would take the outputs elsewhere."""
    parts = PurePosixPath(relative).parts
    for depth in range(1, len(parts) + 1):
        if os.path.islink(base.joinpath(*parts[:depth])):
            return "/".join(parts[:depth])
    return None


def refusal(label: str, state: FolderState, overwrite: bool) -> str | None:
    """Why meshdeform will not write `state` (None: it may), as one line starting with `label`."""
    if state.kind == "not_dir":
        return f"{label}: exists and is not a folder; choose another --out"
    if overwrite:
        return None
    if state.kind == "foreign":
        return (
            f"{label}: folder exists and is not a meshdeform result ({entry_count(len(state.foreign))}, "
            f"e.g. {state.foreign[0]!r}); choose another --out or pass --overwrite"
        )
    if state.kind == "mixed":
        return (
            f"{label}: folder holds a meshdeform result and {entry_count(len(state.foreign))} meshdeform did not "
            f"write (e.g. {state.foreign[0]!r}); choose another --out or pass --overwrite to keep them"
        )
    return None


def check_output_folder(
    target: Path,
    *,
    overwrite: bool = False,
    protect: Mapping[str, Path | str | None] | None = None,
    refuse_cwd: bool = False,
    label: str | None = None,
) -> FolderState:
    """Refuse, before anything is read or written, an output folder meshdeform must not write.

    Refused (OutputFolderError, one line naming `label` or the path, and why): a file system root; with
    `refuse_cwd` the current folder or a folder containing it; the folder of any file in `protect`
    ({"input": mesh, "recipe": toml}) or a folder containing it (symlinks, "..", trailing slashes resolved,
    for the file's own path and the one it links to); an existing non-folder, or a path below one; and,
    unless `overwrite`, a non-empty folder that is not a previous meshdeform result alone. Returns what
    is at the target.
    """
    label = label or str(target)
    real = _resolved(target, label)
    if real.parent == real:
        raise OutputFolderError(f"{label}: is a file system root; choose a folder of its own for --out")
    if refuse_cwd:
        cwd = Path(os.path.realpath(os.getcwd()))
        if cwd.is_relative_to(real):
            where = "is" if cwd == real else "contains"
            raise OutputFolderError(f"{label}: {where} the current folder; choose a folder of its own for --out")
    for what, path in (protect or {}).items():
        if path is not None and (clash := holds_folder_of(real, what, path)) is not None:
            raise OutputFolderError(f"{label}: {clash}; choose another --out")
    above = real.parent
    while not os.path.lexists(above):
        above = above.parent
    if not above.is_dir():
        raise OutputFolderError(f"{label}: {above} exists and is not a folder; choose another --out")
    state = inspect_folder(real)
    message = refusal(label, state, overwrite)
    if message:
        raise OutputFolderError(message)
    return state


# -- locks -------------------------------------------------------------------------------------


def _make_folders(folder: Path, label: str) -> list[Path]:
    """Create `folder` and its missing parents; return those created, outermost first."""
    missing: list[Path] = []
    probe = folder
    while not os.path.lexists(probe) and probe.parent != probe:
        missing.append(probe)
        probe = probe.parent
    for path in reversed(missing):
        try:
            path.mkdir()
        except FileExistsError:
            continue
        except OSError as exc:
            raise OutputFolderError(f"{label}: cannot create the folder {path}: {exc.strerror or exc}") from None
    return list(reversed(missing))


def _remove_if_empty(folders: Sequence[Path]) -> None:
    """Remove folders created for a run that wrote nothing into them (innermost first)."""
    for path in reversed(folders):
        with contextlib.suppress(OSError):
            path.rmdir()


@contextlib.contextmanager
def exclusive_lock(path: Path, label: str, busy: str, error: type[MeshdeformError]) -> Iterator[None]:
    """Hold the file lock `path` (filelock: every OS) for the block. A second holder is refused at once
    with `error("label: busy")`; a lock file that cannot be made with `error` naming it (one line each)."""
    from filelock import FileLock, Timeout

    lock = FileLock(path, timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise error(f"{label}: {busy}") from None
    except OSError as exc:
        raise error(f"{label}: cannot create the lock file {path}: {exc.strerror or exc}") from None
    try:
        yield
    finally:
        lock.release()


def remove_stale_stages(target: Path) -> None:
    """Delete the staging and set-aside folders killed runs left beside the output folder `target`
    (`is_stage_of`: names no person picks). Only safe while no run writes `target`: under
    `output_lock`, or in a batch's job under the batch's lock."""
    parent = target.parent
    if not parent.is_dir():
        return
    for name in os.listdir(parent):
        if is_stage_of(name, target.name):
            shutil.rmtree(parent / name, ignore_errors=True)


@contextlib.contextmanager
def output_lock(target: Path, label: str | None = None) -> Iterator[None]:
    """Hold `<parent>/.<name>.meshdeform.lock` while one run writes `target` (`exclusive_lock`).

    A second run on the same folder is refused at once (OutputFolderError). The lock sits beside the
    target because the target itself is replaced; it is deleted while still held, so nothing stays
    behind (filelock >= 4.3 retries when the file it locked was unlinked meanwhile). Once it is held,
    the staging folders of killed runs on the target are removed (`remove_stale_stages`). Missing
    parent folders are created, and removed again when the run leaves them empty.
    """
    label = label or str(target)
    real = _resolved(target, label)
    created = _make_folders(real.parent, label)
    path = real.parent / f".{real.name}{LOCK_SUFFIX}"
    try:
        with exclusive_lock(path, label, "another meshdeform run is writing this folder", OutputFolderError):
            remove_stale_stages(real)
            try:
                yield
            finally:
                with contextlib.suppress(OSError):  # Windows: filelock deletes it on release instead
                    path.unlink()
    finally:
        _remove_if_empty(created)


# -- staging, then rename or merge -------------------------------------------------------------


def _blocked(target: Path, relative: str) -> str | None:
    """The part of `relative` under `target` that stops a file being written there without deleting or
    following anything: a parent that is a file or a symlink, or the name itself being a real folder."""
    parts = PurePosixPath(relative).parts
    for depth in range(1, len(parts) + 1):
        path = target.joinpath(*parts[:depth])
        try:
            mode = os.lstat(path).st_mode
        except FileNotFoundError:
            return None
        last = depth == len(parts)
        if (last and stat.S_ISDIR(mode)) or (not last and not stat.S_ISDIR(mode)):
            return "/".join(parts[:depth])
    return None


def _remove_own_file(target: Path, relative: str) -> None:
    """Delete a file a previous result listed, unless it is no longer a plain file inside real folders."""
    if _blocked(target, relative) is None:
        path = target / relative
        with contextlib.suppress(OSError):
            if stat.S_ISREG(os.lstat(path).st_mode):
                path.unlink()
                for parent in PurePosixPath(relative).parents:  # its folders, if it was their last file
                    if str(parent) == ".":
                        break
                    with contextlib.suppress(OSError):
                        (target / parent).rmdir()


def _merge(stage: Path, target: Path, previous: frozenset[str], label: str) -> None:
    """--overwrite: move the staged files into `target` one by one (os.replace), replacing the previous
    result's files of the same names; remove files of the previous result that were not written again;
    keep everything else.

    Checked before anything moves, each refusing the whole merge: a file whose place is taken by a
    folder, or under a file or a symlink; a file whose name is taken by a file or symlink meshdeform did
    not write, or by one of its files the user changed since (`_changed_since_written`): a user's file is
    never replaced. The merged list is stamped first and the old report removed first, so a merge cut
    short is never taken for a finished result.
    """
    new = _files_under(stage)
    changed = set(_changed_since_written(target))  # listed files the user changed since: theirs now, kept
    for relative in new:
        if (problem := _blocked(target, relative)) is not None:
            raise OutputFolderError(
                f"{label}: cannot write {relative!r} there: {problem!r} is in the way and meshdeform did not "
                "write it; the folder was left as it was"
            )
        if relative == MARKER_NAME or not os.path.lexists(target / relative):
            continue
        if relative not in previous or os.path.islink(target / relative):
            whose = "meshdeform did not write it"
        elif relative in changed:
            whose = "it was changed since meshdeform wrote it"
        else:
            continue
        raise OutputFolderError(
            f"{label}: will not replace {relative!r}: {whose}; move it away or choose another --out "
            "(the folder was left as it was)"
        )
    write_marker(target, [*previous, *new], {**marker_records(target), **file_records(stage, new)})
    if REPORT_NAME in previous:
        _remove_own_file(target, REPORT_NAME)
    last = (REPORT_NAME, MARKER_NAME)

    def move(relative: str) -> None:
        destination = target / relative
        destination.parent.mkdir(parents=True, exist_ok=True)
        os.replace(stage / relative, destination)

    for relative in new:
        if relative not in last:
            move(relative)
    for old in sorted(previous - set(new) - changed):
        _remove_own_file(target, old)
    for relative in last:
        if relative in new:
            move(relative)
    shutil.rmtree(stage, ignore_errors=True)  # only empty folders are left in it


def _commit(stage: Path, target: Path, label: str, overwrite: bool) -> None:
    """Put the finished stage in place of `target` (checked again: the folder may have changed meanwhile)."""
    state = inspect_folder(target)
    if state.kind == "absent":
        os.replace(stage, target)
    elif state.kind in ("empty", "result"):
        old = stage_path(target, "old")
        os.replace(target, old)
        os.replace(stage, target)
        shutil.rmtree(old, ignore_errors=True)
    elif overwrite and state.kind != "not_dir":
        _merge(stage, target, state.listed, label)
    else:
        raise OutputFolderError(refusal(label, state, overwrite) or f"{label}: cannot be written")


@contextlib.contextmanager
def staged_directory(target: Path, *, overwrite: bool = False) -> Iterator[Path]:
    """Yield an empty staging folder beside `target`; on success it takes the target's place, with a
    MARKER_NAME listing its files; on failure it is removed and the target is left as it was.

    The target is refused up front unless it is absent, empty or a previous meshdeform result alone
    (`refusal`); with `overwrite` the staged files are moved into it one by one instead (`_merge`), and
    every file meshdeform did not write is kept. A symlinked target is written where it points.
    """
    label = str(target)
    state = check_output_folder(target, overwrite=overwrite, label=label)
    real = state.path
    created = _make_folders(real.parent, label)
    stage = stage_path(real)
    try:
        stage.mkdir()
    except OSError as exc:
        _remove_if_empty(created)
        raise OutputFolderError(
            f"{label}: cannot create a staging folder in {real.parent}: {exc.strerror or exc}"
        ) from None
    committed = False
    try:
        yield stage
        write_marker(stage, _files_under(stage))
        with publishing(stage):  # a signal waits for the renames; a pool worker whose batch died stops here
            _commit(stage, real, label, overwrite)
            committed = True
    except BaseException as exc:
        if committed:  # a signal that waited for the renames: the folder is in place, in full
            note_written(exc, target)
            raise
        shutil.rmtree(stage, ignore_errors=True)
        _remove_if_empty(created)
        note_unwritten(exc, target)  # the CLI's one line names the folder that was not written
        raise
