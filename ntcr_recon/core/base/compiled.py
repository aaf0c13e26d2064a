"""The one way the package compiles a kernel: numba's njit with the settings every kernel shares.

Per-point loops over a few thousand points (neighbourhood fits, projections onto the centreline) cost more in
numpy's per-call overhead and temporaries than in arithmetic; compiled, they run at memory speed. Kernels are
cached on disk, so the compilation is paid once per install, not at every start, and never inside the frames:
`ensure_compiled(workload)` runs a workload that calls every kernel (ntcr_recon.sim.warm_up: one rendered
frame pair through the chain) when this version's cache is not complete yet, in one process at a time (a lock
file: the nodes of a graph started together wait for the one that compiles), and `load_cached()` loads the
cached kernels of the modules a process imported, before it subscribes to anything. scripts/setup_env.sh
compiles them at install; a node after a fresh `colcon build` or with an emptied cache at its start, with
one log line.
`nogil`: a node's executor threads and the DDS threads keep running while a kernel works. `error_model="numpy"`:
a division by zero gives inf or nan as the numpy code it replaces did, instead of raising. Single-threaded on
purpose: the graph already runs one process per stage on every core there is.

The cache lives in `$NUMBA_CACHE_DIR` (default `~/.cache/ntcr_recon/numba`) under a digest of the core's
sources: numba re-compiles a kernel when its own file changes, but not when a helper kernel or a constant it
takes from another module does, and would then run stale code.
"""

from __future__ import annotations

import fcntl
import functools
import hashlib
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numba


def cache_dir() -> str:
    """Where this version of the core's kernels are cached: a digest of its sources and of where they are
    installed (numba keys its cache files by the source's path too, so each install has its own, and its
    READY_FILE says that install's kernels are complete)."""
    here = Path(__file__).resolve().parent.parent  # the whole core: kernels live in every sub-package
    sources = sorted(here.rglob("*.py"))
    # each file's path with its contents: a kernel moved to another module unchanged is another cache entry to numba
    digest = hashlib.sha1(str(here).encode() + b"".join(str(path.relative_to(here)).encode() + path.read_bytes()
                                                        for path in sources)).hexdigest()[:16]
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "ntcr_recon",
                                                              "numba")
    return os.path.join(base, digest)


# Read when each kernel is decorated (its cache is located then): set before any kernel module is imported,
# which importing this module first guarantees. Not put in os.environ, which child processes would inherit.
numba.config.CACHE_DIR = cache_dir()
# The filter's kernels split their points over threads (parallel=True, numba's default threading layer: OpenMP
# here). OpenMP's idle threads spin by default, taking a core from the graph's other processes: asleep instead
# (numba's workqueue layer, which sleeps too, cost more per call than the threads saved).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

jit = functools.partial(numba.njit, cache=True, nogil=True, error_model="numpy")


# written in the cache once the workload ran: {"seconds", "finished" (wall time), "files" (the cache's files then)}
READY_FILE = "ready.json"
CACHE_SUFFIXES = (".nbi", ".nbc")  # numba's cache index and data files
DEFAULT_COMPILE_S = 90  # the estimate on a first install (2 cores); later ones say what the last one took


def _base_dir() -> Path:
    return Path(numba.config.CACHE_DIR).parent


def ready_at() -> float | None:
    """Wall-clock time (s) at which this version's kernels were complete in the cache; None while they are not,
    or once a file the cache held then is gone (a cache copied or cleaned in part: its kernels would compile
    inside the frames)."""
    directory = Path(numba.config.CACHE_DIR)
    try:
        record = json.loads((directory / READY_FILE).read_text())
        if not all((directory / name).is_file() for name in record.get("files", ())):
            return None
        return float(record["finished"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def _cache_files(directory: Path) -> list[str]:
    """The cache's index and data files, relative to it (numba keeps them in a folder per source folder)."""
    return sorted(str(path.relative_to(directory)) for path in directory.rglob("*") if path.suffix in CACHE_SUFFIXES)


def estimate_s() -> int:
    """How long a compilation takes here: what the newest one on this machine took, else DEFAULT_COMPILE_S."""
    newest = None
    for path in _base_dir().glob(f"*/{READY_FILE}"):
        try:
            record = json.loads(path.read_text())
            if newest is None or record["finished"] > newest["finished"]:
                newest = record
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return int(round(newest["seconds"] / 5.0) * 5) or 5 if newest else DEFAULT_COMPILE_S


def ensure_compiled(workload: Callable[[], None], log: Callable[[str], None]) -> float | None:
    """Run `workload` (which calls every kernel) unless this version's cache is complete; one process at a time.

    Says so in one line through `log` when it compiles or waits for another process compiling; says nothing
    when the cache is complete. Returns the seconds this process spent compiling or waiting (None: nothing to
    do). A workload that fails is reported and leaves the kernels to compile on first use, as before."""
    directory = Path(numba.config.CACHE_DIR)
    if ready_at() is not None:
        return None
    started = time.monotonic()
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory / "compile.lock", "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log(f"compiling the numba kernels in another process (first start after an install, about "
                f"{estimate_s()} s; cached in {directory}): waiting for them")
            fcntl.flock(lock, fcntl.LOCK_EX)
            if ready_at() is not None:
                return time.monotonic() - started
        else:
            if ready_at() is not None:
                return None
            log(f"compiling the numba kernels (first start after an install, about {estimate_s()} s; cached in "
                f"{directory})")
        try:
            workload()
        except Exception as error:  # noqa: BLE001 - never worse than compiling on first use
            log(f"compiling the kernels ahead failed ({type(error).__name__}: {error}): they compile on first use")
            return time.monotonic() - started
        seconds = time.monotonic() - started
        (directory / READY_FILE).write_text(json.dumps({"seconds": round(seconds, 1), "finished": time.time(),
                                                         "files": _cache_files(directory)}))
        return seconds


def load_cached() -> int:
    """Load the cached compilations of every kernel in the ntcr_recon.core modules this process imported, so
    that no first frame pays for reading them either. Returns how many were loaded."""
    loaded, seen = 0, set()
    for name, module in list(sys.modules.items()):
        if not name.startswith("ntcr_recon.core.") or module is None:
            continue
        for kernel in list(vars(module).values()):
            if not isinstance(kernel, numba.core.registry.CPUDispatcher) or id(kernel) in seen:
                continue
            seen.add(id(kernel))
            loaded += _load(kernel)
    return loaded


def _load(kernel) -> int:
    """The cached overloads of one kernel for this code and this machine (numba's cache index), loaded."""
    try:
        cache = kernel._cache
        codegen = kernel.targetctx.codegen()
        index = cache._cache_file._load_index()
        wanted = [key[0] for key in index if key == cache._index_key(key[0], codegen)]
    except Exception:  # noqa: BLE001 - numba's internals changed or no cache: the kernel loads on first use
        return 0
    count = 0
    for signature in wanted:
        if signature not in kernel.overloads:
            try:
                kernel.compile(signature)
                count += 1
            except Exception:  # noqa: BLE001
                continue
    return count
