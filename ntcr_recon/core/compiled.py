"""The one way the package compiles a kernel: numba's njit with the settings every kernel shares.

Per-point loops over a few thousand points (neighbourhood fits, projections onto the centreline) cost more in
numpy's per-call overhead and temporaries than in arithmetic; compiled, they run at memory speed. Kernels are
compiled on first call and cached on disk, so a node pays the compilation once per machine, not at every start.
`nogil`: a node's executor threads and the DDS threads keep running while a kernel works. `error_model="numpy"`:
a division by zero gives inf or nan as the numpy code it replaces did, instead of raising. Single-threaded on
purpose: the graph already runs one process per stage on every core there is.

The cache lives in `$NUMBA_CACHE_DIR` (default `~/.cache/ntcr_recon/numba`) under a digest of the core's
sources: numba re-compiles a kernel when its own file changes, but not when a helper kernel or a constant it
takes from another module does, and would then run stale code.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import numba


def cache_dir() -> str:
    """Where this version of the core's kernels are cached."""
    sources = sorted(Path(__file__).parent.glob("*.py"))
    digest = hashlib.sha1(b"".join(path.read_bytes() for path in sources)).hexdigest()[:16]
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
