"""The one way the package compiles a kernel: numba's njit with the settings every kernel shares.

Per-point loops over a few thousand points (neighbourhood fits, projections onto the centreline) cost more in
numpy's per-call overhead and temporaries than in arithmetic; compiled, they run at memory speed. Kernels are
compiled on first call and cached on disk (beside the module, or in numba's user cache where the install is
read-only), so a node pays the compilation once per machine, not at every start. `nogil`: a node's executor
threads and the DDS threads keep running while a kernel works. Single-threaded on purpose: the graph already
runs one process per stage on every core there is.
"""

from __future__ import annotations

import functools

import numba

jit = functools.partial(numba.njit, cache=True, nogil=True)
