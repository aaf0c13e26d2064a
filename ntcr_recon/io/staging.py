"""An output directory written whole or not at all: built beside its target, then swapped in by one rename.

    with staged_directory(Path("out/run1")) as staging:   # staging: out/.run1.partial-<pid>-<random>/
        write files into staging ...
    # no exception: out/run1 now holds exactly those files; an exception: out/run1 is as it was

Why beside the target: a rename is atomic only within one file system, and a staging directory in /tmp
would end in "Invalid cross-device link". The swap: on Linux, renameat2(RENAME_EXCHANGE) exchanges the new
directory with the old one in one step, so a reader opening the target sees the old result or the new one,
never a mix nor nothing; the old one, now in the staging place, is removed afterwards. Where the exchange is
not available (another OS, a file system without it), the old directory is renamed aside, the new one in,
and the old removed: a reader may then find no directory for that instant, but never a mix, and a failure
between the two renames puts the old one back. A plain directory rather than a symlink swap, so the result
stays an ordinary directory that tools copy and archive as one.

Staging directories of runs that were killed (their process is gone) are removed when the next run starts;
those of a run still going are left alone.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

STAGING_INFIX = ".partial-"   # .<target name>.partial-<pid>-<random>
PREVIOUS_INFIX = ".previous-"  # .<target name>.previous-<pid>-<random>: the old result, moved aside

# Held while a result is swapped in: the CLI's Ctrl-C handling (cli/__init__) waits for it before it ends the
# process, so an interrupted run leaves the old result or the new one in place, never neither.
SWAP_LOCK = threading.Lock()
_ACTIVE: set[Path] = set()  # this process's staging directories, for remove_active_staging
_PREFIXES: set[Path] = set()  # where they are made (parent / name prefix), registered before mkdtemp makes one

# Tries at removing a staging directory the main thread is still writing into (remove_active_staging).
REMOVAL_ATTEMPTS = 20
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


class StagingError(OSError):
    """The target cannot be written whole (a mount point, not a directory, another file system...)."""


@contextlib.contextmanager
def staged_directory(target: str | os.PathLike, *, created_by_writer: bool = False) -> Iterator[Path]:
    """A fresh staging directory beside `target`; swapped in as `target` when the block ends normally,
    removed when it raises (the target untouched).

    created_by_writer: yield instead a path named like the target that does not exist yet, inside the
    staging directory, for a writer that creates its own directory and names its files after it (rosbags).
    """
    target = _checked_target(target)
    try:  # said of the target, before any work: not "Permission denied: .../.out.partial-1234-x" at the end
        target.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_staging(target)
        prefix = f".{target.name}{STAGING_INFIX}{os.getpid()}-"
        _PREFIXES.add(target.parent / prefix)  # a Ctrl-C between mkdtemp and _ACTIVE.add finds it by its name
        staging = Path(tempfile.mkdtemp(dir=target.parent, prefix=prefix))
    except OSError as error:
        refusal = StagingError(f"{target} cannot be written: {error.strerror or error} in {target.parent}")
        refusal.errno = error.errno
        raise refusal from error
    result = staging / target.name if created_by_writer else staging
    _ACTIVE.add(staging)
    try:
        if target.exists() and os.stat(target).st_dev != os.stat(staging).st_dev:
            raise StagingError(f"{target} is on another file system than its parent directory "
                               "(a mount point?): give a directory inside it")
        yield result
        if not result.is_dir():
            raise StagingError(f"nothing was written for {target}")
        result.chmod(0o755)  # mkdtemp makes it private; the result is an ordinary directory
        # Ctrl-C / SIGTERM wait until the swap is done (its fallback's two renames must not be parted)
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            with SWAP_LOCK:
                swap_in(result, target)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
    finally:
        shutil.rmtree(staging, ignore_errors=True)  # the new result on failure, the old one after a swap
        _ACTIVE.discard(staging)


def remove_active_staging() -> None:
    """Remove this process's staging directories (a process ending on Ctrl-C: its targets stay as they were). The
    main thread may still be writing into one (a figure, a mesh): a file it adds while the tree is removed leaves
    the directory standing, so the removal is tried again until it is gone."""
    found = set(_ACTIVE)
    for prefix in list(_PREFIXES):
        found.update(prefix.parent.glob(_glob_escape(prefix.name) + "*"))
    for staging in found:
        for _ in range(REMOVAL_ATTEMPTS):
            shutil.rmtree(staging, ignore_errors=True)
            if not os.path.lexists(staging):
                break


def _checked_target(target: str | os.PathLike) -> Path:
    text = os.fspath(target)
    if not text.strip():
        raise StagingError("the output directory is empty: name a directory")
    path = Path(os.path.abspath(text))  # not resolve(): a symlinked parent stays as the user named it
    if path.parent == path or path == Path(os.path.abspath(os.curdir)):
        raise StagingError(f"the output directory {text!r} is the current or the root directory: "
                           "it is replaced whole, so name a directory of its own")
    if path.exists() and not path.is_dir():
        raise StagingError(f"{text} exists and is not a directory")
    if is_mount_point(path):
        raise StagingError(f"{text} is a mount point: it cannot be replaced by a rename; give a "
                           "directory inside it")
    return path


def is_mount_point(path: Path, mountinfo: str | os.PathLike = "/proc/self/mountinfo") -> bool:
    """os.path.ismount, and (Linux) any mount point the kernel lists: a bind mount of a folder of the same file
    system is none to ismount, and was refused by the final rename only, after the whole computation."""
    if os.path.ismount(path):
        return True
    try:
        lines = Path(mountinfo).read_text().splitlines()
    except OSError:
        return False
    wanted = os.path.realpath(path)
    for line in lines:
        fields = line.split(" ")
        if len(fields) > 4 and _unescape_mount(fields[4]) == wanted:
            return True
    return False


def _unescape_mount(field: str) -> str:
    """A mountinfo path: space, tab, newline and backslash are written as octal escapes (\\040 ...)."""
    return field.encode("latin-1").decode("unicode_escape") if "\\" in field else field


def swap_in(staging: Path, target: Path) -> None:
    """Make `staging` the `target` directory in one step; the old target (if any) ends up at `staging`."""
    if not target.exists():
        os.rename(staging, target)
        return
    if _exchange(staging, target):
        return
    # No atomic exchange here: the old result aside, the new one in, and back if that fails.
    previous = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}{PREVIOUS_INFIX}{os.getpid()}-"))
    os.rmdir(previous)
    os.rename(target, previous)
    try:
        os.rename(staging, target)
    except BaseException:
        os.rename(previous, target)
        raise
    os.rename(previous, staging)  # removed with the staging directory


def _exchange(first: Path, second: Path) -> bool:
    """renameat2(RENAME_EXCHANGE): True when done, False where the system or file system lacks it."""
    renameat2 = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if renameat2 is None:
        return False
    if renameat2(_AT_FDCWD, os.fsencode(first), _AT_FDCWD, os.fsencode(second), _RENAME_EXCHANGE) == 0:
        return True
    error = ctypes.get_errno()
    if error in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(error, f"cannot swap {first} in as {second}: {os.strerror(error)}")


def remove_stale_staging(target: Path) -> list[Path]:
    """Remove the staging (and moved-aside) directories of `target` left by runs whose process is gone."""
    removed = []
    for infix in (STAGING_INFIX, PREVIOUS_INFIX):
        for path in target.parent.glob(f".{_glob_escape(target.name)}{infix}*"):
            pid_text = path.name[len(f".{target.name}{infix}"):].split("-", 1)[0]
            if path.is_dir() and not _process_alive(int(pid_text) if pid_text.isdigit() else None):
                shutil.rmtree(path, ignore_errors=True)
                removed.append(path)
    return removed


def _process_alive(pid: int | None) -> bool:
    if pid is None:  # a name this module did not make in that form (an older version's): stale
        return False
    if pid == os.getpid():
        return False  # an earlier run inside this very process (tests, a library caller) that was interrupted
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def _glob_escape(name: str) -> str:
    return "".join(f"[{c}]" if c in "*?[" else c for c in name)
